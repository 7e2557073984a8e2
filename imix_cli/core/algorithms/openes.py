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
from typing import NamedTuple

import numpy as np
from numba import njit

from imix_cli.core.algorithms.base import ADAM_EPSILON, AdamState, CompiledStep, EvolutionStrategy, Params, adam_step
from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.numerics import linalg_kernels as lk


class OpenESState(NamedTuple):
    """OpenES's search state, the one record that ``tell``, the compiled loop and the checkpoint use
    (:class:`~imix_cli.core.algorithms.base.CompiledStep`)."""

    #: mu, the mean searched, shape (d,)
    mean: np.ndarray
    #: sigma in every coordinate, shape (d,) (fixed: the compiled loop reads it as every diagonal ES's)
    std: np.ndarray
    #: Adam on mu
    adam: AdamState


class OpenESConstants(NamedTuple):
    """What :func:`openes_update` reads besides the state (never written)."""

    sigma: float
    lr: float
    beta1: float
    beta2: float
    epsilon: float


@njit(cache=True)
def openes_update(samples, utilities, state, constants):
    """One generation of OpenES (module docstring), in place of ``state`` (:class:`OpenESState`).
    The one copy of the update (:class:`~imix_cli.core.algorithms.base.CompiledStep`): :meth:`OpenES._update`
    and the compiled generation loop both run it."""
    n, d = samples.shape
    c = constants
    mu, sigma = state.mean, c.sigma
    eps = np.empty((n, d))
    for i in range(n):
        for j in range(d):
            eps[i, j] = (samples[i, j] - mu[j]) / sigma
    grad = lk.vec_mat_kernel(utilities, eps)  # one fixed summation order (not BLAS's): same bits on every CPU
    scale = n * sigma
    for j in range(d):
        grad[j] = grad[j] / scale
    step = adam_step(state.adam, c.lr, c.beta1, c.beta2, c.epsilon, grad)
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
        self.set_state(OpenESState(self.initial_mean.copy(), np.full(self.dim, self.sigma), AdamState.zeros(self.dim)))

    @property
    def distribution(self) -> DiagonalGaussian:
        return self._dist

    def _update(self, samples: np.ndarray, utilities: np.ndarray) -> None:
        self._update_compiled(samples, utilities)

    def compiled_step(self) -> CompiledStep:
        return CompiledStep(openes_update, OpenESConstants(self.sigma, self.lr, self.params.beta1, self.params.beta2, ADAM_EPSILON))
