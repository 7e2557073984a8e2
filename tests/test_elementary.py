"""imix's own elementary functions (imix_cli.core.numerics.elementary) give glibc 2.36's FMA results, bit for bit.

Why it matters: a run's numbers must not depend on the machine, and the C library's do (glibc runs an
FMA build of exp, expm1, log1p, pow, sin, cos on CPUs with FMA and an SSE2 build elsewhere; they
differ in the last bit on ~0.05 % of inputs). imix computes these functions itself, written out with
explicit fused multiply-adds, so that its results are those of the code that produced every published
number (glibc 2.36's FMA build) on every machine.

The reference is the C library of the machine the tests run on, when it is that code: glibc 2.36 on
an x86-64 CPU with FMA and AVX2 (this project's CI machines); elsewhere these comparisons are skipped
(tests/test_same_numbers_everywhere.py still runs whole jobs against glibc's SSE2 build there). Each
function is compared on a few million inputs drawn over the ranges a run uses and beyond, plus the
special values, bit for bit (NaNs compared as NaNs). Made to fail by writing one fused multiply-add
``fma(a, b, c)`` as ``a * b + c``: exp's last step (969 of 1.6M inputs differ), expm1's k = 0 step (189,
and 268 in tanh), log's reduction r = z invc - 1 (397,968), sin's table step (sin and cos fail). Not every
fused product decides a result: unfusing exp's r^2 (C2 + C3 r) term changed none of these inputs.
"""

import functools
import math
import os
import platform
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from imix_cli.core.numerics import elementary as el


def _glibc_236_fma() -> str | None:
    """Why the C library here is not the reference (None if it is)."""
    if platform.machine() != "x86_64":
        return f"not x86-64 ({platform.machine()})"
    libc, version = platform.libc_ver()
    if (libc, version) != ("glibc", "2.36"):
        return f"the C library is {libc} {version}, not glibc 2.36"
    flags = next((line.split() for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags")), [])
    if not {"fma", "avx2"} <= set(flags):
        return "the CPU has no FMA/AVX2: glibc runs its SSE2 build"
    if "hwcaps" in os.environ.get("GLIBC_TUNABLES", ""):
        return "GLIBC_TUNABLES masks CPU features"
    return None


REFERENCE = pytest.mark.skipif(_glibc_236_fma() is not None, reason=f"reference unavailable: {_glibc_236_fma()}")


@functools.cache  # one compilation per function: a loop that asks again gets the compiled one (was 150 compilations, ~50 s)
def _elementwise(f):
    @njit
    def run(x):
        out = np.empty_like(x)
        for i in range(x.shape[0]):
            out[i] = f(x[i])
        return out

    return run


def _c_library(name: str):
    """The C library's function ``name`` as numba calls it (math.<name> in compiled code)."""
    function = getattr(math, name)

    @njit(inline="always")
    def call(x):
        return function(x)

    return call


SPECIAL = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 5e-324, -5e-324, 2.2250738585072014e-308, 1e-300, -1e-300, 1.0, -1.0, 0.5, -0.5, 1e300, -1e300])


