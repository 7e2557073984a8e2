"""CEM: the cross-entropy method with a diagonal Gaussian and decaying extra variance.

Rubinstein & Kroese (2004), "The Cross-Entropy Method"; the decaying extra ("noisy")
variance follows Szita & Lorincz (2006), "Learning Tetris using the noisy cross-entropy
method", in the geometric form of the CEM-RL implementation (Pourchot & Sigaud 2019,
``sepCEM``: damp <- tau * damp + (1 - tau) * damp_limit). Paper section 2.1.3 of
Pourchot, Perrin & Sigaud (2018): "the K_e most fit individuals are used to compute
the new mean and variance ... after adding some limited extra variance to prevent
premature convergence", K_e usually half the population.

One generation t = 1, 2, ... over the n told samples, ranked by utility (best first)::

    K        = max(1, floor(elite_fraction * n))             # K_e = n/2 by default
    w_i      = 1/K  (or log weights)                         # i = 1..K, sum to 1
    mu      <- sum_i w_i x_{i:n}                             # maximum-likelihood mean
    eps_t    = floor + (eps_0 - floor) * tau**t              # extra variance schedule
    sigma^2 <- sum_i w_i (x_{i:n} - mu)**2 + eps_t           # ML diagonal variance + extra

eps_0 defaults to the initial variance sigma^2, tau = 0.95 and floor = 1e-5 (CEM-RL's
damp_limit), so the extra variance halves about every 14 generations and is ~0.5 % of
eps_0 after 100. The floor keeps every standard deviation >= sqrt(1e-5) ~ 3e-3, which also
keeps the distribution well-defined when K = 1.

Ties: elites are chosen by utility, and tied members share the weights of the rank
positions they span (:func:`~imix_cli.core.algorithms.base.rank_weights`), so the update never
depends on the order of the told population (with mixing, reused members come first).

The update is one compiled function (:func:`cem_update`, the elite weights :func:`cem_mean_weights`), which
:meth:`CEM.tell` and the compiled generation loop (:mod:`imix_cli.running.loop.compiled_loop`) both run.

``style="cemrl"``: the authors' own CEM (apourchot/CEM-RL ``ES.py``, ``sepCEM.tell``),
which differs from the textbook update above in four constants and one formula::

    w_i      = ln((K + 1) / i) / sum                          # log weights
    damp    <- 0.95 damp + 0.05 * 1e-5,  damp_0 = 1e-3         # extra variance, updated first
    mu      <- sum_i w_i x_{i:n}
    sigma^2 <- (1/K) sum_i w_i (x_{i:n} - mu_old)**2 + damp     # about the OLD mean, times 1/K

The 1/K factor makes the fitted variance K times smaller than the elites' spread, so the
distribution contracts within a few generations to the scale of ``damp``; this is the
update the authors' importance-mixing experiments ran with (it raises the reuse rate: the
distribution barely moves once contracted).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from imix_cli.core import numerics as xp
from imix_cli.core.algorithms.base import CompiledStep, EvolutionStrategy, Params, rank_weights_kernel
from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.numerics import elementary as el
from imix_cli.core.numerics import linalg_kernels as lk

ELITE_WEIGHTS = ("equal", "log")
STYLES = ("imix", "cemrl")


class CEMState(NamedTuple):
    """CEM's search state, the one record that ``tell``, the compiled loop and the checkpoint use
    (:class:`~imix_cli.core.algorithms.base.CompiledStep`)."""

    #: mu, shape (d,)
    mean: np.ndarray
    #: sigma of each coordinate, shape (d,)
    std: np.ndarray
    #: eps_t, the current extra variance (eps_0 before the first tell), shape (1,)
    extra_variance: np.ndarray


class CEMConstants(NamedTuple):
    """What :func:`cem_update` and :func:`cem_mean_weights` read besides the state (never written)."""

    elite_fraction: float
    log_weights: bool
    decay: float
    floor: float
    cemrl: bool


@njit(cache=True)
def _elites(n, constants):
    """K = max(1, floor(elite_fraction * n))."""
    return max(1, int(constants.elite_fraction * n))


@njit(cache=True)
def cem_mean_weights(utilities, constants):
    """Each member's elite weight (the new mean is sum_i w_i x_i): the K best share 1/K each, or log weights
    ln((K + 1) / i) / sum; tied members share the weights of the positions they span
    (:func:`~imix_cli.core.algorithms.base.rank_weights_kernel`); 0 for the rest. ``constants``: :class:`CEMConstants`."""
    n = utilities.shape[0]
    k = _elites(n, constants)
    by_rank = np.zeros(n)
    if not constants.log_weights:
        for i in range(k):
            by_rank[i] = 1.0 / k
    else:
        w = np.empty(k)
        for i in range(k):
            w[i] = el.log((k + 1) / (i + 1))
        total = lk.numpy_sum(w)  # w.sum(): numpy's pairwise order
        for i in range(k):
            by_rank[i] = w[i] / total
    return rank_weights_kernel(utilities, by_rank)


@njit(cache=True)
def cem_update(samples, utilities, state, constants):
    """One generation of CEM (module docstring), in place of ``state`` (:class:`CEMState`). The one copy of the update
    (:class:`~imix_cli.core.algorithms.base.CompiledStep`): :meth:`CEM._update` and the compiled generation loop
    both run it."""
    n, d = samples.shape
    k = _elites(n, constants)
    w = cem_mean_weights(utilities, constants)
    mu, sigma = state.mean, state.std
    new_mu = lk.vec_mat_kernel(w, samples)  # one fixed summation order (not BLAS's): same bits on every CPU
    decay = constants.decay
    extra = decay * state.extra_variance[0] + (1.0 - decay) * constants.floor
    cemrl = constants.cemrl
    sq = np.empty((n, d))
    for i in range(n):
        for j in range(d):
            diff = samples[i, j] - (mu[j] if cemrl else new_mu[j])  # cemrl: about the old mean
            sq[i, j] = diff * diff
    var = lk.vec_mat_kernel(w, sq)
    for j in range(d):
        v = var[j] / k + extra if cemrl else var[j] + extra
        mu[j] = new_mu[j]
        sigma[j] = math.sqrt(v)
    state.extra_variance[0] = extra


@dataclass(frozen=True)
class CEMParams(Params):
    """:class:`~imix_cli.core.algorithms.base.Params` (``sigma`` sets the initial covariance
    sigma^2 I; ``lr`` is ignored) and CEM's own options."""

    #: K_e / n, the fraction of told samples kept as elites (paper: half); in (0, 1].
    elite_fraction: float = 0.5
    #: "equal": every elite weighs 1/K. "log": w_i proportional to ln((K + 1) / i), as in
    #: CEM-RL / CMA-ES-style recombination.
    elite_weights: str = "equal"
    #: eps_0, the extra variance before decay; None: sigma^2 (the initial variance), or 1e-3
    #: with style "cemrl"; >= 0.
    extra_variance_init: float | None = None
    #: tau, geometric decay factor of the extra variance per generation (CEM-RL); in [0, 1].
    extra_variance_decay: float = 0.95
    #: Limit of the extra variance (CEM-RL's damp_limit); > 0.
    extra_variance_floor: float = 1e-5
    #: "imix": the textbook update (module docstring). "cemrl": the authors' sepCEM: log
    #: weights, extra variance 1e-3 decaying to 1e-5 unless given, variance about the old
    #: mean scaled by 1/K (``algo.style`` of conf/algo/cem.yaml).
    style: str = field(default="imix", metadata={
        "choices": STYLES, "short": "imix | cemrl",
        "doc": "`algo=cem` only: `imix` (maximum-likelihood variance + decaying extra variance) or `cemrl` (the authors' sepCEM: log "
               "weights, variance about the old mean scaled by 1/K)",
    })  # fmt: skip

    def __post_init__(self):
        super().__post_init__()
        if self.style not in STYLES:
            raise ValueError(f"style must be one of {STYLES}, got {self.style!r}")
        if not 0.0 < self.elite_fraction <= 1.0:
            raise ValueError(f"elite_fraction must be in (0, 1], got {self.elite_fraction}")
        if self.elite_weights not in ELITE_WEIGHTS:
            raise ValueError(f"elite_weights must be one of {ELITE_WEIGHTS}, got {self.elite_weights!r}")
        if self.extra_variance_init is not None and self.extra_variance_init < 0:
            raise ValueError(f"extra_variance_init must be >= 0, got {self.extra_variance_init}")
        if not 0.0 <= self.extra_variance_decay <= 1.0:
            raise ValueError(f"extra_variance_decay must be in [0, 1], got {self.extra_variance_decay}")
        if not self.extra_variance_floor > 0:
            raise ValueError(f"extra_variance_floor must be > 0, got {self.extra_variance_floor}")


