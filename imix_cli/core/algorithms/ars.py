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

The step is compiled (:func:`ars_update`), the one copy that ``tell`` and the compiled generation loop
(:mod:`imix_cli.core.mixing.compiled_generation`) both run. Its numbers are those of the numpy step it
replaced, bit for bit, which the published ARS studies (docs/ars.md) were run with:

* the sum over the kept directions is BLAS's, as numpy's ``@`` was: numba's ``np.dot(vector, matrix)``
  calls the dgemv of scipy's OpenBLAS, and gave numpy's ``@`` bits on 20,000 random shapes under each of
  five OpenBLAS kernels (``OPENBLAS_CORETYPE``; d = 1 excepted, where numpy takes a dot product: so does
  :func:`_directions_sum`). ``tests/test_ars.py`` checks it, so a numpy or scipy whose BLAS orders
  the sum otherwise is seen. This is the one product of imix that BLAS still orders, so ARS's numbers may
  differ between CPUs (docs/numerics.md); a fixed order would change every published ARS number;
* the tie keys are zlib's crc32 of each direction's bytes (:func:`_crc32`, the same table);
* the order is numpy's ``lexsort`` (two stable sorts), sigma_R numpy's ``std`` (pairwise sums).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from imix_cli.core.algorithms.base import CompiledStep, EvolutionStrategy, Params
from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.mixing.mirrored import MIRRORED_PAIRS, mirror
from imix_cli.core.numerics import linalg_kernels as lk


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


def _crc32_table() -> np.ndarray:
    """zlib's CRC-32 table (the reflected polynomial 0xEDB88320), one entry per byte value."""
    table = np.empty(256, dtype=np.int64)
    for byte in range(256):
        c = byte
        for _ in range(8):
            c = (c >> 1) ^ 0xEDB88320 if c & 1 else c >> 1
        table[byte] = c
    return table


_CRC32_TABLE = _crc32_table()


@njit(cache=True)
def _crc32(row):
    """``zlib.crc32(row.tobytes())`` of a contiguous float64 row: a key of a direction that depends only on its values,
    so that ties in the top-b selection are broken at random but independently of the order the pairs are told in."""
    c = 0xFFFFFFFF
    for byte in row.view(np.uint8):
        c = _CRC32_TABLE[(c ^ byte) & 0xFF] ^ (c >> 8)
    return c ^ 0xFFFFFFFF


@njit(cache=True)
def _numpy_std(a):
    """``np.std(a)`` of a contiguous (n,) array, the same bits: the mean by numpy's pairwise sum, then the pairwise
    sum of the squared deviations, over n."""
    n = a.shape[0]
    mean = lk.numpy_sum(a) / n
    sq = np.empty(n)
    for i in range(n):
        dev = a[i] - mean
        sq[i] = dev * dev
    return math.sqrt(lk.numpy_sum(sq) / n)


@njit(cache=True)
def _directions_sum(weights, deltas):
    """``weights @ deltas`` with numpy's bits (module docstring): BLAS's dgemv, or its dot product when d = 1."""
    if deltas.shape[1] == 1:
        out = np.empty(1)
        out[0] = np.dot(weights, deltas[:, 0].copy())
        return out
    return np.dot(weights, deltas)


class ARSState(NamedTuple):
    """ARS's search state (the record ``tell`` moves and the checkpoint saves: :class:`~imix_cli.core.algorithms.base.CompiledStep`)."""

    #: m, the policy the pairs are mirrored about, shape (d,)
    mean: np.ndarray
    #: nu in every coordinate, shape (d,) (fixed)
    std: np.ndarray


class ARSConstants(NamedTuple):
    """What :func:`ars_update` reads besides the state (never written)."""

    #: nu, the noise the members were drawn with
    sigma: float
    #: alpha, the step size
    lr: float
    #: b, the directions a step keeps
    top: int


@njit(cache=True)
def ars_update(samples, fitness, state, constants):
    """One ARS step (module docstring) from 2N members ``[plus; minus]`` and their fitness, in place of ``state``
    (:class:`ARSState`); a pair with a non-finite return is left out. Returns sigma_R, or -1 when no pair is finite
    (no step, no sigma_R). The one
    copy of the step (:class:`~imix_cli.core.algorithms.base.CompiledStep`): :meth:`ARS.tell` and the compiled generation
    loop both run it."""
    n, d = samples.shape[0] // 2, samples.shape[1]
    pairs = np.empty(n, dtype=np.int64)
    count = 0
    for k in range(n):
        if math.isfinite(fitness[k]) and math.isfinite(fitness[n + k]):
            pairs[count] = k
            count += 1
    if count == 0:
        return -1.0
    b = min(constants.top, count)
    two_nu = 2.0 * constants.sigma
    deltas = np.empty((count, d))
    keys = np.empty(count, dtype=np.int64)
    minus_best = np.empty(count)
    for i in range(count):
        k = pairs[i]
        for j in range(d):
            deltas[i, j] = (samples[k, j] - samples[n + k, j]) / two_nu
        keys[i] = _crc32(deltas[i])
        minus_best[i] = -max(fitness[k], fitness[n + k])
    # The b pairs of largest max(r+, r-); ties by a key of the direction, not by position: np.lexsort((keys, -best)).
    by_key = np.argsort(keys, kind="mergesort")
    order = by_key[np.argsort(minus_best[by_key], kind="mergesort")]
    returns = np.empty(2 * b)
    differences = np.empty(b)
    used = np.empty((b, d))
    for i in range(b):
        k = pairs[order[i]]
        returns[i], returns[b + i] = fitness[k], fitness[n + k]
        differences[i] = fitness[k] - fitness[n + k]
        used[i] = deltas[order[i]]
    return_std = _numpy_std(returns)
    if not return_std > 0.0:  # all 2b returns equal: no direction is better than another
        return return_std
    step = (constants.lr / (b * return_std)) * _directions_sum(differences, used)
    mean = state.mean
    for j in range(d):
        mean[j] = mean[j] + step[j]
    return return_std


@njit(cache=True)
def fitness_as_utilities(samples, fitness, generation, weight_decay, multipliers):
    """ARS's compiled utilities (:meth:`~imix_cli.core.algorithms.base.EvolutionStrategy.compiled_utilities`): it steps
    on the raw fitness -- no shaping, no weight decay."""
    return fitness.copy()


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
        #: sigma_R of the last step :meth:`tell` took (a diagnostic: not in the state record, so a generation the compiled
        #: loop ran leaves it as it was)
        self.last_return_std = float("nan")

    @property
    def distribution(self) -> DiagonalGaussian:
        """N(m, nu^2 I): the law of every member (of theta+ and, by symmetry, of theta-)."""
        return self._dist

    def ask(self, rng: np.random.Generator) -> np.ndarray:
        """N fresh mirrored pairs, as ``[theta_1+ .. theta_N+, theta_1- .. theta_N-]``."""
        plus = self._dist.sample(self.directions, rng)
        return np.concatenate([plus, mirror(plus, self.state.mean)])

    @property
    def reward_offset(self) -> float:
        """:attr:`ARSParams.alive_bonus_offset`."""
        return float(self.params.alive_bonus_offset)

    def compiled_step(self) -> CompiledStep:
        return CompiledStep(ars_update, ARSConstants(float(self.sigma), float(self.lr), int(self.top)))

    def compiled_utilities(self):
        return fitness_as_utilities

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
        self.nonfinite_fitness_count += int(np.count_nonzero(~np.isfinite(fitness)))
        return_std = float(self._update_compiled(samples, fitness))
        if return_std != -1.0:  # -1: no finite pair, no step
            self.last_return_std = return_std
