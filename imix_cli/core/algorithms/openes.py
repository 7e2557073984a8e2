"""OpenES: the OpenAI evolution strategy with a fixed isotropic search distribution.

Salimans, Ho, Chen, Sidor & Sutskever (2017), "Evolution Strategies as a Scalable
Alternative to Reinforcement Learning", arXiv:1703.03864. Paper section 2.1.1 of
Pourchot, Perrin & Sigaud (2018): "the covariance matrix of the Gaussian noise is
fixed to sigma^2 I_d ... only the mean is updated through vanilla gradient descent".

One generation, with utilities u_k (higher is better) of the n told samples x_k::

    eps_k = (x_k - mu) / sigma                   # standardised perturbation
    g     = sum_k u_k eps_k / (n sigma)          # vanilla gradient of E[u] w.r.t. mu
    mu   <- mu + Adam(g)                         # ascent, lr 0.01, beta1 0.99, beta2 0.999

No antithetic sampling: the perturbations are recovered from the samples, so any
sample of the current distribution (fresh or reused by importance mixing) counts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from imix_cli.core.algorithms.base import Adam, CompiledStep, EvolutionStrategy, Params, _array_like, adam_step, prefixed, unprefixed
from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.numerics import linalg_kernels as lk


@njit(cache=True)
def openes_update(samples, utilities, state, counts, constants):
    """One generation of OpenES (module docstring), in place: ``state`` rows mu, sigma (per coordinate),
    Adam's m and v; ``counts`` Adam's step count; ``constants`` sigma, lr, beta1, beta2, epsilon.
    The one copy of the update (:class:`~imix_cli.core.algorithms.base.CompiledStep`): :meth:`OpenES._update`
    and the compiled generation loop both run it."""
    n, d = samples.shape
    mu, sigma = state[0], constants[0]
    eps = np.empty((n, d))
    for i in range(n):
        for j in range(d):
            eps[i, j] = (samples[i, j] - mu[j]) / sigma
    grad = lk.vec_mat_kernel(utilities, eps)  # one fixed summation order (not BLAS's): same bits on every CPU
    scale = n * sigma
    for j in range(d):
        grad[j] = grad[j] / scale
    step = adam_step(state[2], state[3], counts, 0, constants[1], constants[2], constants[3], constants[4], grad)
    for j in range(d):
        mu[j] = mu[j] + step[j]


@dataclass(frozen=True)
class OpenESParams(Params):
    """:class:`~imix_cli.core.algorithms.base.Params` (``sigma`` stays fixed for the whole run;
    ``lr`` is Adam's learning rate, paper: 0.01) and OpenES's own options."""

    #: Adam's first-moment decay (paper section 4.1).
    beta1: float = 0.99
    #: Adam's second-moment decay (paper section 4.1).
    beta2: float = 0.999


class OpenES(EvolutionStrategy):
    """OpenES: N(mu, sigma^2 I) with sigma fixed; mu follows Adam on the vanilla gradient.

    ``OpenES(dim, params=None, *, mean=None, **fields)``: see
    :class:`~imix_cli.core.algorithms.base.EvolutionStrategy` and :class:`OpenESParams`.
    """

    name = "openes"
    weights_utilities = "mean"  # its move is a mean over members of u_k times a function of x_k: weighted reuse applies
    Params = OpenESParams

    def _setup(self) -> None:
        self._mu = self.initial_mean.copy()
        self.optimizer = Adam(self.dim, lr=self.lr, beta1=self.params.beta1, beta2=self.params.beta2)
        self._dist = DiagonalGaussian(self._mu, self.sigma)

    @property
    def distribution(self) -> DiagonalGaussian:
        return self._dist

    def _update(self, samples: np.ndarray, utilities: np.ndarray) -> None:
        self._update_compiled(samples, utilities)

    def compiled_step(self) -> CompiledStep:
        o = self.optimizer
        state = np.stack([self._mu, self._dist.std, o.m, o.v])
        constants = np.array([self.sigma, o.lr, o.beta1, o.beta2, o.epsilon], dtype=np.float64)
        return CompiledStep(openes_update, state, np.array([o.t], dtype=np.int64), constants)

    def load_compiled_state(self, state: np.ndarray, counts: np.ndarray) -> None:
        self._mu = state[0].copy()
        self.optimizer.m, self.optimizer.v, self.optimizer.t = state[2].copy(), state[3].copy(), int(counts[0])
        self._dist = DiagonalGaussian(self._mu, self.sigma)

    def _state_dict(self) -> dict:
        return {"mu": self._mu.copy(), **prefixed("optimizer", self.optimizer.state_dict())}

    def _load_state_dict(self, state: dict) -> None:
        self._mu = _array_like(state["mu"], self._mu, "mu")
        self.optimizer.load_state_dict(unprefixed("optimizer", state))
        self._dist = DiagonalGaussian(self._mu, self.sigma)
