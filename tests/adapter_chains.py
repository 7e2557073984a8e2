"""The chain statistic of the adapters' tests (tests/test_adapters_pycma.py, tests/test_adapters_evosax.py).

Members mixed along a library's own path of distributions are whitened by the distribution of their
generation; if every generation is distributed as its distribution, the whitened members are N(0, I).
Members of one chain are correlated (a member is reused for several generations), so the standard
errors come from independent chains: per chain the mean of z and of z^2, across chains their z-scores,
as tests/test_mixing.py's chains.
"""

import numpy as np

from imix_cli.core.distributions import DiagonalGaussian


def whiten(dist, x) -> np.ndarray:
    """``x``'s rows in the coordinates in which ``dist`` is N(0, I)."""
    x = np.atleast_2d(np.asarray(x, dtype=np.float64)) - dist.mean
    if isinstance(dist, DiagonalGaussian):
        return x / dist.std
    return np.linalg.solve(dist.chol, x.T).T


def chain_z_scores(chains) -> tuple[float, float, float]:
    """``(z_mean, z_var, E[z^2])`` of whitened members, ``chains`` a list of one array of z per chain:
    the z-scores across chains of the per-chain mean of z (0 expected) and of z^2 (1 expected)."""
    first = np.array([z.mean() for z in chains])
    second = np.array([np.mean(z * z) for z in chains])
    n = len(chains)
    z_mean = first.mean() / (first.std(ddof=1) / np.sqrt(n))
    z_var = (second.mean() - 1) / (second.std(ddof=1) / np.sqrt(n))
    return float(z_mean), float(z_var), float(second.mean())
