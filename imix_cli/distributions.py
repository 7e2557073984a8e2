"""Gaussian search distributions: draw samples and evaluate log-densities.

Both classes expose the two operations importance mixing needs:

* ``sample(n, rng)`` -> ``(n, d)`` array drawn with a ``numpy.random.Generator``;
* ``log_prob(x)``    -> ``(n,)`` log-densities of the rows of ``x``.

Densities are only ever handled in log space: at d = 10^4 a Gaussian density
under- or overflows float64, while its logarithm is an ordinary number.

``DiagonalGaussian`` (OpenES, SNES, CEM) costs O(d) per sample. Rows are
processed in blocks so that temporaries stay small and cache-resident even at
d = 10^6, and sums are accumulated in float64 whatever the storage dtype.
``FullGaussian`` (CMA-ES) works through the Cholesky factor of the covariance.
"""

from __future__ import annotations

import numpy as np

_LOG_2PI = float(np.log(2.0 * np.pi))
# Elements per block in the row-blocked kernels: ~4 MB of float64, small enough
# to stay in cache, large enough that numpy's per-call overhead is negligible.
_BLOCK_ELEMENTS = 1 << 19


def _row_blocks(n_rows: int, dim: int):
    """Yield slices over rows so that each block holds about _BLOCK_ELEMENTS numbers."""
    step = max(1, _BLOCK_ELEMENTS // max(dim, 1))
    for start in range(0, n_rows, step):
        yield slice(start, min(start + step, n_rows))


class DiagonalGaussian:
    """N(mean, diag(std**2)).

    Parameters
    ----------
    mean, std : array-like of shape (d,)
        Mean and per-coordinate standard deviation (all > 0). A scalar ``std``
        is broadcast to an isotropic distribution.
    dtype : numpy dtype, default float64
        Dtype of the samples returned by :meth:`sample`. float32 halves memory
        and RNG time at very large d (10^5-10^6); densities are still
        accumulated in float64.
    """

    def __init__(self, mean, std, dtype=np.float64):
        self.mean = np.array(mean, dtype=np.float64, copy=True).reshape(-1)
        std = np.asarray(std, dtype=np.float64)
        self.std = np.array(np.broadcast_to(std, self.mean.shape), dtype=np.float64)
        if not np.all(self.std > 0) or not np.all(np.isfinite(self.std)):
            raise ValueError("DiagonalGaussian: std must be finite and > 0 in every coordinate")
        if not np.all(np.isfinite(self.mean)):
            raise ValueError("DiagonalGaussian: mean must be finite")
        self.dtype = np.dtype(dtype)
        # log of the normalising constant: -d/2 log(2 pi) - sum(log std)
        self._log_norm = -0.5 * self.dim * _LOG_2PI - float(np.sum(np.log(self.std)))

    @property
    def dim(self) -> int:
        return self.mean.shape[0]

    @property
    def sigma_mean(self) -> float:
        """Mean standard deviation over coordinates (the CSV's ``sigma_mean``)."""
        return float(np.mean(self.std))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Draw ``n`` independent samples, shape ``(n, d)``."""
        return self.sample_with_log_prob(n, rng)[0]

    def sample_with_log_prob(self, n: int, rng: np.random.Generator):
        """Draw ``n`` samples and return ``(samples, log_prob(samples))``.

        The log-density of a fresh draw follows from the standard normal noise
        alone (``-|eps|^2/2 + const``), which is much cheaper than evaluating
        :meth:`log_prob` on the samples afterwards.
        """
        eps = rng.standard_normal((n, self.dim), dtype=self.dtype)
        sq_norm = np.empty(n)
        for rows in _row_blocks(n, self.dim):
            block = eps[rows]
            sq_norm[rows] = np.einsum("ij,ij->i", block, block, dtype=np.float64)
            block *= self.std.astype(self.dtype, copy=False)
            block += self.mean.astype(self.dtype, copy=False)
        return eps, self._log_norm - 0.5 * sq_norm

    def log_prob(self, x) -> np.ndarray:
        """Log-density of each row of ``x`` (shape ``(n, d)`` or ``(d,)``)."""
        x = np.atleast_2d(x)
        inv_std = 1.0 / self.std
        shifted_mean = self.mean * inv_std
        sq = np.empty(x.shape[0])
        for rows in _row_blocks(x.shape[0], self.dim):
            z = x[rows] * inv_std  # float64 temporary, one block only
            z -= shifted_mean
            sq[rows] = np.einsum("ij,ij->i", z, z)
        return self._log_norm - 0.5 * sq

    def __repr__(self) -> str:
        return f"DiagonalGaussian(dim={self.dim}, sigma_mean={self.sigma_mean:.4g})"


class FullGaussian:
    """N(mean, cov) with a full covariance matrix, through its Cholesky factor L (cov = L L^T)."""

    def __init__(self, mean, cov, dtype=np.float64):
        self.mean = np.array(mean, dtype=np.float64, copy=True).reshape(-1)
        cov = np.array(cov, dtype=np.float64, copy=True)
        if cov.shape != (self.dim, self.dim):
            raise ValueError(f"FullGaussian: cov has shape {cov.shape}, expected {(self.dim, self.dim)}")
        self.cov = 0.5 * (cov + cov.T)  # symmetrise round-off
        try:
            self.chol = np.linalg.cholesky(self.cov)
        except np.linalg.LinAlgError as err:
            raise ValueError("FullGaussian: cov is not positive definite") from err
        self.dtype = np.dtype(dtype)
        self._log_norm = -0.5 * self.dim * _LOG_2PI - float(np.sum(np.log(np.diag(self.chol))))

    @property
    def dim(self) -> int:
        return self.mean.shape[0]

    @property
    def std(self) -> np.ndarray:
        """Marginal standard deviations, sqrt(diag(cov))."""
        return np.sqrt(np.diag(self.cov))

    @property
    def sigma_mean(self) -> float:
        return float(np.mean(self.std))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return self.sample_with_log_prob(n, rng)[0]

    def sample_with_log_prob(self, n: int, rng: np.random.Generator):
        eps = rng.standard_normal((n, self.dim))
        x = self.mean + eps @ self.chol.T
        return x.astype(self.dtype, copy=False), self._log_norm - 0.5 * np.einsum("ij,ij->i", eps, eps)

    def log_prob(self, x) -> np.ndarray:
        from scipy.linalg import solve_triangular

        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        # Solve L z = (x - mean)^T: z is the whitened sample, |z|^2 the squared Mahalanobis distance.
        z = solve_triangular(self.chol, (x - self.mean).T, lower=True, check_finite=False)
        return self._log_norm - 0.5 * np.einsum("ij,ij->j", z, z)

    def __repr__(self) -> str:
        return f"FullGaussian(dim={self.dim}, sigma_mean={self.sigma_mean:.4g})"
