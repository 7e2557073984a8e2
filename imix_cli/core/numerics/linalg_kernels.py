"""Linear algebra in one fixed summation order: the same bits on every CPU.

Why: numpy hands ``@``, ``np.dot`` and ``np.linalg`` to OpenBLAS/LAPACK, which choose a kernel
for the CPU at start-up; kernels block and vectorise sums differently, so a product's last bits
depend on the machine. An evolution strategy amplifies them: the main job (SNES + EIM on
CartPole, 25 seeds) ended at 192.46, 194.24 or 193.27 depending only on ``OPENBLAS_CORETYPE``.
Every product on a run's path is therefore computed here, by compiled loops whose order of
additions is written out below and cannot change with the CPU: numba emits no fused
multiply-adds and no reassociation without ``fastmath``, so vectorising a loop over
independent outputs leaves each output's sum as written. ``tests/test_same_numbers_everywhere.py``
runs whole jobs under three OpenBLAS kernels and requires identical files.

The order, for every sum here: ascending index, one running sum, starting from the first term
(``((a_0 b_0 + a_1 b_1) + a_2 b_2) + ...``). Dimensions are small (d <= 2000 for the full
matrices of CMA-ES, and the O(d) products are a few per generation), so plain loops cost
little next to the episodes.

The symmetric eigensolver is EISPACK's ``tred2`` (Householder reduction to tridiagonal form,
accumulating the transformations) and ``tql2`` (implicit QL with Wilkinson shifts), as in JAMA's
``EigenvalueDecomposition``: O(d^3) like LAPACK's ``dsyevd`` but without blocking, so slower at
large d (``benchmarks/cmaes_speed.py`` measures it) and, unlike LAPACK, the same on every CPU.
``tests/test_linalg_kernels.py`` checks it against ``numpy.linalg.eigh``.

Compilation: ``@njit(cache=True)``, float64 C-contiguous arrays only (the wrappers make them so);
the cache is stamped with every compiled source of the package (:mod:`imix_cli.core.numerics.numba_cache`).
Python code calls the wrappers through :mod:`imix_cli.core.numerics`; compiled code calls the kernels
(``vec_mat_kernel``, ``numpy_sum``, ...).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from imix_cli.core.numerics import elementary as el

__all__ = [
    "numpy_sum",
    "vec_mat_kernel",
    "dot",
    "vec_mat",
    "mat_vec",
    "mat_mat",
    "weighted_gram",
    "row_sq_norms",
    "exp",
    "log",
    "expm1",
    "tanh",
    "cholesky",
    "lower_times_rows",
    "lower_solve_rows",
    "gaussian_log_probs",
    "factor_kind",
    "lower_from_r",
    "eigh",
]


# ------------------------------------------------------------------------------------ kernels
@njit(cache=True)
def _dot(a, b):
    acc = 0.0
    for j in range(a.shape[0]):
        acc += a[j] * b[j]
    return acc


@njit(cache=True)
def _vec_mat(w, x):
    """out[j] = sum_i w[i] x[i, j], i ascending (the loop over j vectorises; each sum keeps its order)."""
    n, d = x.shape
    out = np.zeros(d)
    for i in range(n):
        wi = w[i]
        for j in range(d):
            out[j] += wi * x[i, j]
    return out


#: ``_vec_mat`` for other compiled code (the ES updates): the kernel itself, no argument conversion.
vec_mat_kernel = _vec_mat


@njit(cache=True)
def _mat_vec(a, x):
    """out[i] = sum_j a[i, j] x[j], j ascending from 0.0 (the sums of ``_vec_mat(x, a.T)``, without the transposed copy)."""
    n, d = a.shape
    out = np.empty(n)
    for i in range(n):
        acc = 0.0
        for j in range(d):
            acc += x[j] * a[i, j]
        out[i] = acc
    return out


#: ``_mat_vec`` for other compiled code (CMA-ES's update and distribution).
mat_vec_kernel = _mat_vec


# numpy's own summation order, for compiled code that must give the bits of a Python path's np.sum/np.mean
@njit(cache=True)
def _block_sum(a, lo, n):
    """numpy's pairwise_sum (numpy/_core/src/umath/loops_utils.h.src) of n <= 128 numbers: one loop
    below 8, else eight accumulators combined as a tree, then the remainder."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    last = n - n % 8
    while i < last:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True)
