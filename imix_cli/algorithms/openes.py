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

import numpy as np

from imix_cli.algorithms.base import Adam, EvolutionStrategy
from imix_cli.distributions import DiagonalGaussian


class OpenES(EvolutionStrategy):
    """OpenES: N(mu, sigma^2 I) with sigma fixed; mu follows Adam on the vanilla gradient.

    Parameters
    ----------
    dim, popsize, sigma, lr, weight_decay, weight_decay_form, mean
        See :class:`~imix_cli.algorithms.base.EvolutionStrategy`. ``sigma`` stays
        fixed for the whole run; ``lr`` is Adam's learning rate (paper: 0.01).
    beta1 : float, default 0.99
        Adam's first-moment decay (paper section 4.1).
    beta2 : float, default 0.999
        Adam's second-moment decay (paper section 4.1).
    """

    name = "openes"

    def __init__(
        self,
        dim: int,
        popsize: int = 50,
        sigma: float = 0.25,
        lr: float = 0.01,
        weight_decay: float = 0.05,
        weight_decay_form: str = "estool",
        mean=None,
        beta1: float = 0.99,
        beta2: float = 0.999,
    ):
        super().__init__(dim, popsize, sigma, lr, weight_decay, weight_decay_form, mean)
        self._mu = self.initial_mean.copy()
        self.optimizer = Adam(self.dim, lr=self.lr, beta1=beta1, beta2=beta2)
        self._dist = DiagonalGaussian(self._mu, self.sigma)

    @property
    def distribution(self) -> DiagonalGaussian:
        return self._dist

    def _update(self, samples: np.ndarray, utilities: np.ndarray) -> None:
        n = samples.shape[0]
        eps = (samples - self._mu) / self.sigma
        grad = (utilities @ eps) / (n * self.sigma)
        self._mu = self._mu + self.optimizer.step(grad)
        self._dist = DiagonalGaussian(self._mu, self.sigma)