class CEM(EvolutionStrategy):
    """CEM: diagonal Gaussian refitted to the elites, plus a geometrically decaying extra variance.

    ``CEM(dim, params=None, *, mean=None, **fields)``: see
    :class:`~imix_cli.core.algorithms.base.EvolutionStrategy` and :class:`CEMParams`.
    """

    name = "cem"
    Params = CEMParams

    def _setup(self) -> None:
        p = self.params
        extra_variance_init = p.extra_variance_init
        self.elite_weights = p.elite_weights
        if p.style == "cemrl":
            self.elite_weights = "log"
            if extra_variance_init is None:
                extra_variance_init = 1e-3  # CEM-RL's damp
        if extra_variance_init is None:
            extra_variance_init = xp.power(self.sigma, 2.0)
        self.elite_fraction = float(p.elite_fraction)
        self.extra_variance_decay = float(p.extra_variance_decay)
        self.extra_variance_floor = float(p.extra_variance_floor)
        self.set_state(CEMState(self.initial_mean.copy(), np.full(self.dim, self.sigma), np.array([float(extra_variance_init)])))

    @property
    def extra_variance(self) -> float:
        """eps_t, the current extra variance (eps_0 before the first tell)."""
        return float(self.state.extra_variance[0])

    @property
    def distribution(self) -> DiagonalGaussian:
        return self._dist

    def _constants(self) -> CEMConstants:
        return CEMConstants(self.elite_fraction, self.elite_weights == "log", self.extra_variance_decay, self.extra_variance_floor,
                            self.style == "cemrl")  # fmt: skip

    def _update(self, samples: np.ndarray, utilities: np.ndarray) -> None:
        self._update_compiled(samples, utilities)

    def compiled_step(self) -> CompiledStep:
        return CompiledStep(cem_update, self._constants(), cem_mean_weights)

    def _mean_weights(self, utilities: np.ndarray) -> np.ndarray:
        """Each member's elite weight: the new mean is sum_i w_i x_i (:func:`cem_mean_weights`)."""
        return cem_mean_weights(np.ascontiguousarray(utilities, dtype=np.float64), self._constants())
