"""The numbers of a run, the same on every CPU: the one place Python code takes its math from.

The rule. A run's numbers must not depend on the machine (``tests/test_same_numbers_everywhere.py``):
numpy hands products to OpenBLAS, whose kernels sum in a CPU-dependent order, and numpy's and the C
library's ``exp``/``log``/``tanh``/``pow``/... have CPU-specific variants that differ in the last bit
(:mod:`imix_cli.core.numerics.linalg_kernels` and :mod:`imix_cli.core.numerics.elementary` say where and by how much). So Python code
on a run's path computes them with the numpy-like names below, never numpy's, ``math``'s or ``@``::

    from imix_cli.core import numerics as xp
    xp.exp(log_sigma), xp.log(2.0), xp.dot(a, b), xp.vec_mat(w, x), xp.power(beta, t)

Each name takes what its numpy namesake takes here: a number (Python or numpy scalar: a float comes back;
passed on as it is, so its type picks the compiled version as before) or, where the function has an
array form, a float64 vector or matrix. Compiled code (``@njit``) calls the
kernels themselves (:mod:`imix_cli.core.numerics.elementary`'s scalar functions, :mod:`imix_cli.core.numerics.linalg_kernels`'s
``*_kernel`` and ``numpy_sum``), which are what these names run. ``tests/test_numerics.py`` checks that
every Python module takes them from here.
"""

from __future__ import annotations

import numpy as np

from imix_cli.core.numerics import elementary as _el
from imix_cli.core.numerics import linalg_kernels as _lk
from imix_cli.core.numerics.linalg_kernels import (
    cholesky,
    dot,
    eigh,
    factor_kind,
    gaussian_log_probs,
    lower_from_r,
    lower_solve_rows,
    lower_times_rows,
    mat_mat,
    mat_vec,
    row_sq_norms,
    tanh,
    vec_mat,
    weighted_gram,
)

#: log(2 pi), a number (:data:`imix_cli.core.numerics.elementary.LOG_2PI`)
LOG_2PI = _el.LOG_2PI

__all__ = [
    "LOG_2PI",
    "exp",
    "log",
    "log1p",
    "expm1",
    "power",
    "tanh",
    "dot",
    "vec_mat",
    "mat_vec",
    "mat_mat",
    "weighted_gram",
    "row_sq_norms",
    "cholesky",
    "lower_times_rows",
    "lower_solve_rows",
    "gaussian_log_probs",
    "factor_kind",
    "lower_from_r",
    "eigh",
]


def exp(x):
    """``np.exp``: of a float (a float back) or of a (d,) vector."""
    return _el.math_exp(x) if np.ndim(x) == 0 else _lk.exp(x)


def log(x):
    """``np.log`` (log(0) = -inf, of a negative number NaN, no warning): of a float or of a (d,) vector."""
    return _el.math_log(x) if np.ndim(x) == 0 else _lk.log(x)


def expm1(x):
    """``np.expm1`` of a (d,) vector."""
    return _lk.expm1(x)


def log1p(x) -> float:
    """``np.log1p`` of a float (log1p(-1) = -inf, no exception)."""
    return _el.math_log1p(x)


def power(x, y) -> float:
    """``np.power`` of two floats (Python's ``x ** y`` on floats is the C library's pow)."""
    return _el.math_pow(x, y)