def _half(n):
    half = n // 2
    return half - half % 8


@njit(cache=True)
def _pairwise(a, lo, n):
    """numpy's pairwise_sum of ``a[lo:lo + n]``: above 128 numbers, the sum of the two halves (the
    first rounded down to a multiple of 8), each summed the same way. Written with an explicit
    stack: numba's on-disk cache does not reload self-recursive functions safely."""
    if n <= 128:
        return _block_sum(a, lo, n)
    los = np.empty(64, dtype=np.int64)
    ns = np.empty(64, dtype=np.int64)
    right = np.zeros(64, dtype=np.bool_)  # the pending node's left half is summed; its right is running
    left = np.empty(64)
    los[0], ns[0], right[0], top = lo, n, False, 1
    while True:
        i = top - 1
        if ns[i] > 128:  # descend into the left half
            los[top], ns[top], right[top] = los[i], _half(ns[i]), False
            top += 1
            continue
        v = _block_sum(a, los[i], ns[i])
        top -= 1
        while True:  # hand v up: a left half starts its sibling, a right half completes its parent
            if top == 0:
                return v
            p = top - 1
            if not right[p]:
                left[p], right[p] = v, True
                half = _half(ns[p])
                los[top], ns[top], right[top] = los[p] + half, ns[p] - half, False
                top += 1
                break
            v = left[p] + v
            top -= 1


@njit(cache=True)
def numpy_sum(a):
    """``np.sum(a)`` of a contiguous (n,) float64 array, the same bits (numpy's pairwise summation), for
    compiled code; ``numpy_sum(a) / n`` is ``np.mean(a)``."""
    return _pairwise(a, 0, a.shape[0])


@njit(cache=True)
def _mat_mat(a, b):
    """out[i, j] = sum_k a[i, k] b[k, j], k ascending."""
    n, m = a.shape
    p = b.shape[1]
    out = np.zeros((n, p))
    for i in range(n):
        for k in range(m):
            aik = a[i, k]
            for j in range(p):
                out[i, j] += aik * b[k, j]
    return out


@njit(cache=True)
def _weighted_gram(coef, v):
    """out[i, j] = sum_k (coef[k] v[k, i]) v[k, j], k ascending: sum_k coef_k v_k v_k^T."""
    n, d = v.shape
    out = np.zeros((d, d))
    for i in range(d):
        for k in range(n):
            a = coef[k] * v[k, i]
            for j in range(d):
                out[i, j] += a * v[k, j]
    return out


@njit(cache=True)
def _row_sq_norms(x):
    n, d = x.shape
    out = np.empty(n)
    for i in range(n):
        acc = 0.0
        for j in range(d):
            acc += x[i, j] * x[i, j]
        out[i] = acc
    return out


@njit(cache=True)
def _exp(x):
    out = np.empty_like(x)
    for j in range(x.shape[0]):
        out[j] = el.exp(x[j])
    return out


@njit(cache=True)
def _log(x):
    out = np.empty_like(x)
    for j in range(x.shape[0]):
        out[j] = el.log(x[j]) if x[j] > 0.0 else (-math.inf if x[j] == 0.0 else math.nan)
    return out


@njit(cache=True)
def _tanh_inplace(x):
    for j in range(x.shape[0]):
        x[j] = el.tanh_lanes(x[j])


@njit(cache=True)
def _expm1(x):
    out = np.empty_like(x)
    for j in range(x.shape[0]):
        out[j] = el.expm1(x[j])
    return out


