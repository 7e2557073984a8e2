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

import numpy as np
from numba import njit

from imix_cli.core import numerics as xp
from imix_cli.core.algorithms.base import Adam, CompiledStep, EvolutionStrategy, Params, _array_like, adam_step, prefixed, unprefixed
from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.numerics import elementary as el
from imix_cli.core.numerics import linalg_kernels as lk


@njit(cache=True)
def snes_update(samples, utilities, state, counts, constants):
    """One generation of SNES (module docstring), in place: ``state`` rows mu, sigma, log sigma, Adam's m
    and v for mu, then for log sigma; ``counts`` the two Adams' step counts; ``constants`` lr, sigma_lr,
    beta1, beta2 and the two Adams' epsilons. The one copy of the update
    (:class:`~imix_cli.core.algorithms.base.CompiledStep`): :meth:`SNES._update` and the compiled generation
    loop both run it."""
    n, d = samples.shape
    mu, sigma, log_sigma = state[0], state[1], state[2]
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
    step_mu = adam_step(state[3], state[4], counts, 0, constants[0], constants[2], constants[3], constants[4], grad_mu)
    step_log_sigma = adam_step(state[5], state[6], counts, 1, constants[1], constants[2], constants[3], constants[5], grad_log_sigma)
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
        beta1, beta2 = self.params.beta1, self.params.beta2
        self.sigma_lr = self.lr if self.params.sigma_lr is None else float(self.params.sigma_lr)
        self._mu = self.initial_mean.copy()
        self._log_sigma = np.full(self.dim, xp.log(self.sigma))
        self.mu_optimizer = Adam(self.dim, lr=self.lr, beta1=beta1, beta2=beta2)
        self.sigma_optimizer = Adam(self.dim, lr=self.sigma_lr, beta1=beta1, beta2=beta2)
        self._dist = DiagonalGaussian(self._mu, xp.exp(self._log_sigma))

    @property
    def distribution(self) -> DiagonalGaussian:
        return self._dist

    def _update(self, samples: np.ndarray, utilities: np.ndarray) -> None:
        self._update_compiled(samples, utilities)

    def compiled_step(self) -> CompiledStep:
        m, s = self.mu_optimizer, self.sigma_optimizer
        state = np.stack([self._mu, self._dist.std, self._log_sigma, m.m, m.v, s.m, s.v])
        constants = np.array([m.lr, s.lr, m.beta1, m.beta2, m.epsilon, s.epsilon], dtype=np.float64)
        return CompiledStep(snes_update, state, np.array([m.t, s.t], dtype=np.int64), constants)

    def load_compiled_state(self, state: np.ndarray, counts: np.ndarray) -> None:
        self._mu, self._log_sigma = state[0].copy(), state[2].copy()
        self.mu_optimizer.m, self.mu_optimizer.v, self.mu_optimizer.t = state[3].copy(), state[4].copy(), int(counts[0])
        self.sigma_optimizer.m, self.sigma_optimizer.v, self.sigma_optimizer.t = state[5].copy(), state[6].copy(), int(counts[1])
        self._dist = DiagonalGaussian(self._mu, state[1])

    def _state_dict(self) -> dict:
        return {
            "mu": self._mu.copy(),
            "log_sigma": self._log_sigma.copy(),
            **prefixed("mu_optimizer", self.mu_optimizer.state_dict()),
            **prefixed("sigma_optimizer", self.sigma_optimizer.state_dict()),
        }

    def _load_state_dict(self, state: dict) -> None:
        self._mu = _array_like(state["mu"], self._mu, "mu")
        self._log_sigma = _array_like(state["log_sigma"], self._log_sigma, "log_sigma")
        self.mu_optimizer.load_state_dict(unprefixed("mu_optimizer", state))
        self.sigma_optimizer.load_state_dict(unprefixed("sigma_optimizer", state))
        self._dist = DiagonalGaussian(self._mu, xp.exp(self._log_sigma))
