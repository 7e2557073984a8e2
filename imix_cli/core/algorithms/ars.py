"""ARS: Augmented Random Search (Mania, Guy & Recht 2018, arXiv:1803.07055).

Why ARS in imix: on MuJoCo's locomotion tasks it is the sample-efficiency reference among
evolution strategies -- linear policies, mirrored directions, the top-b directions and a step
scaled by the spread of the returns. This module is the ES alone; how its mirrored pairs are
built with importance mixing (exactly, and why whole pairs cannot be reused) is
:mod:`imix_cli.core.mixing.mirrored` and docs/ars.md.

One generation (an ARS *iteration*) with N directions, step size alpha and noise nu::

    delta_1..N ~ N(0, I)                         # directions
    theta_k+- = m +- nu delta_k                  # mirrored pair k: two episodes, returns r_k+, r_k-
    keep the b pairs of largest max(r_k+, r_k-)  # "-t"; b = N keeps all (V1, V2)
    sigma_R = std of the 2b kept returns
    m <- m + alpha / (b sigma_R) sum_kept (r_k+ - r_k-) delta_k

V2 (state normalisation) is the policy's observation normaliser (``policy.obs_norm``), with
statistics frozen after a warm-up by default: a stored return is only the return of the policy
function it was measured with (docs/ars.md). ``policy.obs_norm_freeze=false`` updates them forever,
as ARS does, and re-expresses the archived anchors under each new statistics (with mixing, this
needs ``policy.bias=true``: imix_cli.core.evaluation.policies, "Observation normalisation").

In imix's terms: ``popsize`` is the number of *members* 2N (episodes of a generation without
mixing, as for the other ES), ``sigma`` is nu, ``lr`` is alpha (no Adam), ``algo.top`` is b.
The weight decay and the fitness shaping of the other ES do not apply: ARS steps on raw
returns.

``tell`` takes the 2N members as ``[theta_1+ .. theta_N+, theta_1- .. theta_N-]`` (what ``ask``
returns) and reads each direction back as ``(theta_k+ - theta_k-) / (2 nu)``, so it needs no
record of which draws were made.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from imix_cli.core.algorithms.base import EvolutionStrategy, Params
from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.mixing.mirrored import MIRRORED_PAIRS, mirror


@dataclass(frozen=True)
class ARSParams(Params):
    """:class:`~imix_cli.core.algorithms.base.Params` read the ARS way: ``popsize`` = 2N members (even),
    ``sigma`` = the fixed noise nu, ``lr`` = the step size alpha; ``weight_decay`` and
    ``fitness_shaping`` are not used. And ARS's own option:"""

    #: b, the number of best directions a step uses ("ARS V1-t / V2-t"); None: all N.
    top: int | None = field(default=None, metadata={
        "short": "b, the best directions a step uses (null: all)",
        "doc": "`algo=ars` only: b, the number of best directions a step uses (ARS V1-t/V2-t); `null` = all N = popsize/2",
    })  # fmt: skip
    #: Added to every step's reward during training (ARS's "shift", rl-zoo3's ``alive_bonus_offset``):
    #: -1 on Hopper and Walker2d cancels their survival bonus of 1 per step, so that a policy is not
    #: rewarded for merely standing. A member's fitness is then return + offset x episode length (CSV
    #: columns mean_score/best_score and the archive hold it); the distribution mean's measurements
    #: (mean_policy_score, the thresholds) stay on the env's own return.
    alive_bonus_offset: float = field(default=0.0, metadata={
        "short": "added to each step's reward in training",
        "doc": "`algo=ars` only: added to every step's reward during training (ARS's shift; `-1` cancels Hopper's and Walker2d's "
               "survival bonus, as `+ars=hopper` does); the CSV's population columns hold these training returns, `mean_policy_score` "
               "the env's own",
    })  # fmt: skip

    def __post_init__(self):
        super().__post_init__()
        if self.popsize % 2:
            raise ValueError(f"popsize must be even for ARS (2 members per direction), got {self.popsize}")
        if self.top is not None and not 1 <= self.top <= self.popsize // 2:
            raise ValueError(f"top must be in [1, popsize/2 = {self.popsize // 2}] (directions), got {self.top}")
        if not np.isfinite(self.alive_bonus_offset):
            raise ValueError(f"alive_bonus_offset must be finite, got {self.alive_bonus_offset}")