@njit(cache=True)
def _cholesky(a):
    """Lower L with L L^T = a (reading a's lower triangle); ok = False if a is not positive definite."""
    d = a.shape[0]
    low = np.zeros((d, d))
    for j in range(d):
        acc = a[j, j]
        for k in range(j):
            acc -= low[j, k] * low[j, k]
        if not acc > 0.0:  # NaN too
            return low, False
        ljj = math.sqrt(acc)
        low[j, j] = ljj
        for i in range(j + 1, d):
            acc = a[i, j]
            for k in range(j):
                acc -= low[i, k] * low[j, k]
            low[i, j] = acc / ljj
    return low, True


@njit(cache=True)
def _lower_times_rows(low, e):
    """out[r] = low @ e[r] for each row r: out[r, i] = sum_{k <= i} low[i, k] e[r, k], k ascending."""
    n, d = e.shape
    out = np.empty((n, d))
    for r in range(n):
        for i in range(d):
            acc = 0.0
            for k in range(i + 1):
                acc += low[i, k] * e[r, k]
            out[r, i] = acc
    return out


#: From this many rows on, :func:`_lower_solve_rows` solves them together (measured: 2.8x at 50 rows, d = 130;
#: slower below ~12 rows, where the transposed copy costs more than it saves).
SOLVE_ROWS_TOGETHER = 16


@njit(cache=True)
def _lower_solve_rows(low, y):
    """z[r] with low @ z[r] = y[r] for each row r (forward substitution, k ascending).

    Each row's operations are the same and in the same order either way; many rows are solved
    together with the loop over rows innermost, so that it vectorises (the rows are independent),
    where a row alone is a chain of dependent subtractions (CMA-ES's mixing: ~30 % of its run)."""
    n, d = y.shape
    if n < SOLVE_ROWS_TOGETHER:
        z = np.empty((n, d))
        for r in range(n):
            for i in range(d):
                acc = y[r, i]
                for k in range(i):
                    acc -= low[i, k] * z[r, k]
                z[r, i] = acc / low[i, i]
        return z
    zt = np.empty((d, n))  # z transposed: row k of it holds z[:, k], contiguous
    acc = np.empty(n)
    for i in range(d):
        for r in range(n):
            acc[r] = y[r, i]
        for k in range(i):
            lik = low[i, k]
            for r in range(n):
                acc[r] -= lik * zt[k, r]
        lii = low[i, i]
        for r in range(n):
            zt[i, r] = acc[r] / lii
    return np.ascontiguousarray(zt.T)


@njit(cache=True)
def _gaussian_log_probs(lows, means, log_norms, x):
    """out[j, r] = log_norms[j] - 0.5 |z|^2 with lows[j] z = x[r] - means[j]: the log-density of each row of x
    under each of several Gaussians N(means[j], lows[j] lows[j]^T).

    Bit for bit ``log_norms[j] - 0.5 * row_sq_norms(lower_solve_rows(lows[j], x - means[j]))``, row by row (the same
    subtraction, forward substitution with k ascending, sum of squares with i ascending from 0.0), in one call:
    importance mixing with full covariances asks for the same rows under up to four distributions at once, and at
    small d each separate call cost more in Python than the arithmetic (the pycma adapter, issue 45)."""
    m, d = means.shape
    n = x.shape[0]
    out = np.empty((m, n))
    if n < SOLVE_ROWS_TOGETHER:
        z = np.empty(d)
        for j in range(m):
            for r in range(n):
                sq = 0.0
                for i in range(d):
                    acc = x[r, i] - means[j, i]
                    for k in range(i):
                        acc -= lows[j, i, k] * z[k]
                    zi = acc / lows[j, i, i]
                    z[i] = zi
                    sq += zi * zi
                out[j, r] = log_norms[j] - 0.5 * sq
        return out
    # Many rows: solved together, the loop over rows innermost (as _lower_solve_rows: one row is a chain of dependent
    # subtractions; rows side by side vectorise), each row's operations the same and in the same order.
    xt = np.ascontiguousarray(x.T)
    zt = np.empty((d, n))
    acc = np.empty(n)
    sq = np.empty(n)
    for j in range(m):
        for r in range(n):
            sq[r] = 0.0
        for i in range(d):
            mi = means[j, i]
            for r in range(n):
                acc[r] = xt[i, r] - mi
            for k in range(i):
                lik = lows[j, i, k]
                for r in range(n):
                    acc[r] -= lik * zt[k, r]
            lii = lows[j, i, i]
            for r in range(n):
                zi = acc[r] / lii
                zt[i, r] = zi
                sq[r] += zi * zi
        for r in range(n):
            out[j, r] = log_norms[j] - 0.5 * sq[r]
    return out


