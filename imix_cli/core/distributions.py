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

Every dot product and matrix product here is :mod:`imix_cli.core.numerics.linalg_kernels`' (one fixed
summation order), not BLAS's, whose kernel -- and so whose last bits -- depends on the CPU.
"""

from __future__ import annotations

import functools
from typing import Protocol, runtime_checkable

import numpy as np

from imix_cli.core import numerics as xp

# Elements per block in the row-blocked kernels: ~4 MB of float64, small enough
# to stay in cache, large enough that numpy's per-call overhead is negligible.
_BLOCK_ELEMENTS = 1 << 19


# Above this dimension, rows are processed one at a time in column chunks of this many numbers
# (512 KB of float64, L2-resident): whole-row temporaries at d = 10^6 would spill to memory.
_CHUNK = 1 << 16


def _whitened_sq_norms(x: np.ndarray, rows: np.ndarray, mean: np.ndarray, inv_std: np.ndarray) -> np.ndarray:
    """sum(((x[r] - mean) * inv_std)**2) for each r in ``rows``, accumulated in float64."""
    dim = x.shape[1]
    out = np.empty(rows.shape[0])
    if dim < _CHUNK:  # small d: vectorised over blocks of rows, few numpy calls
        for block in _row_blocks(rows.shape[0], dim):
            z = x[rows[block]] - mean  # float64 temporary of one block
            z *= inv_std
            out[block] = np.einsum("ij,ij->i", z, z)
        return out
    buf = np.empty(_CHUNK)
    for k, r in enumerate(rows):
        row, acc = x[r], 0.0
        for c in range(0, dim, _CHUNK):
            seg = buf[: min(_CHUNK, dim - c)]
            np.subtract(row[c : c + _CHUNK], mean[c : c + _CHUNK], out=seg)
            seg *= inv_std[c : c + _CHUNK]
            acc += xp.dot(seg, seg)
        out[k] = acc
    return out


def _quadratic_row_sums(x, quad, lin, rows=None, shift=None, affine=None) -> np.ndarray:
    """sum_j (quad_j * y_j + lin_j) * y_j for each selected row, with y = x[r] - shift.

    ``quad``, ``lin`` and ``shift`` must have the dtype of ``x``. Computed in that dtype (float32 at large d) with pairwise summation, chunk
    by chunk, accumulated in float64: the terms are small when two distributions are
    close, so this is accurate where acceptance probabilities are not 0 or 1.
    ``affine=(std, mean)`` additionally turns each row of noise into a sample in place,
    x[r] = x[r] * std + mean, while the row is in cache.
    """
    dim = x.shape[1]
    n_rows = x.shape[0] if rows is None else rows.shape[0]
    if dim < _CHUNK and n_rows * dim <= _BLOCK_ELEMENTS:  # one block of the path below, in fewest numpy calls
        y = x if rows is None else x[rows]
        if shift is not None:
            y = y - shift
        t = y * quad
        t += lin
        t *= y
        out = np.add.reduce(t, axis=1).astype(np.float64, copy=False)  # pairwise, per row, as in blocks
        if affine is not None:
            if rows is None:
                x *= affine[0]
                x += affine[1]
            else:
                x[rows] = x[rows] * affine[0] + affine[1]
        return out
    rows = np.arange(x.shape[0]) if rows is None else rows
    out = np.zeros(rows.shape[0])
    if dim < _CHUNK:  # small d: vectorised over blocks of rows
        for block in _row_blocks(rows.shape[0], dim):
            y = x[rows[block]]
            if shift is not None:
                y = y - shift
            t = y * quad
            t += lin
            t *= y
            out[block] = t.sum(axis=1)
        if affine is not None:
            x[rows] = x[rows] * affine[0] + affine[1]
        return out
    y_buf, t_buf = np.empty(_CHUNK, dtype=x.dtype), np.empty(_CHUNK, dtype=x.dtype)
    for k, r in enumerate(rows):
        row = x[r]
        for c in range(0, dim, _CHUNK):
            cols, width = slice(c, c + _CHUNK), min(_CHUNK, dim - c)
            y = row[cols] if shift is None else np.subtract(row[cols], shift[cols], out=y_buf[:width])
            t = np.multiply(y, quad[cols], out=t_buf[:width])
            t += lin[cols]
            t *= y
            out[k] += float(t.sum())
            if affine is not None:
                row[cols] *= affine[0][cols]
                row[cols] += affine[1][cols]
    return out


def _row_blocks(n_rows: int, dim: int):
    """Yield slices over rows so that each block holds about _BLOCK_ELEMENTS numbers."""
    step = max(1, _BLOCK_ELEMENTS // max(dim, 1))
    for start in range(0, n_rows, step):
        yield slice(start, min(start + step, n_rows))


@functools.cache
def _strict_upper(dim: int) -> np.ndarray:
    """Mask of the entries above the diagonal of a (dim, dim) matrix."""
    return ~np.tri(dim, dtype=bool)


def _float_dtype(name) -> np.dtype:
    """A sample dtype read back from a state: float32 or float64 only (ValueError otherwise)."""
    dtype = np.dtype(str(name))
    if dtype not in (np.float32, np.float64):
        raise ValueError(f"sample dtype {name!r} is not float32 or float64")
    return dtype


@runtime_checkable
class SearchDistribution(Protocol):
    """What :func:`imix_cli.core.mixing.mix` needs of a search distribution (any class with these works).

    DiagonalGaussian and FullGaussian implement it; between two DiagonalGaussians ``mix`` also
    uses their ``mean``/``std`` (log-ratios without densities, and the compiled step).
    """

    @property
    def dim(self) -> int:
        """Number of coordinates d."""

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` independent draws, shape ``(n, d)``, from ``rng``."""

    def log_prob(self, x: np.ndarray) -> np.ndarray:
        """Log-density of each row of ``x`` (shape ``(n, d)``), shape ``(n,)``."""

    # Optional: ``dtype`` (the samples' dtype, float64 if absent).


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
        self._cast = None  # mean and std in the sample dtype, made on first use
        self._inv_std = 1.0 / self.std
        # log of the normalising constant: -d/2 log(2 pi) - sum(log std)
        self.log_norm = -0.5 * self.dim * xp.LOG_2PI - float(np.sum(xp.log(self.std)))

    @property
    def dim(self) -> int:
        return self.mean.shape[0]

    @property
    def sigma_mean(self) -> float:
        """Mean standard deviation over coordinates (the CSV's ``sigma_mean``)."""
        return float(np.mean(self.std))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Draw ``n`` independent samples, shape ``(n, d)``."""
        x = rng.standard_normal((n, self.dim), dtype=self.dtype)
        mean, std = self._mean_std_in_dtype()
        for rows in _row_blocks(n, self.dim):
            block = x[rows]
            block *= std
            block += mean
        return x

    def sample_with_log_prob(self, n: int, rng: np.random.Generator):
        """Draw ``n`` samples (the same random numbers as :meth:`sample`) and their log-densities."""
        eps = rng.standard_normal((n, self.dim), dtype=self.dtype)
        sq_norm = np.einsum("ij,ij->i", eps, eps, dtype=np.float64)
        mean, std = self._mean_std_in_dtype()
        for rows in _row_blocks(n, self.dim):
            block = eps[rows]
            block *= std
            block += mean
        return eps, self.log_norm - 0.5 * sq_norm

    def log_ratio_to(self, other: DiagonalGaussian) -> DiagonalLogRatio:
        """The log-density ratio log(p_self / p_other), with its per-coordinate coefficients computed once."""
        return DiagonalLogRatio(self, other)

    def log_prob(self, x, rows=None) -> np.ndarray:
        """Log-density of each row of ``x`` (shape ``(n, d)`` or ``(d,)``), or of ``x[rows]`` only.

        Passing ``rows`` avoids copying the selected rows out of a large array first.
        """
        x = np.atleast_2d(x)
        rows = np.arange(x.shape[0]) if rows is None else np.asarray(rows)
        return self.log_norm - 0.5 * _whitened_sq_norms(x, rows, self.mean, self._inv_std)

    def _precision(self) -> np.ndarray:
        """1 / std**2, computed once per distribution (it enters every log-ratio it is part of)."""
        w = self.__dict__.get("_w")  # computed on first use, then kept
        if w is None:
            w = self._w = self._inv_std**2
        return w

    def _mean_std_in_dtype(self):
        if self._cast is None:
            self._cast = (self.mean.astype(self.dtype), self.std.astype(self.dtype))
        return self._cast

    def to_state(self) -> dict:
        """Mean, std and sample dtype: a flat dict of arrays and JSON scalars (see :meth:`from_state`)."""
        return {"mean": self.mean.copy(), "std": self.std.copy(), "dtype": self.dtype.str}

    @classmethod
    def from_state(cls, state: dict) -> DiagonalGaussian:
        """The distribution :meth:`to_state` described (ValueError if it is not a valid one)."""
        return cls(state["mean"], state["std"], dtype=_float_dtype(state["dtype"]))

    def __repr__(self) -> str:
        return f"DiagonalGaussian(dim={self.dim}, sigma_mean={self.sigma_mean:.4g})"


class DiagonalLogRatio:
    """log(p_new(x) / p_old(x)) between two DiagonalGaussians, without forming either density.

    Importance mixing needs only this ratio. Written as a sum over coordinates of terms that
    vanish when the two distributions coincide, it stays accurate when summed in float32 at
    d = 10^6 (pairwise summation per chunk, float64 across chunks), and its coefficients are
    computed once per pair of distributions and reused for every row.
    """

    def __init__(self, new: DiagonalGaussian, old: DiagonalGaussian):
        if new.dim != old.dim:
            raise ValueError(f"dimensions differ: {new.dim} vs {old.dim}")
        self.new, self.old = new, old
        dtype = new.dtype
        w_new, w_old = new._precision(), old._precision()
        delta = new.mean - old.mean
        # Old rows: y = x - m_old gives -1/2 sum[(w_new - w_old) y^2 - 2 delta w_new y] + const.
        # (astype(copy=False): no copy when the sample dtype is float64; all are read-only here.)
        self._old_mean = old.mean.astype(dtype, copy=False)
        self._row_quad = (w_new - w_old).astype(dtype, copy=False)
        self._row_lin = (-2.0 * delta * w_new).astype(dtype, copy=False)
        self._row_const = new.log_norm - old.log_norm - 0.5 * xp.dot(delta * delta, w_new)
        # Fresh draws x = m_new + s_new * eps, with a = delta/s_old, b = s_new/s_old:
        # 1/2 sum[-(1 - b^2) eps^2 + 2 a b eps] + 1/2 |a|^2 + const.
        a = delta * old._inv_std
        b = new.std * old._inv_std
        self._noise_quad = (-(1.0 - b * b)).astype(dtype, copy=False)
        self._noise_lin = (2.0 * a * b).astype(dtype, copy=False)
        self._noise_const = new.log_norm - old.log_norm + 0.5 * xp.dot(a, a)

    def of_rows(self, x: np.ndarray, rows=None) -> np.ndarray:
        """The log-ratio at each row of ``x`` (or of ``x[rows]``, without copying them out first)."""
        x = np.atleast_2d(x)
        rows = np.arange(x.shape[0]) if rows is None else np.asarray(rows)
        return self._row_const - 0.5 * _quadratic_row_sums(x, self._row_quad, self._row_lin, rows=rows, shift=self._old_mean)

    def sample(self, n: int, rng: np.random.Generator, out=None):
        """``n`` draws from p_new (the same random numbers as ``new.sample``) and their log-ratios.

        ``out`` (shape (n, d), the sample dtype) receives the samples: a reused scratch buffer
        avoids fresh page faults at large d.
        """
        eps = rng.standard_normal((n, self.new.dim), dtype=self.new.dtype, out=out)
        mean, std = self.new._mean_std_in_dtype()
        sums = _quadratic_row_sums(eps, self._noise_quad, self._noise_lin, affine=(std, mean))
        return eps, self._noise_const + 0.5 * sums


class FullGaussian:
    """N(mean, cov) with a full covariance matrix, through its Cholesky factor L (cov = L L^T)."""

    def __init__(self, mean, cov, dtype=np.float64):
        self.mean = np.array(mean, dtype=np.float64, copy=True).reshape(-1)
        cov = np.array(cov, dtype=np.float64, copy=True)
        if cov.shape != (self.dim, self.dim):
            raise ValueError(f"FullGaussian: cov has shape {cov.shape}, expected {(self.dim, self.dim)}")
        self._cov = 0.5 * (cov + cov.T)  # symmetrise round-off
        try:
            self.chol = xp.cholesky(self._cov)
        except np.linalg.LinAlgError as err:
            raise ValueError("FullGaussian: cov is not positive definite") from err
        self.dtype = np.dtype(dtype)
        self.log_norm = -0.5 * self.dim * xp.LOG_2PI - float(np.sum(xp.log(np.diag(self.chol))))

    @classmethod
    def from_cholesky(cls, mean, chol, dtype=np.float64, checked: bool = True, log_norm: float | None = None) -> FullGaussian:
        """N(mean, L L^T) from its lower-triangular factor L itself, never from L L^T factored again.

        Why: a Cholesky factorisation of C works at C's condition number, the square of its factor's; a library
        that keeps a square root of C (pycma's B D: :func:`imix_cli.core.adapters.pycma.gaussian_from_factor`
        turns it into L) gives the density at its own precision this way. ValueError (one line) if ``chol`` is
        not lower triangular with a finite, positive diagonal: the density does not exist. ``checked=False``: the
        caller has made ``chol`` a new float64 array and checked it (pycma's adapter, every generation: issue 45);
        ``log_norm``: the caller's, computed with ``chol`` as here (:func:`imix_cli.core.numerics.lower_from_r`), else
        computed here.
        """
        mean = np.array(mean, dtype=np.float64, copy=True).reshape(-1)
        dim = mean.shape[0]
        if checked:
            chol = np.array(chol, dtype=np.float64, copy=True)
            if chol.shape != (dim, dim):
                raise ValueError(f"FullGaussian: the factor has shape {chol.shape}, expected {(dim, dim)}")
        # in few numpy calls, and the covariance only when asked for: pycma's adapter makes one every generation (issue 45)
        if checked:
            diag = np.diag(chol)
            if not (np.isfinite(chol).all() and (diag > 0).all()) or chol[_strict_upper(dim)].any():
                raise ValueError("FullGaussian: the factor is not lower triangular with a positive diagonal (singular)")
        self = cls.__new__(cls)
        self.mean, self.chol, self._cov = mean, chol, None
        self.dtype = np.dtype(dtype)
        self.log_norm = -0.5 * dim * xp.LOG_2PI - float(np.sum(xp.log(np.diag(chol)))) if log_norm is None else log_norm
        return self

    @property
    def dim(self) -> int:
        return self.mean.shape[0]

    @property
    def cov(self) -> np.ndarray:
        """The covariance L L^T (made from L on first use where the distribution was made from its factor)."""
        if self._cov is None:
            self._cov = xp.mat_mat(self.chol, np.ascontiguousarray(self.chol.T))
        return self._cov

    @property
    def std(self) -> np.ndarray:
        """Marginal standard deviations, sqrt(diag(cov))."""
        return np.sqrt(np.diag(self.cov))

    @property
    def sigma_mean(self) -> float:
        return float(np.mean(self.std))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Draw ``n`` independent samples, shape ``(n, d)`` (the draws of :meth:`sample_with_log_prob`)."""
        eps = rng.standard_normal((n, self.dim))
        return (self.mean + xp.lower_times_rows(self.chol, eps)).astype(self.dtype, copy=False)

    def sample_with_log_prob(self, n: int, rng: np.random.Generator, other=None, out=None):
        """Draw ``n`` samples; return ``(samples, log_prob(samples))``, plus ``other.log_prob(samples)`` if given."""
        eps = rng.standard_normal((n, self.dim))
        x = (self.mean + xp.lower_times_rows(self.chol, eps)).astype(self.dtype, copy=False)
        if out is not None:
            out[...] = x
            x = out
        log_prob = self.log_norm - 0.5 * xp.row_sq_norms(eps)
        if other is None:
            return x, log_prob
        return x, log_prob, other.log_prob(x)

    def log_prob(self, x, rows=None) -> np.ndarray:
        """Log-density of each row of ``x`` (or of ``x[rows]``)."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        if rows is not None:
            x = x[np.asarray(rows)]
        # Solve L z = x - mean: z is the whitened sample, |z|^2 the squared Mahalanobis distance (one compiled call).
        return xp.gaussian_log_probs(self.chol[None], self.mean[None], np.array([self.log_norm]), x)[0]

    def to_state(self) -> dict:
        """Mean, covariance and sample dtype (the Cholesky factor is recomputed, bit for bit, on load)."""
        return {"mean": self.mean.copy(), "cov": self.cov.copy(), "dtype": self.dtype.str}

    @classmethod
    def from_state(cls, state: dict) -> FullGaussian:
        return cls(state["mean"], state["cov"], dtype=_float_dtype(state["dtype"]))

    def __repr__(self) -> str:
        return f"FullGaussian(dim={self.dim}, sigma_mean={self.sigma_mean:.4g})"


class FullGaussianStack:
    """The log-densities of the same rows under several FullGaussians, in one compiled call.

    Why: importance mixing with full covariances (pycma's adapter, imix's CMA-ES) asks for each batch of rule-2
    draws under the new distribution and every archived one; at small d a separate ``log_prob`` per distribution
    cost more in Python than in arithmetic (issue 45). Row for row the same bits as :meth:`FullGaussian.log_prob`.
    """

    def __init__(self, dists):
        self.dists = tuple(dists)
        self.lows = np.array([d.chol for d in self.dists])
        self.means = np.array([d.mean for d in self.dists])
        self.log_norms = np.array([d.log_norm for d in self.dists])

    def log_probs(self, x) -> np.ndarray:
        """(m, n): the log-density of each row of ``x`` (n, d) under each of the m distributions."""
        return xp.gaussian_log_probs(self.lows, self.means, self.log_norms, x)


class AffinePushforward:
    """The law of ``T(theta)`` for ``theta ~ base``, T an invertible affine map ``theta' = A theta + c``.

    Why: a search whose parameters change meaning (observation statistics that keep updating:
    :class:`imix_cli.core.evaluation.policies.NormalizerChange`) re-expresses every archived member as ``T(theta)``, the same
    policy in today's coordinates; its generation is then distributed as this pushforward, whose density is
    ``log p'(x) = log p(T^-1 x) - log|det A|``. Importance mixing reads it through ``log_prob`` like any
    :class:`SearchDistribution` (it is neither a DiagonalGaussian nor a FullGaussian, so mixing takes its generic
    path); heights ``log(y / p(x))`` are ratios to the density and stay what they were.

    ``transform``: an object with ``forward(x)``, ``inverse(x)`` (rows (n, d) -> new rows), a number ``log_det``
    (log|det A|), ``then(later)`` (the composition, for :meth:`then`) and ``to_state``/``from_state`` (checkpoints).
    """

    def __init__(self, base, transform):
        if isinstance(base, AffinePushforward):  # one map from the base's coordinates, never a tower of them
            base, transform = base.base, base.transform.then(transform)
        self.base, self.transform = base, transform
        self.dtype = np.dtype(getattr(base, "dtype", np.float64))

    @property
    def dim(self) -> int:
        return self.base.dim

    @property
    def mean(self) -> np.ndarray:
        """The mean ``A m + c`` (an affine map of the base's mean)."""
        return self.transform.forward(np.asarray(self.base.mean, dtype=np.float64)[None, :])[0]

    @property
    def sigma_mean(self) -> float:
        return float(self.base.sigma_mean)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` draws: the base's, mapped."""
        return self.transform.forward(self.base.sample(n, rng)).astype(self.dtype, copy=False)

    def log_prob(self, x, rows=None) -> np.ndarray:
        """Log-density of each row of ``x`` (or of ``x[rows]``): the base's at ``T^-1 x``, minus log|det A|."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        if rows is not None:
            x = x[np.asarray(rows)]
        return self.base.log_prob(self.transform.inverse(x)) - self.transform.log_det

    def pulled_back(self, x) -> np.ndarray:
        """``T^-1 x``: rows in the base's coordinates (mixing's whitening, variant ``"conditional"``)."""
        return self.transform.inverse(np.atleast_2d(np.asarray(x, dtype=np.float64)))

    def to_state(self) -> dict:
        """The base and the map, each saved as the value it is (checkpoints: data, not pickles)."""
        return {"base": self.base, "transform": self.transform}

    @classmethod
    def from_state(cls, state: dict) -> AffinePushforward:
        return cls(state["base"], state["transform"])

    def __repr__(self) -> str:
        return f"AffinePushforward({self.base!r}, {self.transform!r})"