def _pair_keys(deltas: np.ndarray) -> np.ndarray:
    """A key per direction that depends only on its values: breaks ties in the top-b selection at
    random but independently of the order the pairs are told in."""
    return np.array([zlib.crc32(np.ascontiguousarray(row, dtype=np.float64).tobytes()) for row in deltas], dtype=np.int64)


class ARSState(NamedTuple):
    """ARS's search state (the record ``tell`` moves and the checkpoint saves: :class:`~imix_cli.core.algorithms.base.CompiledStep`)."""

    #: m, the policy the pairs are mirrored about, shape (d,)
    mean: np.ndarray
    #: nu in every coordinate, shape (d,) (fixed)
    std: np.ndarray


class ARS(EvolutionStrategy):
    """ARS: the mean m of N(m, nu^2 I) moves along mirrored directions weighted by return differences.

    ``ARS(dim, params=None, *, mean=None, **fields)``: see
    :class:`~imix_cli.core.algorithms.base.EvolutionStrategy` and :class:`ARSParams`.
    """

    name = "ars"
    Params = ARSParams
    #: Members come in mirrored pairs: their generations are mixed, evaluated and archived by the pairs'
    #: scheme (:mod:`imix_cli.core.mixing.mirrored`), which :mod:`imix_cli.core.mixing.generation` calls through this hook.
    generation_scheme = MIRRORED_PAIRS

    def _setup(self) -> None:
        self.directions = self.popsize // 2
        self.top = self.directions if self.params.top is None else int(self.params.top)
        self.set_state(ARSState(self.initial_mean.copy(), np.full(self.dim, self.sigma)))
        self.last_return_std = float("nan")

    @property
    def distribution(self) -> DiagonalGaussian:
        """N(m, nu^2 I): the law of every member (of theta+ and, by symmetry, of theta-)."""
        return self._dist

    def ask(self, rng: np.random.Generator) -> np.ndarray:
        """N fresh mirrored pairs, as ``[theta_1+ .. theta_N+, theta_1- .. theta_N-]``."""
        plus = self._dist.sample(self.directions, rng)
        return np.concatenate([plus, mirror(plus, self.state.mean)])

    def training_fitness(self, returns: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """return + alive_bonus_offset x episode length (:attr:`ARSParams.alive_bonus_offset`)."""
        offset = self.params.alive_bonus_offset
        return returns if offset == 0.0 else np.asarray(returns, dtype=np.float64) + offset * np.asarray(steps, dtype=np.float64)

    def tell(self, samples, fitness) -> None:
        """One ARS step from 2N members ``[plus; minus]`` and their returns (non-finite: the pair is left out)."""
        samples = np.asarray(samples, dtype=np.float64)
        fitness = np.asarray(fitness, dtype=np.float64).reshape(-1)
        n = self.directions
        if samples.shape != (2 * n, self.dim):
            raise ValueError(f"samples must have shape ({2 * n}, {self.dim}) (N mirrored pairs), got {samples.shape}")
        if fitness.shape[0] != 2 * n:
            raise ValueError(f"got {samples.shape[0]} samples but {fitness.shape[0]} fitness values")
        self._update(samples, fitness)
        self.generation += 1

    def _update(self, samples: np.ndarray, fitness: np.ndarray) -> None:
        n = self.directions
        plus, minus = samples[:n], samples[n:]
        r_plus, r_minus = fitness[:n], fitness[n:]
        deltas = (plus - minus) / (2.0 * self.sigma)
        finite = np.isfinite(r_plus) & np.isfinite(r_minus)
        self.nonfinite_fitness_count += int(np.count_nonzero(~np.isfinite(fitness)))
        pairs = np.flatnonzero(finite)
        if pairs.size == 0:
            return
        b = min(self.top, pairs.size)
        # The b pairs of largest max(r+, r-); ties by a key of the direction, not by position.
        best = np.maximum(r_plus[pairs], r_minus[pairs])
        order = np.lexsort((_pair_keys(deltas[pairs]), -best))
        used = pairs[order[:b]]
        return_std = float(np.std(np.concatenate([r_plus[used], r_minus[used]])))
        self.last_return_std = return_std
        if not return_std > 0.0:  # all 2b returns equal: no direction is better than another
            return
        step = (self.lr / (b * return_std)) * ((r_plus[used] - r_minus[used]) @ deltas[used])
        self.set_state(ARSState(self.state.mean + step, self.state.std))