@njit(cache=True)
def _factor_kind(a):
    """0 if the square ``a`` is diagonal (every entry off the diagonal 0, none NaN) with a finite diagonal; else 1
    if every entry is finite, 2 if not."""
    d = a.shape[0]
    diagonal, finite = True, True
    for i in range(d):
        for j in range(d):
            v = a[i, j]
            if not math.isfinite(v):
                finite = False
            if i != j and v != 0.0:
                diagonal = False
    if diagonal and finite:
        return 0
    return 1 if finite else 2


@njit(cache=True)
def _lower_from_r(r):
    """(L, log_norm, ok) from a QR factorisation's R (the upper triangle of ``r``; below it LAPACK's geqrf keeps its
    reflectors, never read): L = R^T, each column's sign flipped so that L's diagonal is positive, and log_norm =
    -d/2 log(2 pi) - sum_j log L[j, j] in numpy's summation order. ok = False where R has a non-finite entry or a
    zero on its diagonal (singular). The same bits as ``np.tril((triu(r) * signs[:, None]).T)`` and
    :meth:`imix_cli.core.distributions.FullGaussian.from_cholesky`'s log_norm of it (signs: -1 where R's diagonal is
    negative), in one call: the pycma adapter makes one every generation (numpy's dozen small calls cost more)."""
    d = r.shape[0]
    low = np.zeros((d, d))
    for j in range(d):
        if r[j, j] == 0.0:
            return low, 0.0, False
        for i in range(j, d):
            if not math.isfinite(r[j, i]):
                return low, 0.0, False
    logs = np.empty(d)
    for j in range(d):
        sign = -1.0 if r[j, j] < 0.0 else 1.0
        for i in range(j, d):
            low[i, j] = r[j, i] * sign
        logs[j] = el.log(low[j, j])
    return low, -0.5 * d * el.LOG_2PI - numpy_sum(logs), True


@njit(cache=True)
def _hypot(a, b):
    """sqrt(a^2 + b^2) without overflow, in basic IEEE operations only (libm's hypot may differ by CPU)."""
    a, b = abs(a), abs(b)
    big = max(a, b)
    if big == 0.0:
        return 0.0
    small = min(a, b) / big
    return big * math.sqrt(1.0 + small * small)


