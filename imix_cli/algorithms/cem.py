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
positions they span (:func:`~imix_cli.algorithms.base.rank_weights`), so the update never
depends on the order of the told population (with mixing, reused members come first).

``style="cemrl"``: the authors' own CEM (apourchot/CEM-RL ``ES.py``, ``sepCEM.tell``),
which differs from the textbook update above in four constants and one formula::

    w_i      = ln((K + 1) / i) / sum                          # log weights
    damp    <- 0.95 damp + 0.05 * 1e-5,  damp_0 = 1e-3         # extra variance, updated first
    mu      <- sum_i w_i x_{i:n}
    sigma^2 <- (1/K) sum_i w_i (x_{i:n} - mu_old)**2 + damp     # about the OLD mean, times 1/K

The 1/K factor makes the fitted variance K times smaller than the elites' spread, so the
distribution contracts within a few generations to the scale of ``damp``; this is the
update the authors' importance-mixing experiments ran with (issue 11, item 5 measures
what it does to the reuse rate).
"""

from __future__ import annotations

import numpy as np

from imix_cli.algorithms.base import EvolutionStrategy, rank_weights
from imix_cli.distributions import DiagonalGaussian

ELITE_WEIGHTS = ("equal", "log")
STYLES = ("imix", "cemrl")


class CEM(EvolutionStrategy):
    """CEM: diagonal Gaussian refitted to the elites, plus a geometrically decaying extra variance.

    Parameters
    ----------
    dim, popsize, sigma, lr, weight_decay, weight_decay_form, mean
        See :class:`~imix_cli.algorithms.base.EvolutionStrategy`. ``sigma`` sets the
        initial covariance sigma^2 I; ``lr`` is ignored.
    elite_fraction : float, default 0.5
        K_e / n, the fraction of told samples kept as elites (paper: half).
    elite_weights : {"equal", "log"}, default "equal"
        "equal": every elite weighs 1/K. "log": w_i proportional to
        ln((K + 1) / i), as in CEM-RL / CMA-ES-style recombination.
    extra_variance_init : float, optional
        eps_0, the extra variance before decay; default sigma^2 (the initial variance).
    extra_variance_decay : float, default 0.95
        tau, geometric decay factor per generation (CEM-RL).
    extra_variance_floor : float, default 1e-5
        Limit of the extra variance (CEM-RL's damp_limit); must be > 0.
    style : {"imix", "cemrl"}, default "imix"
        "imix": the update above. "cemrl": the authors' sepCEM (module docstring): log
        weights, extra variance 1e-3 decaying to 1e-5 unless given, variance about the old
        mean scaled by 1/K.
    """

    name = "cem"

    def __init__(
        self,
        dim: int,
        popsize: int = 50,
        sigma: float = 0.25,
        lr: float = 0.01,
        weight_decay: float = 0.05,
        weight_decay_form: str = "estool",
        mean=None,
        elite_fraction: float = 0.5,
        elite_weights: str = "equal",
        extra_variance_init: float | None = None,
        extra_variance_decay: float = 0.95,
        extra_variance_floor: float = 1e-5,
        style: str = "imix",
    ):
        super().__init__(dim, popsize, sigma, lr, weight_decay, weight_decay_form, mean)
        if style not in STYLES:
            raise ValueError(f"style must be one of {STYLES}, got {style!r}")
        self.style = style
        if style == "cemrl":
            elite_weights = "log"
            if extra_variance_init is None:
                extra_variance_init = 1e-3  # CEM-RL's damp
        if not 0.0 < elite_fraction <= 1.0:
            raise ValueError(f"elite_fraction must be in (0, 1], got {elite_fraction}")
        if elite_weights not in ELITE_WEIGHTS:
            raise ValueError(f"elite_weights must be one of {ELITE_WEIGHTS}, got {elite_weights!r}")
        if extra_variance_init is None:
            extra_variance_init = self.sigma**2
        if extra_variance_init < 0:
            raise ValueError(f"extra_variance_init must be >= 0, got {extra_variance_init}")
        if not 0.0 <= extra_variance_decay <= 1.0:
            raise ValueError(f"extra_variance_decay must be in [0, 1], got {extra_variance_decay}")
        if not extra_variance_floor > 0:
            raise ValueError(f"extra_variance_floor must be > 0, got {extra_variance_floor}")
        self.elite_fraction = float(elite_fraction)
        self.elite_weights = elite_weights
        self.extra_variance_decay = float(extra_variance_decay)
        self.extra_variance_floor = float(extra_variance_floor)
        #: current extra variance eps_t (eps_0 before the first tell)
        self.extra_variance = float(extra_variance_init)
        self._dist = DiagonalGaussian(self.initial_mean, self.sigma)

    @property
    def distribution(self) -> DiagonalGaussian:
        return self._dist

    def _weights(self, k: int) -> np.ndarray:
        if self.elite_weights == "equal":
            return np.full(k, 1.0 / k)
        w = np.log((k + 1) / np.arange(1, k + 1))
        return w / w.sum()

    def _update(self, samples: np.ndarray, utilities: np.ndarray) -> None:
        n = samples.shape[0]
        k = max(1, int(self.elite_fraction * n))
        by_rank = np.zeros(n)
        by_rank[:k] = self._weights(k)
        w = rank_weights(utilities, by_rank)  # elites' weights, ties sharing theirs; 0 for the rest
        old_mu = self._dist.mean
        mu = w @ samples
        self.extra_variance = (
            self.extra_variance_decay * self.extra_variance
            + (1.0 - self.extra_variance_decay) * self.extra_variance_floor
        )
        if self.style == "cemrl":
            var = (w @ ((samples - old_mu) ** 2)) / k + self.extra_variance
        else:
            var = w @ ((samples - mu) ** 2) + self.extra_variance
        self._dist = DiagonalGaussian(mu, np.sqrt(var))
