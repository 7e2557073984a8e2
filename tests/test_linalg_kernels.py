"""imix_cli.core.numerics.linalg_kernels: the products sum in the documented order, and the eigensolver agrees with LAPACK's.

Order: every product must equal, bit for bit, a pure-Python loop adding its terms in ascending
index order (Python floats are IEEE doubles with no fused multiply-add), i.e. the order cannot
depend on the CPU. Eigensolver: EISPACK's tred2 + tql2 against ``numpy.linalg.eigh`` on matrices
shaped like CMA-ES's (random SPD, condition up to 1e14, repeated eigenvalues, diagonal), to
~1e-12 of the largest eigenvalue and with an orthonormal basis that reconstructs the matrix.
"""

import math

import numpy as np
import pytest
from numba import njit

from imix_cli.core.numerics import linalg_kernels as lk


def _seq_sum(terms):
    acc = 0.0
    for t in terms:
        acc += t
    return acc


@pytest.fixture
def rng():
    return np.random.default_rng(20261124)


def test_products_sum_in_ascending_order_bit_for_bit(rng):
    n, m, p = 7, 13, 5
    a, b = rng.standard_normal((n, m)) * 10.0 ** rng.uniform(-8, 8, (n, m)), rng.standard_normal((m, p))
    w, x = rng.standard_normal(m) * 10.0 ** rng.uniform(-8, 8, m), rng.standard_normal(m)
    assert lk.dot(w, x) == _seq_sum(float(w[k]) * float(x[k]) for k in range(m))
    assert list(lk.vec_mat(w, b)) == [_seq_sum(float(w[k]) * float(b[k, j]) for k in range(m)) for j in range(p)]
    assert list(lk.mat_vec(a, x)) == [_seq_sum(float(a[i, k]) * float(x[k]) for k in range(m)) for i in range(n)]
    assert lk.mat_mat(a, b).tolist() == [[_seq_sum(float(a[i, k]) * float(b[k, j]) for k in range(m)) for j in range(p)] for i in range(n)]
    gram = lk.weighted_gram(w, b)
    assert gram.tolist() == [[_seq_sum((float(w[k]) * float(b[k, i])) * float(b[k, j]) for k in range(m)) for j in range(p)] for i in range(p)]
    assert list(lk.row_sq_norms(a)) == [_seq_sum(float(a[i, k]) * float(a[i, k]) for k in range(m)) for i in range(n)]