@njit(cache=True)
def _reduce_rows(w, d, e, i):
    """tred2's ``e[:i] = (A d)`` step (A: the leading i x i block, its upper triangle read) with ``w[i, :i] = d[:i]``:
    JAMA's loop, row j by row j, each row's sum ``g`` in ascending k and each ``e[k]`` gaining its rows' terms in
    ascending j -- but four rows at a time. Why: each row's sum is a chain of dependent additions (no fastmath: no
    reordering), so one row at a time leaves the CPU waiting on the adder; four independent chains keep it busy (the
    same operations, in the same order for every number: tests/test_linalg_kernels.py compares the bits with the
    one-row loop). This and :func:`_apply_reflections` were ~90 % of the eigendecomposition at d = 130."""
    for j in range(i):
        e[j] = 0.0
    j = 0
    while j + 4 <= i:
        f0, f1, f2, f3 = d[j], d[j + 1], d[j + 2], d[j + 3]
        w[i, j], w[i, j + 1], w[i, j + 2], w[i, j + 3] = f0, f1, f2, f3
        # the triangle: row j + r starts once rows j .. j + r - 1 have added their term to e[j + r]
        g0 = e[j] + w[j, j] * f0
        g0 += w[j, j + 1] * d[j + 1]
        e[j + 1] += w[j, j + 1] * f0
        g1 = e[j + 1] + w[j + 1, j + 1] * f1
        g0 += w[j, j + 2] * d[j + 2]
        e[j + 2] += w[j, j + 2] * f0
        g1 += w[j + 1, j + 2] * d[j + 2]
        e[j + 2] += w[j + 1, j + 2] * f1
        g2 = e[j + 2] + w[j + 2, j + 2] * f2
        g0 += w[j, j + 3] * d[j + 3]
        e[j + 3] += w[j, j + 3] * f0
        g1 += w[j + 1, j + 3] * d[j + 3]
        e[j + 3] += w[j + 1, j + 3] * f1
        g2 += w[j + 2, j + 3] * d[j + 3]
        e[j + 3] += w[j + 2, j + 3] * f2
        g3 = e[j + 3] + w[j + 3, j + 3] * f3
        for k in range(j + 4, i):  # the four rows side by side
            dk = d[k]
            a0, a1, a2, a3 = w[j, k], w[j + 1, k], w[j + 2, k], w[j + 3, k]
            g0 += a0 * dk
            g1 += a1 * dk
            g2 += a2 * dk
            g3 += a3 * dk
            ek = e[k]
            ek += a0 * f0
            ek += a1 * f1
            ek += a2 * f2
            ek += a3 * f3
            e[k] = ek
        e[j], e[j + 1], e[j + 2], e[j + 3] = g0, g1, g2, g3
        j += 4
    while j < i:  # the last rows, one at a time (JAMA's loop itself)
        f = d[j]
        w[i, j] = f
        g = e[j] + w[j, j] * f
        for k in range(j + 1, i):
            g += w[j, k] * d[k]
            e[k] += w[j, k] * f
        e[j] = g
        j += 1


@njit(cache=True)
def _apply_reflections(w, d, i):
    """tred2's accumulation step for column ``i``: each row j <= i of ``w`` loses ``(w[i+1] . w[j]) d`` (both over
    0..i; ``d`` holds w[i+1] / h). JAMA's loop, row by row, four rows at a time: their sums are independent
    (:func:`_reduce_rows` says why), each in ascending k as JAMA's."""
    j = 0
    while j + 4 <= i + 1:
        g0 = g1 = g2 = g3 = 0.0
        for k in range(i + 1):
            v = w[i + 1, k]
            g0 += v * w[j, k]
            g1 += v * w[j + 1, k]
            g2 += v * w[j + 2, k]
            g3 += v * w[j + 3, k]
        for k in range(i + 1):
            dk = d[k]
            w[j, k] -= g0 * dk
            w[j + 1, k] -= g1 * dk
            w[j + 2, k] -= g2 * dk
            w[j + 3, k] -= g3 * dk
        j += 4
    while j < i + 1:
        g = 0.0
        for k in range(i + 1):
            g += w[i + 1, k] * w[j, k]
        for k in range(i + 1):
            w[j, k] -= g * d[k]
        j += 1