def _inputs(name: str, rng: np.random.Generator) -> np.ndarray:
    n = 500_000
    ranges = {
        "exp": [rng.uniform(-1, 1, n), rng.uniform(-40, 40, n), rng.uniform(-746, 710, n), rng.normal(0, 1e-9, n // 4)],
        "expm1": [rng.uniform(-3, 3, n), rng.uniform(-50, 50, n), rng.uniform(-750, 710, n // 2), rng.normal(0, 1e-9, n // 4)],
        "log": [
            np.exp(rng.uniform(-700, 700, n)),
            rng.uniform(0.9, 1.1, n),
            rng.uniform(0, 2, n),
            -rng.uniform(0, 10, n // 10),
            rng.uniform(0, 1e-308, n // 10),
        ],
        "log1p": [rng.uniform(-1, 1, n), rng.uniform(-1, 10, n), np.exp(rng.uniform(-40, 700, n)), rng.normal(0, 1e-9, n // 4)],
        "tanh": [rng.normal(0, 1, n), rng.normal(0, 5, n), rng.uniform(-25, 25, n), rng.normal(0, 1e-9, n // 4)],
        "sin": [
            rng.uniform(-4, 4, n),
            rng.uniform(-40, 40, n),
            rng.integers(0, 2000, n) * (np.pi / 2) + rng.normal(0, 1e-6, n),
            10 ** rng.uniform(8, 300, n // 10),
        ],
    }
    ranges["cos"] = ranges["sin"]
    return np.concatenate([SPECIAL, *ranges[name]])


CASES = {name: (getattr(el, name), _c_library(name)) for name in ("exp", "expm1", "log", "log1p", "tanh", "sin", "cos")}


def _mismatches(mine: np.ndarray, reference: np.ndarray) -> np.ndarray:
    return np.flatnonzero((mine.view(np.int64) != reference.view(np.int64)) & ~(np.isnan(mine) & np.isnan(reference)))


@REFERENCE
@pytest.mark.parametrize("name", sorted(CASES))
def test_each_function_gives_glibc_fma_results_bit_for_bit(name):
    mine, libm = CASES[name]
    x = _inputs(name, np.random.default_rng(20261127))
    got, want = _elementwise(mine)(x), _elementwise(libm)(x)
    bad = _mismatches(got, want)
    assert bad.size == 0, f"{name}: {bad.size} of {x.size} differ, e.g. x={x[bad[:3]].tolist()}: {got[bad[:3]].tolist()} vs {want[bad[:3]].tolist()}"


@njit
def _pow_pairs(f, x, y):
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        out[i] = f(x[i], y[i])
    return out


@njit(inline="always")
def _libm_pow(x, y):
    return math.pow(x, y)


@REFERENCE
def test_pow_gives_glibc_fma_results_bit_for_bit():
    """Adam's bias correction (beta^t, t up to 10^6), general positive powers, and the special pairs."""
    rng = np.random.default_rng(11)
    n = 500_000
    beta = rng.choice([0.9, 0.999, 0.99, 0.5], n)
    special = np.array([0.0, -0.0, 1.0, -1.0, 2.0, -2.0, 0.5, np.inf, -np.inf, np.nan, 5e-324, 1e300])
    sx, sy = np.meshgrid(special, special)
    x = np.concatenate([beta, rng.uniform(0, 10, n), np.exp(rng.uniform(-700, 700, n)), -rng.uniform(0, 10, n // 4), sx.ravel()])
    y = np.concatenate(
        [rng.integers(1, 1_000_000, n).astype(float), rng.uniform(-50, 50, n), rng.uniform(-2, 2, n), rng.integers(-9, 9, n // 4).astype(float), sy.ravel()]
    )
    got, want = _pow_pairs(el.pow, x, y), _pow_pairs(_libm_pow, x, y)
    bad = _mismatches(got, want)
    assert bad.size == 0, f"{bad.size} of {x.size} differ, e.g. {list(zip(x[bad[:3]], y[bad[:3]]))}"


def test_the_python_callable_functions_are_the_compiled_ones():
    rng = np.random.default_rng(2)
    for x in rng.uniform(-5, 5, 50):
        assert el.math_exp(x) == _elementwise(el.exp)(np.array([x]))[0]
        assert el.math_log1p(abs(x)) == _elementwise(el.log1p)(np.array([abs(x)]))[0]
        assert el.math_log(abs(x)) == _elementwise(el.log)(np.array([abs(x)]))[0]
        assert el.math_pow(abs(x), x) == _pow_pairs(el.pow, np.array([abs(x)]), np.array([x]))[0]


@pytest.mark.slow
def test_the_tables_are_computed_from_their_definitions():
    """tools/elementary_tables.py recomputes every table (the log table by its search) and finds the shipped file."""
    import subprocess
    import sys

    tool = Path(__file__).resolve().parents[1] / "tools" / "elementary_tables.py"
    proc = subprocess.run([sys.executable, str(tool), "--check"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_tanh_without_branches_is_tanh():
    """``tanh_lanes`` (every path evaluated, one selected: it vectorises) equals ``tanh`` on every input kind."""
    x = _inputs("tanh", np.random.default_rng(3))
    bad = _mismatches(_elementwise(el.tanh_lanes)(x), _elementwise(el.tanh)(x))
    assert bad.size == 0, x[bad[:5]]


def test_the_exp_table_is_its_definition_in_decimal():
    """2^(k/128) = H_k (1 + T_k): H_k the nearest double to 2^(k/128), |T_k| below half an ulp of 1, and
    H_k (1 + T_k) closer to 2^(k/128) than H_k alone (checked in 60-digit decimal arithmetic)."""
    from decimal import Decimal, localcontext

    tab = el._EXP_TAB
    with localcontext() as ctx:
        ctx.prec = 60
        for k in range(128):
            high = float(np.int64(tab[2 * k + 1] + ((k << 52) // 128)).view(np.float64))
            tail = float(np.int64(tab[2 * k]).view(np.float64))
            exact = Decimal(2) ** (Decimal(k) / 128)
            assert high == float(exact) and abs(tail) < 2.0**-53
            assert abs(Decimal(high) * (1 + Decimal(tail)) - exact) <= abs(Decimal(high) - exact)


def _numpy_has_fma3_kernels() -> bool:
    from numpy._core._multiarray_umath import __cpu_features__

    return bool(__cpu_features__.get("FMA3") and __cpu_features__.get("AVX2"))


@pytest.mark.skipif(not _numpy_has_fma3_kernels(), reason="numpy runs its float32 sin/cos vector kernel on CPUs with FMA3/AVX2 only")
def test_float32_sin_and_cos_give_numpy_vector_kernel_results():
    """Acrobot's first observation: every 97th float32 in [-0.1, 0.1] (~21 million values, both signs) and 2
    million random float32 up to the kernel's limits, against numpy's float32 np.sin/np.cos (its vector kernel
    here). Made to fail by computing the quadrant with a separate multiply and add (0 differences below pi/4,
    ~3,000 per 10^7 inputs up to 7e4) and by dropping the "+ 0" multiply-add of the sine (-0 comes out as -0)."""

    @njit
    def both(x):
        s, c = np.empty_like(x), np.empty_like(x)
        for i in range(x.shape[0]):
            s[i], c[i] = el.sin32(x[i]), el.cos32(x[i])
        return s, c

    top = int(np.float32(0.1).view(np.uint32)) + 1
    small = np.arange(0, top, 97, dtype=np.uint32)
    rng = np.random.default_rng(9)
    x = np.concatenate([small.view(np.float32), (small | np.uint32(0x80000000)).view(np.float32), rng.uniform(-7e4, 7e4, 2_000_000).astype(np.float32)])
    s, c = both(x)
    for name, got, want in (("sin", s, np.sin(x)), ("cos", c, np.cos(x))):
        bad = np.flatnonzero(got.view(np.uint32) != want.view(np.uint32))
        assert bad.size == 0, f"{name}: {bad.size} of {x.size} differ, e.g. {x[bad[:3]].tolist()}"