def test_products_agree_with_numpy_to_round_off(rng):
    a, b, x = rng.standard_normal((40, 130)), rng.standard_normal((130, 60)), rng.standard_normal(130)
    np.testing.assert_allclose(lk.mat_mat(a, b), a @ b, rtol=0, atol=1e-12)
    np.testing.assert_allclose(lk.mat_vec(a, x), a @ x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(lk.vec_mat(x, b), x @ b, rtol=0, atol=1e-12)
    np.testing.assert_allclose(lk.mat_mat(a[:, :7].T, a[:, 3:9]), a[:, :7].T @ a[:, 3:9], rtol=0, atol=1e-12)  # non-contiguous inputs


def test_triangular_kernels_and_cholesky_agree_with_numpy_and_scipy(rng):
    from scipy.linalg import solve_triangular

    g = rng.standard_normal((130, 130))
    spd = g @ g.T + 130 * np.eye(130)
    low = lk.cholesky(spd)
    np.testing.assert_allclose(low, np.linalg.cholesky(spd), rtol=0, atol=1e-11)
    assert np.array_equal(low, np.tril(low))
    e = rng.standard_normal((9, 130))
    np.testing.assert_allclose(lk.lower_times_rows(low, e), e @ low.T, rtol=0, atol=1e-11)
    np.testing.assert_allclose(lk.lower_solve_rows(low, e), solve_triangular(low, e.T, lower=True).T, rtol=0, atol=1e-12)
    with pytest.raises(np.linalg.LinAlgError):
        lk.cholesky(np.diag([1.0, -1e-12, 2.0]))
    with pytest.raises(np.linalg.LinAlgError):
        lk.cholesky(np.diag([1.0, np.nan]))


def _spd(rng, d, log10_condition):
    q, _ = np.linalg.qr(rng.standard_normal((d, d)))
    values = 10.0 ** np.linspace(0.0, log10_condition, d)
    return (q * values) @ q.T


@pytest.mark.parametrize(
    "name, make",
    [
        ("1x1", lambda rng: np.array([[3.0]])),
        ("2x2", lambda rng: np.array([[2.0, 1.0], [1.0, 2.0]])),
        ("identity 10", lambda rng: np.eye(10)),
        ("pycma initial C at d=130", lambda rng: np.diag(np.exp((1e-4 / 130) * np.arange(130)))),
        ("random SPD d=130", lambda rng: (lambda g: g @ g.T)(rng.standard_normal((130, 130)))),
        ("condition 1e6 d=50", lambda rng: _spd(rng, 50, 6)),
        ("condition 1e14 d=30", lambda rng: _spd(rng, 30, 14)),
        ("repeated eigenvalues d=20", lambda rng: (lambda q: (q * np.repeat([1.0, 2.0, 5.0, 5.0], 5)) @ q.T)(np.linalg.qr(rng.standard_normal((20, 20)))[0])),
        ("indefinite d=25", lambda rng: (lambda g: g + g.T)(rng.standard_normal((25, 25)))),
        ("zero 4x4", lambda rng: np.zeros((4, 4))),
    ],
)
def test_eigh_agrees_with_lapack(rng, name, make):
    a = make(rng)
    values, vectors = lk.eigh(a)
    reference = np.linalg.eigh(a)[0]
    scale = max(np.max(np.abs(reference)), 1e-300)
    assert np.all(np.diff(values) >= 0), "ascending"
    np.testing.assert_allclose(values, reference, rtol=0, atol=1e-12 * scale, err_msg=name)
    np.testing.assert_allclose(vectors.T @ vectors, np.eye(a.shape[0]), rtol=0, atol=1e-12, err_msg=name)
    np.testing.assert_allclose((vectors * values) @ vectors.T, a, rtol=0, atol=1e-12 * scale, err_msg=name)


def test_eigh_well_separated_eigenvalues_to_relative_round_off(rng):
    a = _spd(rng, 130, 4)
    values = lk.eigh(a)[0]
    np.testing.assert_allclose(values, np.linalg.eigh(a)[0], rtol=1e-12, atol=0)


def test_eigh_reads_the_lower_triangle_only(rng):
    a = _spd(rng, 12, 2)
    upper_garbage = np.tril(a) + np.triu(rng.standard_normal((12, 12)), 1)
    assert [x.tolist() for x in lk.eigh(upper_garbage)] == [x.tolist() for x in lk.eigh(a)]


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_eigh_refuses_a_non_finite_matrix(bad):
    a = np.eye(3)
    a[2, 1] = bad
    with pytest.raises(np.linalg.LinAlgError):
        lk.eigh(a)


def test_many_rows_are_solved_with_the_same_operations_as_one_row_at_a_time():
    """From SOLVE_ROWS_TOGETHER rows on, the rows are solved together (the loop over rows innermost); each row's
    result must be bit for bit what solving it alone gives. Made to fail by starting each row's sum from 0 and
    adding y[r, i] last."""
    rng = np.random.default_rng(4)
    d = 130
    a = rng.normal(size=(d, d))
    low = np.linalg.cholesky(a @ a.T / d + np.eye(d))
    y = rng.normal(size=(3 * lk.SOLVE_ROWS_TOGETHER, d))
    together = lk.lower_solve_rows(low, y)
    alone = np.vstack([lk.lower_solve_rows(low, y[r : r + 1]) for r in range(len(y))])
    assert np.array_equal(together.view(np.int64), alone.view(np.int64))


@pytest.mark.parametrize("d,n", [(1, 3), (10, 5), (40, 2 * lk.SOLVE_ROWS_TOGETHER)])
def test_gaussian_log_probs_are_log_prob_row_by_row_bit_for_bit(d, n):
    """gaussian_log_probs (several Gaussians in one call: importance mixing with full covariances) gives, for each
    factor, the bits of log_norm - 0.5 |L^-1 (x - m)|^2 computed with lower_solve_rows and row_sq_norms, whatever
    rows and factors are computed with it. Made to fail by summing the squares of a row last index first."""
    rng = np.random.default_rng(d)
    lows = np.array([np.linalg.cholesky(a @ a.T / d + np.eye(d)) for a in rng.normal(size=(3, d, d))])
    means, log_norms, x = rng.normal(size=(3, d)), rng.normal(size=3), 3 * rng.normal(size=(n, d))
    together = lk.gaussian_log_probs(lows, means, log_norms, x)
    for j in range(3):
        alone = log_norms[j] - 0.5 * lk.row_sq_norms(lk.lower_solve_rows(lows[j], x - means[j]))
        assert np.array_equal(together[j].view(np.int64), alone.view(np.int64))
        first = lk.gaussian_log_probs(lows[j : j + 1], means[j : j + 1], log_norms[j : j + 1], x[:1])[0]
        assert np.array_equal(first.view(np.int64), alone[:1].view(np.int64))


@pytest.mark.parametrize("d", [1, 2, 5, 10, 40])
def test_lower_from_r_is_the_numpy_path_bit_for_bit(d):
    """lower_from_r (the pycma adapter's L from LAPACK's R, one compiled call) gives the bits of the numpy path it
    replaced: L = tril((R * signs).T), signs -1 where R's diagonal is negative, and FullGaussian.from_cholesky's
    log_norm of it; what lies below R's diagonal (LAPACK's reflectors) is not read; a zero or non-finite R is
    refused. Made to fail by summing the logs last index first."""
    from imix_cli.core.distributions import FullGaussian

    rng = np.random.default_rng(d)
    for scale in (1.0, 1e-9, 1e7):
        a = rng.standard_normal((d, d)) * scale * 10.0 ** rng.uniform(-3, 3, d)
        r = np.linalg.qr(a, mode="r")
        assert d < 10 or (np.diag(r) < 0).any()  # the sign flips are exercised
        signs = np.where(np.diag(r) < 0, -1.0, 1.0)
        expected = np.tril((r * signs[:, None]).T)
        low, log_norm = lk.lower_from_r(r + np.tril(rng.standard_normal((d, d)), -1))  # below the diagonal: never read
        assert np.array_equal(low.view(np.int64), expected.view(np.int64))
        assert log_norm == FullGaussian.from_cholesky(np.zeros(d), expected).log_norm
    for bad in (0.0, np.nan, np.inf):
        r = np.triu(rng.standard_normal((d, d)) + 3 * np.eye(d))
        r[d - 1, d - 1] = bad
        with pytest.raises(np.linalg.LinAlgError):
            lk.lower_from_r(r)


def test_factor_kind_tells_diagonal_full_and_non_finite_factors():
    eye = np.eye(3)
    assert lk.factor_kind(2 * eye) == 0 and lk.factor_kind(-eye) == 0 and lk.factor_kind(np.zeros((3, 3))) == 0
    full = eye.copy()
    full[0, 2] = 1e-300
    assert lk.factor_kind(full) == 1
    for bad, kind in ((np.nan, 2), (np.inf, 2)):
        for where in ((0, 0), (0, 1)):
            a = eye.copy()
            a[where] = bad
            assert lk.factor_kind(a) == kind, (bad, where)


@njit
def _tred2_one_row_at_a_time(w, d, e):
    """JAMA/EISPACK tred2 as imix computed it before its two O(d^3) loops went four rows at a time: the reference."""
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
            for j in range(i):
                e[j] = 0.0
            for j in range(i):
                f = d[j]
                w[i, j] = f
                g = e[j] + w[j, j] * f
                for k in range(j + 1, i):
                    g += w[j, k] * d[k]
                    e[k] += w[j, k] * f
                e[j] = g
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
                for k in range(j, i):
                    w[j, k] -= f * e[k] + g * d[k]
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
            for j in range(i + 1):
                g = 0.0
                for k in range(i + 1):
                    g += w[i + 1, k] * w[j, k]
                for k in range(i + 1):
                    w[j, k] -= g * d[k]
        for k in range(i + 1):
            w[i + 1, k] = 0.0
    for j in range(n):
        d[j] = w[j, n - 1]
        w[j, n - 1] = 0.0
    w[n - 1, n - 1] = 1.0
    e[0] = 0.0


def _symmetric_cases():
    rng = np.random.default_rng(130)
    for n in (*range(1, 12), 13, 31, 64, 130, 203):
        g = rng.standard_normal((n, n))
        yield f"random d={n}", g + g.T
    for n in (9, 40):
        yield f"SPD condition 1e12 d={n}", _spd(rng, n, 12)
        a = _spd(rng, n, 3)
        a[:, n // 2] = a[n // 2, :] = 0.0  # a zero row and column: tred2's scale == 0 branch
        yield f"zero row d={n}", a
        yield f"diagonal d={n}", np.diag(rng.uniform(1, 2, n))
    yield "pycma initial C d=130", np.diag(np.exp((1e-4 / 130) * np.arange(130)))


@pytest.mark.parametrize("name,a", list(_symmetric_cases()), ids=lambda v: v if isinstance(v, str) else "")
def test_tred2_four_rows_at_a_time_gives_the_one_row_loops_bits(name, a):
    """tred2's two O(d^3) loops run four rows side by side (linalg_kernels._reduce_rows, _apply_reflections); every
    number must be the one the one-row-at-a-time loop (JAMA's order, imix's before) gives, so that CMA-ES's runs keep
    their bits. Made to fail by adding row j + 1's term to e[k] before row j's in the four-row loop."""
    n = a.shape[0]
    outputs = []
    for tred2 in (lk._tred2, _tred2_one_row_at_a_time):
        w, d, e = np.array(a.T, order="C"), np.empty(n), np.empty(n)  # a copy: tred2 works in place
        tred2(w, d, e)
        outputs.append((w, d, e))
    for new, old in zip(*outputs):
        assert np.array_equal(new.view(np.int64), old.view(np.int64)), name