@njit(cache=True)
def _tred2(w, d, e):
    """Householder tridiagonalisation (JAMA/EISPACK tred2) of the symmetric matrix ``w`` (its upper triangle is read).

    JAMA's algorithm on the transpose: JAMA's ``V[r][c]`` is ``w[c, r]`` here, so that its inner
    loops, which run down V's columns, run along w's rows (contiguous memory: 2.9 s -> 1.3 s at
    d = 1000); same operations in the same order, its two O(d^3) loops four rows at a time
    (:func:`_reduce_rows`, :func:`_apply_reflections`). On return ``d`` is the diagonal, ``e[1:]`` the
    subdiagonal and the rows of ``w`` are the orthogonal transform's columns.
    """
    n = w.shape[0]
    for j in range(n):
        d[j] = w[j, n - 1]
    for i in range(n - 1, 0, -1):
        scale = 0.0
        h = 0.0
        for k in range(i):
            scale += abs(d[k])
        if scale == 0.0:
            e[i] = d[i - 1]
            for j in range(i):
                d[j] = w[j, i - 1]
                w[j, i] = 0.0
                w[i, j] = 0.0
        else:
            for k in range(i):
                d[k] /= scale
                h += d[k] * d[k]
            f = d[i - 1]
            g = math.sqrt(h)
            if f > 0:
                g = -g
            e[i] = scale * g
            h = h - f * g
            d[i - 1] = f - g
            _reduce_rows(w, d, e, i)
            f = 0.0
            for j in range(i):
                e[j] /= h
                f += e[j] * d[j]
            hh = f / (h + h)
            for j in range(i):
                e[j] -= hh * d[j]
            for j in range(i):
                f = d[j]
                g = e[j]
                k = j
                while k + 4 <= i:  # written out four at a time: numba's loop alone ran ~1.5x slower (same numbers)
                    w[j, k] -= f * e[k] + g * d[k]
                    w[j, k + 1] -= f * e[k + 1] + g * d[k + 1]
                    w[j, k + 2] -= f * e[k + 2] + g * d[k + 2]
                    w[j, k + 3] -= f * e[k + 3] + g * d[k + 3]
                    k += 4
                while k < i:
                    w[j, k] -= f * e[k] + g * d[k]
                    k += 1
                d[j] = w[j, i - 1]
                w[j, i] = 0.0
        d[i] = h
    for i in range(n - 1):  # accumulate the transformations
        w[i, n - 1] = w[i, i]
        w[i, i] = 1.0
        h = d[i + 1]
        if h != 0.0:
            for k in range(i + 1):
                d[k] = w[i + 1, k] / h
            _apply_reflections(w, d, i)
        for k in range(i + 1):
            w[i + 1, k] = 0.0
    for j in range(n):
        d[j] = w[j, n - 1]
        w[j, n - 1] = 0.0
    w[n - 1, n - 1] = 1.0
    e[0] = 0.0


@njit(cache=True)
def _tql2(vt, d, e):
    """Implicit QL on the tridiagonal (d, e) (JAMA/EISPACK tql2), rotating the rows of ``vt``
    (the transform's columns, stored as rows so that each rotation runs over contiguous memory).

    Eigenvalues end in ``d``, ascending, eigenvectors in the rows of ``vt``. False if an
    eigenvalue did not converge in 30 iterations (LAPACK's limit per eigenvalue).
    """
    n = d.shape[0]
    for i in range(1, n):
        e[i - 1] = e[i]
    e[n - 1] = 0.0
    f = 0.0
    tst1 = 0.0
    eps = 2.0**-52
    for ll in range(n):
        tst1 = max(tst1, abs(d[ll]) + abs(e[ll]))
        m = ll
        while m < n - 1:  # e[n-1] is 0: the search always stops at n - 1
            if abs(e[m]) <= eps * tst1:
                break
            m += 1
        if m > ll:
            iterations = 0
            while True:
                iterations += 1
                if iterations > 30:
                    return False
                g = d[ll]
                p = (d[ll + 1] - g) / (2.0 * e[ll])
                r = _hypot(p, 1.0)
                if p < 0:
                    r = -r
                d[ll] = e[ll] / (p + r)
                d[ll + 1] = e[ll] * (p + r)
                dl1 = d[ll + 1]
                h = g - d[ll]
                for i in range(ll + 2, n):
                    d[i] -= h
                f += h
                p = d[m]
                c = 1.0
                c2 = c
                c3 = c
                el1 = e[ll + 1]
                s = 0.0
                s2 = 0.0
                for i in range(m - 1, ll - 1, -1):
                    c3 = c2
                    c2 = c
                    s2 = s
                    g = c * e[i]
                    h = c * p
                    r = _hypot(p, e[i])
                    e[i + 1] = s * r
                    s = e[i] / r
                    c = p / r
                    p = c * d[i] - s * g
                    d[i + 1] = h + s * (c * g + s * d[i])
                    for k in range(n):
                        h = vt[i + 1, k]
                        vt[i + 1, k] = s * vt[i, k] + c * h
                        vt[i, k] = c * vt[i, k] - s * h
                p = -s * s2 * c3 * el1 * e[ll] / dl1
                e[ll] = s * p
                d[ll] = c * p
                if not abs(e[ll]) > eps * tst1:
                    break
        d[ll] = d[ll] + f
        e[ll] = 0.0
    for i in range(n - 1):  # selection sort, ascending
        k = i
        p = d[i]
        for j in range(i + 1, n):
            if d[j] < p:
                k = j
                p = d[j]
        if k != i:
            d[k] = d[i]
            d[i] = p
            for j in range(n):
                t = vt[i, j]
                vt[i, j] = vt[k, j]
                vt[k, j] = t
    return True


