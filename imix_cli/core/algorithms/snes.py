"""SNES: separable natural evolution strategy (diagonal Gaussian, natural gradient).

Schaul, Glasmachers & Schmidhuber (2011), "High dimensions and heavy tails for natural
evolution strategies", GECCO. Paper section 2.1.2 of Pourchot, Perrin & Sigaud (2018):
all diagonal coefficients of the covariance are adapted, starting from sigma^2 I_d.

One generation, with utilities u_k (higher is better) of the n told samples x_k::

    s_k         = (x_k - mu) / sigma                 # per-coordinate standardisation
    grad_mu     = sigma * sum_k u_k s_k              # natural gradient for mu
    grad_logsig = sum_k u_k (s_k**2 - 1) / 2         # natural gradient for log sigma
    mu         <- mu + Adam_mu(grad_mu)              # paper 4.1: Adam, lr 0.01
    log sigma  <- log sigma + Adam_sigma(grad_logsig)

Why Adam on log sigma rather than SNES's own eta_sigma = (3 + ln d) / (5 sqrt d):

* The paper applies Adam (lr 0.01, beta1 0.99, beta2 0.999) to "the algorithms relying
  on gradient descent (OpenES and SNES)"; this is the literal reading.
* eta_sigma was tuned for SNES's own utilities (L1 norm ~1.1-1.2), not for the centred
  ranks used here (L1 norm ~n/4): used as is, log sigma would random-walk by ~e^{+-0.2}
  per generation at d = 155, n = 50. Adam divides by the running RMS of the gradient,
  so it is indifferent to the utilities' scale.
* Adam moves each log sigma by at most about lr per generation (~e^{+-0.01}); sigma can
  neither collapse nor explode within a few generations, and gradient noise averages
  out in the first moment (beta1 = 0.99). Faster sigma rules also fight Adam's
  second moment on mu: grad_mu scales with sigma while Adam's RMS remembers ~1/(1 -
  beta2) = 1000 generations, so a sigma shrinking much faster than that stalls the
  mean (tried: eta_sigma with utilities rescaled to unit L1 norm reached f = 5-110
  instead of 0.05-0.07 after 1000 generations on a 10-D axis-aligned ellipsoid of
  condition 1e3, 3 seeds).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from imix_cli.core import numerics as xp
from imix_cli.core.algorithms.base import ADAM_EPSILON, AdamState, CompiledStep, EvolutionStrategy, Params, adam_step
from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.numerics import elementary as el
from imix_cli.core.numerics import linalg_kernels as lk


class SNESState(NamedTuple):
    """SNES's search state, the one record that ``tell``, the compiled loop and the checkpoint use
    (:class:`~imix_cli.core.algorithms.base.CompiledStep`); every field has shape (d,) but the Adams' counts."""

    #: mu, the mean searched
    mean: np.ndarray
    #: sigma = exp(log sigma), the standard deviation of each coordinate
    std: np.ndarray
    #: log sigma, what Adam moves
    log_sigma: np.ndarray
    #: Adam on mu
    mu_adam: AdamState
    #: Adam on log sigma
    sigma_adam: AdamState


class SNESConstants(NamedTuple):
    """What :func:`snes_update` reads besides the state (never written)."""

    lr: float
    sigma_lr: float
    beta1: float
    beta2: float
    epsilon: float


@njit(cache=True)
def snes_update(samples, utilities, state, constants):
    """One generation of SNES (module docstring), in place of ``state`` (:class:`SNESState`). The one copy of the
    update (:class:`~imix_cli.core.algorithms.base.CompiledStep`): :meth:`SNES._update` and the compiled generation
    loop both run it."""
    n, d = samples.shape
    mu, sigma, log_sigma = state.mean, state.std, state.log_sigma
    s = np.empty((n, d))
    sq = np.empty((n, d))
    for i in range(n):
        for j in range(d):
            s[i, j] = (samples[i, j] - mu[j]) / sigma[j]
            sq[i, j] = s[i, j] * s[i, j] - 1.0
    grad_mu = lk.vec_mat_kernel(utilities, s)  # sums in one fixed order (not BLAS's): same bits on every CPU
    grad_log_sigma = lk.vec_mat_kernel(utilities, sq)
    for j in range(d):
        grad_mu[j] = sigma[j] * grad_mu[j]
        grad_log_sigma[j] = grad_log_sigma[j] / 2.0
    c = constants
    step_mu = adam_step(state.mu_adam, c.lr, c.beta1, c.beta2, c.epsilon, grad_mu)
    step_log_sigma = adam_step(state.sigma_adam, c.sigma_lr, c.beta1, c.beta2, c.epsilon, grad_log_sigma)
    for j in range(d):
        mu[j] = mu[j] + step_mu[j]
        log_sigma[j] = log_sigma[j] + step_log_sigma[j]
        sigma[j] = el.exp(log_sigma[j])


@dataclass(frozen=True)
class SNESParams(Params):
    """:class:`~imix_cli.core.algorithms.base.Params` (``sigma`` is the initial standard deviation of
    every coordinate; ``lr`` is Adam's learning rate for the mean, paper: 0.01) and SNES's own options."""

    #: Adam's learning rate for log sigma; None: ``lr``.
    sigma_lr: float | None = None
    #: Adam's first-moment decay (paper section 4.1), for mu and log sigma.
    beta1: float = 0.99
    #: Adam's second-moment decay (paper section 4.1), for mu and log sigma.
    beta2: float = 0.999

    def __post_init__(self):
        super().__post_init__()
        if self.sigma_lr is not None and not self.sigma_lr > 0:
            raise ValueError(f"sigma_lr must be > 0, got {self.sigma_lr}")


class SNES(EvolutionStrategy):
    """SNES: N(mu, diag(sigma^2)); natural-gradient Adam steps on mu and on log sigma.

    ``SNES(dim, params=None, *, mean=None, **fields)``: see
    :class:`~imix_cli.core.algorithms.base.EvolutionStrategy` and :class:`SNESParams`.
    """

    name = "snes"
    weights_utilities = "sum"  # its move is a sum over members of u_k times a function of x_k: weighted reuse applies
    Params = SNESParams

    def _setup(self) -> None:
        self.sigma_lr = self.lr if self.params.sigma_lr is None else float(self.params.sigma_lr)
        log_sigma = np.full(self.dim, xp.log(self.sigma))
        state = SNESState(self.initial_mean.copy(), xp.exp(log_sigma), log_sigma, AdamState.zeros(self.dim), AdamState.zeros(self.dim))
        self.set_state(state)

    @property
    def distribution(self) -> DiagonalGaussian:
        return self._dist

    def _update(self, samples: np.ndarray, utilities: np.ndarray) -> None:
        self._update_compiled(samples, utilities)

    def compiled_step(self) -> CompiledStep:
        constants = SNESConstants(self.lr, self.sigma_lr, self.params.beta1, self.params.beta2, ADAM_EPSILON)
        return CompiledStep(snes_update, constants)