@njit(cache=True)
def _eigh(a):
    """(eigenvalues ascending, eigenvectors as rows, ok) of the symmetric ``a`` (its lower triangle is read)."""
    n = a.shape[0]
    vt = np.ascontiguousarray(a.T)  # tred2 reads the upper triangle of a.T, i.e. a's lower one
    d = np.empty(n)
    e = np.empty(n)
    _tred2(vt, d, e)
    ok = _tql2(vt, d, e)
    return d, vt, ok


# ------------------------------------------------------------------------------------ wrappers
#: The kernels themselves, for compiled callers and for the warm-up's cache check (:mod:`imix_cli.running.warmup`).
eigh_kernel, cholesky_kernel, tanh_kernel, gaussian_log_probs_kernel = _eigh, _cholesky, _tanh_inplace, _gaussian_log_probs
mat_mat_kernel, weighted_gram_kernel, log_kernel = _mat_mat, _weighted_gram, _log


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def dot(a, b) -> float:
    """sum_j a[j] b[j] of two (d,) vectors, j ascending."""
    return float(_dot(_f64(a), _f64(b)))


def vec_mat(w, x) -> np.ndarray:
    """``w @ x`` for w (n,), x (n, d): out[j] = sum_i w[i] x[i, j], i ascending."""
    return _vec_mat(_f64(w), _f64(x))


def mat_vec(a, x) -> np.ndarray:
    """``a @ x`` for a (n, d), x (d,): out[i] = sum_j a[i, j] x[j], j ascending."""
    return _mat_vec(_f64(a), _f64(x))


def mat_mat(a, b) -> np.ndarray:
    """``a @ b`` for a (n, m), b (m, p): out[i, j] = sum_k a[i, k] b[k, j], k ascending."""
    return _mat_mat(_f64(a), _f64(b))


def weighted_gram(coef, v) -> np.ndarray:
    """sum_k coef[k] v[k] v[k]^T for v (n, d), k ascending: ``(coef * v.T) @ v``."""
    return _weighted_gram(_f64(coef), _f64(v))


def row_sq_norms(x) -> np.ndarray:
    """sum_j x[i, j]^2 of each row, j ascending (``einsum("ij,ij->i", x, x)``)."""
    return _row_sq_norms(_f64(x))


# numpy's float64 exp and log have AVX-512 versions of their own (and expm1 an SVML one) that
# other CPUs do not run, and the C library's differ between CPUs too (glibc's FMA and SSE2 builds):
# these loops compute them with imix_cli.core.numerics.elementary, the same bits on every CPU.
def exp(x) -> np.ndarray:
    """``np.exp`` of a (d,) vector (:func:`imix_cli.core.numerics.elementary.exp`)."""
    return _exp(_f64(x))


def log(x) -> np.ndarray:
    """``np.log`` of a (d,) vector, through libm (log(0) = -inf, log of a negative number NaN, no warning)."""
    return _log(_f64(x))


def expm1(x) -> np.ndarray:
    """``np.expm1`` of a (d,) vector (:func:`imix_cli.core.numerics.elementary.expm1`)."""
    return _expm1(_f64(x))


def tanh(x, out=None) -> np.ndarray:
    """``np.tanh(x, out=out)`` (:func:`imix_cli.core.numerics.elementary.tanh`), for float64 arrays of any shape (``out``
    C-contiguous, or None). numpy's float64 tanh has an AVX2 version and a baseline one that differ in the
    last bit; the C library's FMA and SSE2 builds differ too."""
    if out is None:
        out = np.array(x, dtype=np.float64, order="C")
    elif out is not x:
        np.copyto(out, x)
    _tanh_inplace(out.reshape(-1))
    return out


def cholesky(a) -> np.ndarray:
    """Lower Cholesky factor of the symmetric positive definite ``a``; numpy.linalg.LinAlgError otherwise."""
    low, ok = _cholesky(_f64(a))
    if not ok:
        raise np.linalg.LinAlgError("matrix is not positive definite")
    return low


def lower_times_rows(low, e) -> np.ndarray:
    """``e @ low.T`` for e (n, d) and lower-triangular ``low``: each row r becomes low @ e[r]."""
    return _lower_times_rows(_f64(low), _f64(e))


def lower_solve_rows(low, y) -> np.ndarray:
    """Each row r of y (n, d) solved as low z = y[r] (``solve_triangular(low, y.T, lower=True).T``)."""
    return _lower_solve_rows(_f64(low), _f64(y))


def gaussian_log_probs(lows, means, log_norms, x) -> np.ndarray:
    """(m, n) array: out[j, r] = log_norms[j] - 0.5 |lows[j]^-1 (x[r] - means[j])|^2 for m lower-triangular factors
    ``lows`` (m, d, d), means (m, d), log-normalisers (m,) and rows x (n, d); the same bits as
    ``log_norms[j] - 0.5 * row_sq_norms(lower_solve_rows(lows[j], x - means[j]))``."""
    return _gaussian_log_probs(_f64(lows), _f64(means), _f64(log_norms), _f64(x))


def factor_kind(a) -> int:
    """What a square root ``a`` of a covariance is, in one pass: 0 diagonal with a finite diagonal (every entry off it
    0), 1 full and finite, 2 with a non-finite entry (:func:`_factor_kind`)."""
    return _factor_kind(_f64(a))


def lower_from_r(r) -> tuple[np.ndarray, float]:
    """``(L, log_norm)`` from the R of a QR factorisation A^T = Q R (its upper triangle; what is below is not read):
    L = R^T with a positive diagonal (so L L^T = A A^T) and the log-normaliser of N(m, L L^T)
    (:func:`_lower_from_r`); numpy.linalg.LinAlgError if R is singular or not finite."""
    low, log_norm, ok = _lower_from_r(_f64(r))
    if not ok:
        raise np.linalg.LinAlgError("R is singular or not finite")
    return low, log_norm


def eigh(a) -> tuple[np.ndarray, np.ndarray]:
    """``numpy.linalg.eigh(a)`` for a symmetric ``a`` (lower triangle read): eigenvalues ascending, eigenvectors
    as columns; numpy.linalg.LinAlgError if an entry is not finite or the QL iteration does not converge.
    Signs of the eigenvectors may differ from LAPACK's."""
    a = _f64(a)
    if not np.all(np.isfinite(a)):
        raise np.linalg.LinAlgError("matrix has non-finite entries")
    values, vectors_t, ok = _eigh(a)
    if not ok:
        raise np.linalg.LinAlgError("eigenvalues did not converge")
    return values, np.ascontiguousarray(vectors_t.T)
