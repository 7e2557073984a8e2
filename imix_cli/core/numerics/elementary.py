"""Elementary functions computed by imix itself: the same bits on every machine.

Why: a run's numbers pass through ``exp`` (SNES's step sizes), ``log``/``log1p``/``expm1`` (the
mixing rules), ``pow`` (Adam's bias correction), ``tanh`` (every policy) and ``sin``/``cos``
(CartPole's and Acrobot's dynamics). Calling the C library for them ties the numbers to the
machine: glibc's x86-64 libm picks, when the program starts, an FMA-compiled variant of
``exp``, ``expm1``, ``log1p``, ``pow``, ``sin``, ``cos`` (and so ``tanh``) on CPUs with FMA and a
plain SSE2 one on CPUs without; the two differ in the last bit on ~0.03-0.07 % of inputs
(200,000 random inputs each, ``benchmarks/libm_variants.py``). An evolution strategy amplifies
such bits: every SNES seed of the main job ran a different search from generation 6-15 on when
the same machine was made to take the SSE2 variants (``GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA``,
which is what glibc does on a CPU without FMA). Other C libraries (macOS, musl, other glibc
versions, aarch64) have other code again.

What: each function here is written out in float64 operations with every fused multiply-add
explicit (LLVM's ``llvm.fma``: one rounding on any CPU; a CPU without FMA computes it in
software, exactly), so its result is defined by this file, not by the machine. The operations
are those of glibc 2.36's x86-64 FMA variants -- the code that produced every number imix has
published -- so on such a machine nothing changes, bit for bit (``tests/test_elementary.py``
compares each function with the C library's on millions of inputs there, and
``tests/test_same_numbers_everywhere.py`` runs whole jobs with glibc's SSE2 variants selected).

The algorithms (each section's comment and each function's docstring say more):

* ``exp``: table-driven, exp(x) = 2^(k/128) exp(r), |r| <= ln2/256, a degree-5 polynomial for
  exp(r) - 1 and a 128-entry table of 2^(k/128) split into a double and a correction (Szabolcs
  Nagy's algorithm in ARM's optimized-routines, which glibc uses since 2.28).
* ``log``, ``pow``: the same library's: log through a 128-entry table of 1/c and log c and a
  polynomial for log1p(r); pow as exp(y log x) with log x carried to ~68 bits and exp's table.
* ``expm1``, ``tanh``, ``log1p``: fdlibm's (Sun, 1993): x = k ln2 + r, a rational approximation of
  expm1(r) on |r| <= ln2/2, scaled back; tanh(x) = 1 - 2/(expm1(2|x|) + 2) for |x| >= 1 and
  -expm1(-2|x|)/(expm1(-2|x|) + 2) below; log1p through 1 + x = 2^k (1 + f) and a series in f/(2 + f).
* ``sin``, ``cos``: IBM's Accurate Mathematical Library (glibc's s_sin.c): a table of sin and cos
  at k/128 and short polynomials, after a reduction by pi/2 (exact, to ~1800 bits, for huge x).
* ``sin32``, ``cos32``: numpy 2.4.6's float32 vector kernel (what gymnasium's Acrobot observation uses).

Every table is computed from its definition by ``tools/elementary_tables.py`` into
``imix_cli/core/numerics/elementary_tables.py`` (the tests recompute it and compare).

How fast: the functions are compiled into the loops that call them (no call into a shared
library). ``tanh_lanes`` computes every path of ``tanh`` and selects the right one, with no
branch, so that a loop over a layer's units compiles to vector instructions. One CartPole episode
at a time, the compiled episodes run 4.86M steps/s against 4.30M with the C library's functions,
Acrobot's 2.77M against 2.01M (``imix bench rollouts``, batch 2, both versions back to back).

Compilation: ``exp``, ``log`` and ``tanh_lanes`` are inlined into their callers (they sit in the hot
loops, and ``tanh_lanes`` must be inlined to be vectorised); the larger functions are compiled once
and called (inlining ``sin``, ``cos`` and ``pow`` at every call site multiplied the compile time).
Either way a cached kernel holds these functions' code, so numba's disk cache of a kernel would not
see a change made here: :mod:`imix_cli.core.numerics.numba_cache` (imported below, before the first kernel of the
package is defined) stamps every imix kernel with a hash of every compiled source, this file included.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from imix_cli.core.numerics import elementary_tables as _tables
from imix_cli.core.numerics import numba_cache  # noqa: F401 -- imix's cache locator, in place before the first @njit(cache=True) of the package

__all__ = [
    "exp", "expm1", "log", "log1p", "pow", "tanh", "tanh_lanes", "sin", "cos", "sin32", "cos32", "fma",
    "math_exp", "math_log", "math_log1p", "math_pow",
]  # fmt: skip


# ----------------------------------------------------------------------------- primitives
# LLVM operations that numba does not expose: written straight into the caller's code.
@intrinsic
def fma(typingctx, a, b, c):
    """a * b + c with one rounding (``llvm.fma``): exact on every CPU."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        d = ir.DoubleType()
        fn = builder.module.declare_intrinsic("llvm.fma", [d], ir.FunctionType(d, [d, d, d]))
        return builder.call(fn, args)

    return sig, codegen


@intrinsic
def _bits(typingctx, a):
    """The IEEE bits of a float64, as an int64."""

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.int64(types.float64), codegen


@intrinsic
def _float(typingctx, a):
    """The float64 whose IEEE bits are the int64 ``a``."""

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.int64), codegen


@intrinsic
def _div(typingctx, a, b):
    """a / b as IEEE division, whatever the caller's error model (numba's default checks for a zero
    divisor with a branch, which keeps a loop from being vectorised; the paths here never divide by zero
    where their result is used)."""

    def codegen(context, builder, signature, args):
        return builder.fdiv(args[0], args[1])

    return types.float64(types.float64, types.float64), codegen


@intrinsic
def _pick(typingctx, cond, a, b):
    """``a if cond else b`` without a branch (LLVM ``select``)."""
    kind = typingctx.unify_types(types.unliteral(a), types.unliteral(b))

    def codegen(context, builder, signature, args):
        return builder.select(args[0], args[1], args[2])

    return kind(types.boolean, kind, kind), codegen


def _double(hex_literal: str) -> float:
    return float.fromhex(hex_literal)


#: log(2 pi) as :func:`math_log` gives it, written out: computing it at import would start numba (~1.5 s) in every
#: process, one that only refuses a bad key included (tests/test_numerics.py checks the literal and the import)
LOG_2PI = 1.8378770664093453


# ----------------------------------------------------------------------------- exp
_EXP_BITS = 7
_N = 1 << _EXP_BITS


_EXP_TAB = np.array(_tables.EXP_TAB, dtype=np.uint64).view(np.int64)  # 2^(k/N) = H (1 + T): bits of T, of H - (k << 52)/N
_INV_LN2_N = _double("0x1.71547652b82fep0") * _N  # N / ln2
_NEG_LN2_HI_N = _double("-0x1.62e42fefa0000p-8")  # -ln2 / N, its high part (k * it is exact)
_NEG_LN2_LO_N = _double("-0x1.cf79abc9e3b3ap-47")  # ... and the rest
_ROUND_SHIFT = _double("0x1.8p52")  # adding it rounds to an integer, which lands in the low bits
# exp(r) - 1 ~ r + C2 r^2 + ... + C5 r^5 on |r| <= ln2/256 (|error| 1.555 * 2^-66)
_EXP_C2 = _double("0x1.ffffffffffdbdp-2")
_EXP_C3 = _double("0x1.555555555543cp-3")
_EXP_C4 = _double("0x1.55555cf172b91p-5")
_EXP_C5 = _double("0x1.1111167a4d017p-7")
_TWO_1009 = 2.0**1009
_TWO_M1022 = 2.0**-1022


@njit(inline="always")
def _exp_near_limits(tmp, sbits, ki):
    """exp for 512 <= |x| < 1024, where the scale 2^(k/N) overflows or underflows a double: scaled by
    2^-1009 (large x) or 2^1022 (small x, rounding once more to the subnormal precision)."""
    if (ki & 0x80000000) == 0:
        scale = _float(sbits - (1009 << 52))
        return _TWO_1009 * fma(scale, tmp, scale)
    scale = _float(sbits + (1022 << 52))
    product = scale * tmp  # used twice: rounded once, as glibc computes it
    y = scale + product
    if y < 1.0:  # the result is subnormal: round y to its final precision before scaling it down
        lo = scale - y + product
        hi = 1.0 + y
        lo = 1.0 - hi + y + lo
        y = (hi + lo) - 1.0
        if y == 0.0:
            y = 0.0
    return _TWO_M1022 * y


@njit(inline="always")
def exp(x):
    """e^x: x = k ln2/128 + r; e^x = 2^(k/128) (1 + (e^r - 1)), 2^(k/128) from the table."""
    abstop = (_bits(x) >> 52) & 0x7FF
    if abstop < 0x3C9 or abstop >= 0x408:  # |x| < 2^-54, or |x| >= 512 (or inf/nan)
        if abstop < 0x3C9:
            return 1.0 + x
        if abstop >= 0x409:  # |x| >= 1024
            if x == -math.inf:
                return 0.0
            if abstop >= 0x7FF:
                return 1.0 + x
            return 0.0 if x < 0.0 else math.inf
        abstop = 0  # 512 <= |x| < 1024: scaled with care below
    kd = _INV_LN2_N * x + _ROUND_SHIFT
    ki = _bits(kd)
    kd -= _ROUND_SHIFT
    r = fma(kd, _NEG_LN2_LO_N, fma(kd, _NEG_LN2_HI_N, x))
    idx = 2 * (ki & (_N - 1))
    tail = _float(_EXP_TAB[idx])
    sbits = _EXP_TAB[idx + 1] + (ki << (52 - _EXP_BITS))
    r2 = r * r
    tmp = fma(r2 * r2, fma(r, _EXP_C5, _EXP_C4), fma(r2, fma(r, _EXP_C3, _EXP_C2), tail + r))
    if abstop == 0:
        return _exp_near_limits(tmp, sbits, ki)
    scale = _float(sbits)
    return fma(scale, tmp, scale)


# ----------------------------------------------------------------------------- expm1 and tanh
_LN2_HI = _double("0x1.62e42fee00000p-1")  # ln2 = LN2_HI + LN2_LO, k * LN2_HI exact for |k| < 2^11
_LN2_LO = _double("0x1.a39ef35793c76p-33")
_INV_LN2 = _double("0x1.71547652b82fep0")
# 6/r ((e^r + 1)/(e^r - 1) - 2/r) ~ 1 + Q1 z + ... + Q5 z^5 with z = r^2/2 (|error| < 2^-61 on |r| <= 0.347)
_Q1 = _double("-0x1.11111111110f4p-5")
_Q2 = _double("0x1.a01a019fe5585p-10")
_Q3 = _double("-0x1.4ce199eaadbb7p-14")
_Q4 = _double("0x1.0cfca86e65239p-18")
_Q5 = _double("-0x1.afdb76e09c32dp-23")
_HALF_LN2 = _double("0x1.62e43p-2")  # |x| above it: reduce (the high word 0x3fd62e43)
_THREE_HALVES_LN2 = _double("0x1.0a2b2p0")  # |x| below it (and above the last): k = +-1
_EXPM1_TINY = 2.0**-54
_EXPM1_SATURATES = _double("0x1.3687ap5")  # below -56 ln2 (the high word 0x4043687a): -1
_EXPM1_OVERFLOWS = _double("0x1.62e42fefa39efp9")  # above 709.78...: e^x overflows
_TANH_TINY = 2.0**-55


@njit(inline="always")
def _expm1_kernel(x, k, hi, lo):
    """expm1 of x = k ln2 + (hi - lo) with |hi - lo| <= ln2/2 (fdlibm's steps 2 and 3)."""
    r = x
    c = 0.0
    if k != 0:
        r = hi - lo
        c = (hi - r) - lo  # what rounding r lost
    hfx = 0.5 * r
    hxs = r * hfx
    r1 = fma(hxs * hxs * (hxs * hxs), fma(hxs, _Q5, _Q4), fma(hxs * hxs, fma(hxs, _Q3, _Q2), fma(hxs, _Q1, 1.0)))
    t = fma(-r1, hfx, 3.0)
    e = hxs * _div(r1 - t, fma(-r, t, 6.0))
    if k == 0:
        return r - fma(r, e, -hxs)
    e = fma(r, e - c, -c) - hxs
    if k == -1:
        return fma(0.5, r - e, -0.5)
    if k == 1:
        if r < -0.25:
            return -2.0 * (e - (r + 0.5))
        return fma(2.0, r - e, 1.0)
    if k <= -2 or k > 56:
        return _float(_bits(1.0 - (e - r)) + (k << 52)) - 1.0
    if k < 20:
        y = _float((0x3FF00000 - (0x200000 >> k)) << 32) - (e - r)  # (1 - 2^-k) - (e - r)
        return _float(_bits(y) + (k << 52))
    y = (r - (e + _float((0x3FF - k) << 52))) + 1.0  # (r - (e + 2^-k)) + 1
    return _float(_bits(y) + (k << 52))


@njit
def expm1(x):
    """e^x - 1, accurate near 0: x = k ln2 + r, |r| <= ln2/2, e^x - 1 = 2^k (e^r - 1 + 1) - 1."""
    ax = abs(x)
    if not ax < _EXPM1_SATURATES:
        if x != x or x == math.inf:
            return x + x if x != x else x
        if x < 0.0:
            return -1.0
        if x > _EXPM1_OVERFLOWS:
            return math.inf
    if ax < _HALF_LN2:
        if ax < _EXPM1_TINY:
            return x
        return _expm1_kernel(x, 0, 0.0, 0.0)
    if ax < _THREE_HALVES_LN2:
        if x > 0.0:
            return _expm1_kernel(x, 1, x - _LN2_HI, _LN2_LO)
        return _expm1_kernel(x, -1, x + _LN2_HI, -_LN2_LO)
    k = int(fma(_INV_LN2, x, -0.5 if x < 0.0 else 0.5))
    t = float(k)
    return _expm1_kernel(x, k, fma(-t, _LN2_HI, x), t * _LN2_LO)


@njit
def tanh(x):
    """tanh: 1 - 2/(e^(2|x|) + 1) through expm1, with the sign of x; +-1 beyond |x| = 22."""
    ax = abs(x)
    if not ax < 22.0:
        return x + x if x != x else (1.0 if x > 0.0 else -1.0)
    if ax < _TANH_TINY:
        return x * (1.0 + x)
    if ax >= 1.0:
        z = 1.0 - _div(2.0, expm1(2.0 * ax) + 2.0)
    else:
        t = expm1(-2.0 * ax)
        z = _div(-t, t + 2.0)
    return z if x >= 0.0 else -z


@njit(inline="always")
def tanh_lanes(x):
    """:func:`tanh`, computed without a branch: every path of expm1 is evaluated and the one
    :func:`tanh` takes is selected, so that a loop applying it over an array vectorises (each lane
    does the same operations as the scalar path it selects: the same bits)."""
    ax = abs(x)
    big = ax >= 1.0
    a = _pick(big, 2.0 * ax, -2.0 * ax)  # expm1's argument
    aa = abs(a)
    negative = a < 0.0
    band = (aa >= _HALF_LN2) & (aa < _THREE_HALVES_LN2)  # k = +-1
    general = aa >= _THREE_HALVES_LN2
    kg = int(fma(_INV_LN2, a, _pick(negative, -0.5, 0.5)))
    tg = float(kg)
    hi = _pick(general, fma(-tg, _LN2_HI, a), _pick(negative, a + _LN2_HI, a - _LN2_HI))
    lo = _pick(general, tg * _LN2_LO, _pick(negative, -_LN2_LO, _LN2_LO))
    k = _pick(general, kg, _pick(band, _pick(negative, -1, 1), 0))
    reduced = general | band
    r = _pick(reduced, hi - lo, a)
    c = _pick(reduced, (hi - r) - lo, 0.0)
    hfx = 0.5 * r
    hxs = r * hfx
    r1 = fma(hxs * hxs * (hxs * hxs), fma(hxs, _Q5, _Q4), fma(hxs * hxs, fma(hxs, _Q3, _Q2), fma(hxs, _Q1, 1.0)))
    t = fma(-r1, hfx, 3.0)
    e = hxs * _div(r1 - t, fma(-r, t, 6.0))
    y_k0 = r - fma(r, e, -hxs)
    e = fma(r, e - c, -c) - hxs
    y_km1 = fma(0.5, r - e, -0.5)
    y_far = _float(_bits(1.0 - (e - r)) + (k << 52)) - 1.0  # k <= -2 or k > 56 (k = 1 cannot occur here)
    k_small = _pick((k >= 2) & (k < 20), k, 2)  # shifts stay in range on the lanes that do not use them
    y_small = _float(_bits(_float((0x3FF00000 - (0x200000 >> k_small)) << 32) - (e - r)) + (k << 52))
    k_mid = _pick((k >= 20) & (k <= 56), k, 20)
    y_mid = _float(_bits((r - (e + _float((0x3FF - k_mid) << 52))) + 1.0) + (k << 52))
    em1 = _pick(k == 0, y_k0, _pick(k == -1, y_km1, _pick((k <= -2) | (k > 56), y_far, _pick(k < 20, y_small, y_mid))))
    em1 = _pick(negative & (aa >= _EXPM1_SATURATES), -1.0, em1)
    z = _pick(big, 1.0 - _div(2.0, em1 + 2.0), _div(-em1, em1 + 2.0))
    z = _pick(ax < _TANH_TINY, x * (1.0 + x), _pick(x >= 0.0, z, -z))
    return _pick(ax < 22.0, z, _pick(x != x, x + x, _pick(x > 0.0, 1.0, -1.0)))


# ----------------------------------------------------------------------------- log, log1p, pow
# log and pow: ARM's optimized-routines (glibc's e_log.c, e_pow.c); log1p: fdlibm's. numba's own
# math.log and math.pow call the C library's compatibility versions (log@GLIBC_2.2.5, pow@GLIBC_2.2.5):
# their results are the same but for the NaN that log of a negative number gives (+NaN there, -NaN
# from log@@GLIBC_2.29); these give numba's, what imix has always computed. Every table is computed from
# its definition by tools/elementary_tables.py (the log table by a search that reproduces all 128 of
# glibc's entries). errno and floating-point exception flags are not reproduced.
_LOG_INVC = np.array([float.fromhex(v) for v in _tables.LOG_INVC])
_LOG_LOGC = np.array([float.fromhex(v) for v in _tables.LOG_LOGC])
_POW_INVC = np.array([float.fromhex(v) for v in _tables.POW_INVC])
_POW_LOGC = np.array([float.fromhex(v) for v in _tables.POW_LOGC])
_POW_LOGCTAIL = np.array([float.fromhex(v) for v in _tables.POW_LOGCTAIL])
_LOG_LN2_HI = _double("0x1.62e42fefa3800p-1")  # shared by log and pow's log
_LOG_LN2_LO = _double("0x1.ef35793c76730p-45")

# log: poly for log1p(r) - r on |r| < 1/256 (A), and for log(1+r) on the close-to-1 band (B)
_LOG_A0 = _double("-0x1.0000000000001p-1")
_LOG_A1 = _double("0x1.555555551305bp-2")
_LOG_A2 = _double("-0x1.fffffffeb459p-3")
_LOG_A3 = _double("0x1.999b324f10111p-3")
_LOG_A4 = _double("-0x1.55575e506c89fp-3")
_LOG_B0 = -0.5
_LOG_B1 = _double("0x1.5555555555577p-2")
_LOG_B2 = _double("-0x1.ffffffffffdcbp-3")
_LOG_B3 = _double("0x1.999999995dd0cp-3")
_LOG_B4 = _double("-0x1.55555556745a7p-3")
_LOG_B5 = _double("0x1.24924a344de3p-3")
_LOG_B6 = _double("-0x1.fffffa4423d65p-4")
_LOG_B7 = _double("0x1.c7184282ad6cap-4")
_LOG_B8 = _double("-0x1.999eb43b068ffp-4")
_LOG_B9 = _double("0x1.78182f7afd085p-4")
_LOG_B10 = _double("-0x1.5521375d145cdp-4")
_LOG_OFF = 0x3FE6000000000000
_LOG_NEAR_ONE_LO = 0x3FEE000000000000  # asuint64(1 - 2^-4)
_LOG_NEAR_ONE_HI = 0x3FF1090000000000  # asuint64(1 + 0x1.09p-4)

# pow's log (coefficients pre-scaled as in glibc)
_POW_A0 = -0.5
_POW_A1 = _double("0x1.555555555556p-2") * -2
_POW_A2 = _double("-0x1.0000000000006p-2") * -2
_POW_A3 = _double("0x1.999999959554ep-3") * 4
_POW_A4 = _double("-0x1.555555529a47ap-3") * 4
_POW_A5 = _double("0x1.2495b9b4845e9p-3") * -8
_POW_A6 = _double("-0x1.0002b8b263fc3p-3") * -8
_POW_OFF = 0x3FE6955500000000

# exp part of pow
_SIGN_BIAS = 0x800 << 7
_TWO_769 = 2.0**769
_TWO_M767 = 2.0**-767  # __math_oflow / __math_uflow operands

# log1p (fdlibm)
_L1P_LN2_HI = 6.93147180369123816490e-01  # 3fe62e42 fee00000
_L1P_LN2_LO = 1.90821492927058770002e-10  # 3dea39ef 35793c76
_TWO54 = 1.80143985094819840000e16
_L1P_LP1 = 6.666666666666735130e-01
_L1P_LP2 = 3.999999999940941908e-01
_L1P_LP3 = 2.857142874366239149e-01
_L1P_LP4 = 2.222219843214978396e-01
_L1P_LP5 = 1.818357216161805012e-01
_L1P_LP6 = 1.531383769920937332e-01
_L1P_LP7 = 1.479819860511658591e-01
_TWO_THIRDS = 0.66666666666666666

_ONE_BITS = 0x3FF0000000000000
_INF_BITS = 0x7FF0000000000000
_ABS_MASK = 0x7FFFFFFFFFFFFFFF
_SIGN_MASK = -0x8000000000000000  # 0x8000000000000000 as int64
_EXP_MASK = -(1 << 52)  # 0xfff0000000000000 as int64
_I64_MIN = -0x8000000000000000
_QNAN2 = 0xFFF0000000000000 - (1 << 64)  # 2 * 0x7ff8000000000000 as int64
_DEFAULT_NAN = np.uint64(0xFFF8000000000000).view(np.float64).item()  # x86 default NaN (0/0)
_POS_NAN = np.uint64(0x7FF8000000000000).view(np.float64).item()  # the C constant NAN
_NEG_INF = -np.inf


@njit(inline="always")
def _ult(a, b):
    """Unsigned 64-bit a < b for int64 operands."""
    return (a ^ _I64_MIN) < (b ^ _I64_MIN)


@njit(inline="always")
def _invalid(x):
    """glibc __math_invalid / fdlibm (x-x)/(x-x): the x86 default NaN (0xfff8...) for non-NaN x,
    x quieted for NaN x.  Written without a division so it also works when inlined into a caller
    compiled with numba's python error model (which raises on division by zero)."""
    return x - x if x != x else _DEFAULT_NAN


# ================================================================================================
# log
# ================================================================================================
@njit(inline="always")
def log(x):
    """Natural logarithm, bit-exact to glibc 2.36 __log_fma.

    x = 2^k z with z in [0x1.6p-1, 0x1.6p0) split into 128 subintervals; with table values
    invc ~ 1/c and logc = log(c) (c near the subinterval centre, chosen so logc needs <= 43
    fractional bits and is accurate to ~2^-70):  r = z*invc - 1 (one fma, exact enough),
    log(x) = k ln2 + logc + log1p(r), log1p(r) - r by a degree-6 polynomial.
    Inputs within [1 - 2^-4, 1 + 0x1.09p-4) take a separate path: log(1+r) directly by a
    degree-11 polynomial in r = x - 1 plus a careful hi/lo split of r - r^2/2, since there the
    table path would lose accuracy to cancellation.  Zero, negative, inf, nan and subnormals are
    dispatched on the top 16 bits (subnormals are rescaled by 2^52).
    """
    ix = _bits(x)
    if _LOG_NEAR_ONE_LO <= ix < _LOG_NEAR_ONE_HI:  # (signed: negative x never lands here)
        # close to 1.0
        if ix == _ONE_BITS:
            return 0.0
        r = x - 1.0
        r2 = r * r
        r3 = r * r2
        p1 = fma(r2, _LOG_B3, fma(r, _LOG_B2, _LOG_B1))
        p2 = fma(r2, _LOG_B6, fma(r, _LOG_B5, _LOG_B4))
        p3 = fma(r3, _LOG_B10, fma(r2, _LOG_B9, fma(r, _LOG_B8, _LOG_B7)))
        p = fma(fma(p3, r3, p2), r3, p1)
        # rhi = r + w - w with w = r*2^27 (GCC fused both products): top 26 bits of r
        t = fma(r, 134217728.0, r)
        rhi = fma(-r, 134217728.0, t)
        rlo = r - rhi
        rhi2 = rhi * rhi  # exact
        hi = fma(rhi2, _LOG_B0, r)
        lo = fma(rhi2, _LOG_B0, r - hi)
        lo = fma(_LOG_B0 * rlo, r + rhi, lo)
        y = fma(p, r3, lo)
        return hi + y
    top = (ix >> 48) & 0xFFFF
    if top < 0x0010 or top >= 0x7FF0:
        # x < 0x1p-1022 or inf or nan
        if (ix << 1) == 0:
            return _NEG_INF  # log(+-0) = -inf (glibc: -1/0, divide-by-zero)
        if ix == _INF_BITS:
            return x
        if x != x:
            return x - x  # nan: quieted x (glibc __math_invalid)
        if (top & 0x8000) != 0:
            # x < 0 (incl. -inf).  numba's math.log binds log@GLIBC_2.2.5, the SVID/POSIX compat
            # wrapper, whose __kernel_standard returns the constant NAN (+nan, 0x7ff8...) here;
            # log@@GLIBC_2.29 (what C code linked today gets) would return the default NaN
            # 0xfff8... (= _invalid(x)).  We follow numba's libm binding.
            return _POS_NAN
        ix = _bits(x * 4503599627370496.0) - (52 << 52)  # subnormal: normalise
    tmp = ix - _LOG_OFF
    i = (tmp >> 45) & 127
    k = tmp >> 52
    iz = ix - (tmp & _EXP_MASK)
    invc = _LOG_INVC[i]
    logc = _LOG_LOGC[i]
    z = _float(iz)
    r = fma(z, invc, -1.0)
    kd = float(k)
    w = fma(kd, _LOG_LN2_HI, logc)
    hi = w + r
    lo = fma(kd, _LOG_LN2_LO, (w - hi) + r)
    r2 = r * r
    q = fma(r2, fma(r, _LOG_A4, _LOG_A3), fma(r, _LOG_A2, _LOG_A1))
    y = fma(r * r2, q, fma(r2, _LOG_A0, lo))
    return y + hi


# ================================================================================================
# log1p
# ================================================================================================
@njit
def log1p(x):
    """log(1 + x), bit-exact to glibc 2.36 __log1p_fma (fdlibm algorithm).

    1 + x = 2^k (1 + f) with sqrt(2)/2 < 1+f < sqrt(2); when k != 0, u = 1 + x is rounded and the
    correction c = ((1+x) - u)/u is carried.  log(1+f) = f - (hfsq - s (hfsq + R)), hfsq = f^2/2,
    s = f/(2+f), R a degree-14 even polynomial in s.  Paths: x <= -1 (nan / -inf); |x| < 2^-29
    (x - x^2/2, or x itself below 2^-54); -0.2929 < x < 0.41422 needs no reduction (k = 0, f = x);
    x >= 2^53 reduces x itself (c = 0); f tiny (high word of f zero) uses a short series.
    """
    hx = _bits(x) >> 32  # signed high word
    ax = hx & 0x7FFFFFFF
    k = 1
    f = 0.0
    c = 0.0
    hu = 0
    if hx < 0x3FDA827A:  # x < 0.41422
        if ax >= 0x3FF00000:  # x <= -1.0 (or -nan)
            if x == -1.0:
                return _NEG_INF  # glibc: -two54/zero
            return _invalid(x)  # glibc: (x-x)/(x-x)
        if ax < 0x3E200000:  # |x| < 2^-29
            if ax < 0x3C900000:  # |x| < 2^-54
                return x
            return fma(-(x * x), 0.5, x)
        if hx > 0 or hx <= 0xBFD2BEC3 - (1 << 32):
            k = 0  # -0.2929 < x < 0.41422
            f = x
            hu = 1
    elif hx >= 0x7FF00000:
        return x + x
    if k != 0:
        if hx < 0x43400000:
            u = 1.0 + x
            hu = _bits(u) >> 32
            k = (hu >> 20) - 1023
            if k > 0:
                c = 1.0 - (u - x)
            else:
                c = x - (u - 1.0)
            c /= u
        else:
            u = x
            hu = _bits(u) >> 32
            k = (hu >> 20) - 1023
            c = 0.0
        hu &= 0x000FFFFF
        low = _bits(u) & 0xFFFFFFFF
        if hu < 0x6A09E:
            u = _float(((hu | 0x3FF00000) << 32) | low)  # normalise u
        else:
            k += 1
            u = _float(((hu | 0x3FE00000) << 32) | low)  # normalise u/2
            hu = (0x00100000 - hu) >> 2
        f = u - 1.0
    hfsq = (0.5 * f) * f
    kd = float(k)
    if hu == 0:  # |f| < 2^-20
        if f == 0.0:
            if k == 0:
                return 0.0
            return fma(kd, _L1P_LN2_HI, fma(kd, _L1P_LN2_LO, c))
        R = hfsq * fma(-f, _TWO_THIRDS, 1.0)
        if k == 0:
            return f - R
        return fma(kd, _L1P_LN2_HI, -((R - fma(kd, _L1P_LN2_LO, c)) - f))
    s = f / (2.0 + f)
    z = s * s
    R2 = fma(z, _L1P_LP3, _L1P_LP2)
    R3 = fma(z, _L1P_LP5, _L1P_LP4)
    R4 = fma(z, _L1P_LP7, _L1P_LP6)
    z2 = z * z
    z4 = z2 * z2
    z6 = z2 * z4
    R = fma(z6, R4, fma(z4, R3, fma(z, _L1P_LP1, z2 * R2)))
    t = (hfsq + R) * s
    if k == 0:
        return f - (hfsq - t)
    return fma(kd, _L1P_LN2_HI, -((hfsq - (t + fma(kd, _L1P_LN2_LO, c))) - f))


# ================================================================================================
# pow
# ================================================================================================
@njit(inline="always")
def _pow_log(ix):
    """log(x) as hi + lo with ~15 extra bits (glibc log_inline).  ix: bits of x > 0, normalised.

    x = 2^k z, z in [0x1.69555p-1, 0x1.69555p0); invc has <= 9 significant bits so
    r = z*invc - 1 is exact; k ln2 + logc + r + A0 r^2 is summed with error-free transforms and
    the rest of log1p(r) added as a polynomial.
    """
    tmp = ix - _POW_OFF
    i = (tmp >> 45) & 127
    k = tmp >> 52
    iz = ix - (tmp & _EXP_MASK)
    z = _float(iz)
    kd = float(k)
    invc = _POW_INVC[i]
    logc = _POW_LOGC[i]
    logctail = _POW_LOGCTAIL[i]
    r = fma(z, invc, -1.0)
    t1 = fma(kd, _LOG_LN2_HI, logc)
    t2 = t1 + r
    lo1 = fma(kd, _LOG_LN2_LO, logctail)
    lo2 = t1 - t2 + r
    ar = _POW_A0 * r
    ar2 = r * ar
    ar3 = r * ar2
    hi = t2 + ar2
    lo3 = fma(ar, r, -ar2)
    lo4 = t2 - hi + ar2
    p = fma(ar2, fma(ar2, fma(r, _POW_A6, _POW_A5), fma(r, _POW_A4, _POW_A3)), fma(r, _POW_A2, _POW_A1))
    lo = fma(ar3, p, lo1 + lo2 + lo3 + lo4)
    y = hi + lo
    tail = hi - y + lo
    return y, tail


@njit(inline="always")
def _pow_exp_near_limits(tmp, sbits, ki):
    """exp result scale*(1+tmp) when it may overflow or underflow (glibc specialcase)."""
    if (ki & 0x80000000) == 0:
        # k > 0: the exponent of scale might have overflowed by <= 460
        scale = _float(sbits - (1009 << 52))
        return fma(scale, tmp, scale) * _TWO_1009
    # k < 0: round once in the subnormal range (avoid double rounding)
    sbits = sbits + (1022 << 52)
    scale = _float(sbits)
    p = scale * tmp  # used twice, so not fused
    y = scale + p
    if abs(y) < 1.0:
        one = -1.0 if y < 0.0 else 1.0
        lo = scale - y + p
        hi = one + y
        lo = one - hi + y + lo
        y = (hi + lo) - one
        if y == 0.0:
            y = _float(sbits & _SIGN_MASK)
    return _TWO_M1022 * y


@njit(inline="always")
def _pow_exp(x, xtail, sign_bias):
    """sign * exp(x + xtail) (glibc exp_inline): x = k ln2/128 + r, 2^(k/128) from the table,
    exp(r) - 1 by a degree-5 polynomial.  Tiny |x| gives +-1, |x| >= 1024 overflows/underflows,
    512 <= |x| < 1024 goes through _exp_special."""
    abstop = (_bits(x) >> 52) & 0x7FF
    special = False
    if abstop < 0x3C9 or abstop >= 0x408:  # |x| < 2^-54 or |x| >= 512
        if abstop < 0x3C9:
            one = 1.0 + x
            return -one if sign_bias != 0 else one
        if abstop >= 0x409:  # |x| >= 1024
            if _bits(x) < 0:
                return (-_TWO_M767 if sign_bias != 0 else _TWO_M767) * _TWO_M767
            return (-_TWO_769 if sign_bias != 0 else _TWO_769) * _TWO_769
        special = True
    kd = fma(_INV_LN2_N, x, _ROUND_SHIFT)  # z = InvLn2N*x; kd = z + Shift (fused)
    ki = _bits(kd)
    kd = kd - _ROUND_SHIFT
    r = fma(kd, _NEG_LN2_LO_N, fma(kd, _NEG_LN2_HI_N, x))
    r = xtail + r
    idx = 2 * (ki & 127)
    top = (ki + sign_bias) << 45
    tail = _float(_EXP_TAB[idx])
    sbits = _EXP_TAB[idx + 1] + top
    r2 = r * r
    tmp = fma(r2 * r2, fma(r, _EXP_C5, _EXP_C4), fma(r2, fma(r, _EXP_C3, _EXP_C2), tail + r))
    if special:
        return _pow_exp_near_limits(tmp, sbits, ki)
    scale = _float(sbits)
    return fma(scale, tmp, scale)


@njit(inline="always")
def _nan_add(x, y):
    """x + y where x or y is NaN, with x86 addsd's rule made explicit (LLVM may commute fadd):
    the result is the first operand's NaN if it is one, else the second's, quieted."""
    v = x if x != x else y
    return _float(_bits(v) | 0x0008000000000000)


@njit(inline="always")
def _checkint(iy):
    """0: y not an integer, 1: odd integer, 2: even integer (iy: bits of finite nonzero y)."""
    e = (iy >> 52) & 0x7FF
    if e < 0x3FF:
        return 0
    if e > 0x3FF + 52:
        return 2
    if (iy & ((1 << (0x3FF + 52 - e)) - 1)) != 0:
        return 0
    if (iy & (1 << (0x3FF + 52 - e))) != 0:
        return 1
    return 2


@njit(inline="always")
def _zeroinfnan(i):
    """bits i encode +-0, +-inf or nan."""
    return not _ult((i << 1) - 1, (_INF_BITS << 1) - 1)


@njit(inline="always")
def _issignaling(i):
    # glibc: 2 * (i ^ 0x0008000000000000) > 2 * 0x7ff8000000000000 (unsigned)
    return _ult(_QNAN2, (i ^ 0x0008000000000000) << 1)


@njit
def pow(x, y):
    """x**y, bit-exact to glibc 2.36 __pow_fma.

    pow = exp(y * log(x)): log(x) to ~68 bits as hi + lo (_pow_log, its own 128-entry table),
    y*log(x) as ehi + elo with an fma-exact product, then exp with the tail folded into the
    reduced argument (_pow_exp, exp's 2^(k/128) table).  Sign: negative x with odd integer y
    sets the sign bias, non-integer y is invalid (nan).  Special paths: y or x in {0, inf, nan};
    |y| < 2^-65 (x^y = 1 +- y) and |y| >= 2^63 (overflow/underflow or 1); subnormal x is
    normalised; results near overflow/underflow are finished in _exp_special.
    """
    sign_bias = 0
    ix = _bits(x)
    iy = _bits(y)
    topx = (ix >> 52) & 0xFFF
    topy = (iy >> 52) & 0xFFF
    aty = topy & 0x7FF
    if topx == 0 or topx >= 0x7FF or aty < 0x3BE or aty >= 0x43E:
        # x < 0x1p-1022 or x <= 0 or inf/nan; or |y| < 2^-65 or |y| >= 2^63 or nan
        if _zeroinfnan(iy):
            if (iy << 1) == 0:
                return _nan_add(x, y) if _issignaling(ix) else 1.0
            if ix == _ONE_BITS:
                return _nan_add(x, y) if _issignaling(iy) else 1.0
            if _ult(_INF_BITS << 1, ix << 1) or _ult(_INF_BITS << 1, iy << 1):
                return _nan_add(x, y)
            if (ix << 1) == (_ONE_BITS << 1):
                return 1.0
            if _ult(ix << 1, _ONE_BITS << 1) == (iy >= 0):
                return 0.0  # |x|<1 && y==inf or |x|>1 && y==-inf
            return y * y
        if _zeroinfnan(ix):
            x2 = x * x
            if ix < 0 and _checkint(iy) == 1:
                x2 = -x2
            if iy >= 0:
                return x2
            if x2 == 0.0:  # 1/(+-0) = +-inf (no division: see _invalid)
                return math.copysign(np.inf, x2)
            return 1.0 / x2
        # here x and y are nonzero finite
        if ix < 0:
            yint = _checkint(iy)
            if yint == 0:
                return _invalid(x)
            if yint == 1:
                sign_bias = _SIGN_BIAS
            ix &= _ABS_MASK
            topx &= 0x7FF
        if aty < 0x3BE or aty >= 0x43E:
            # sign_bias == 0 here because y is not odd
            if ix == _ONE_BITS:
                return 1.0
            if aty < 0x3BE:
                # |y| < 2^-65: x^y ~= 1 + y log(x)
                return 1.0 + y if _ult(_ONE_BITS, ix) else 1.0 - y
            if _ult(_ONE_BITS, ix) == (topy < 0x800):
                return _TWO_769 * _TWO_769  # overflow
            return _TWO_M767 * _TWO_M767  # underflow
        if topx == 0:
            # normalise subnormal x so the exponent becomes negative
            ix = (_bits(x * 4503599627370496.0) & _ABS_MASK) - (52 << 52)
    hi, lo = _pow_log(ix)
    ehi = y * hi
    elo = fma(y, lo, fma(y, hi, -ehi))
    return _pow_exp(ehi, elo, sign_bias)


# ----------------------------------------------------------------------------- sin and cos
# IBM's Accurate Mathematical Library (glibc's s_sin.c): |x| < 0.126 a Taylor polynomial; below
# 0.855 a table of sin and cos at k/128 (a double-double each) and short polynomials for the rest
# r: sin(t_k + r) = sin t_k cos r + cos t_k sin r; below 2.43 through pi/2 - |x|; below 105414350 a
# reduction x = n pi/2 + (a + da) with pi/2 in four pieces; beyond, an exact reduction with 2/pi
# to ~1800 bits (``_branred``; glibc runs the same plain code from both variants: no fma there).
#
# The sin/cos table is computed below from its definition (80-digit decimal series, each value
# rounded to a double and its rest rounded again). glibc's own table was computed to ~2^-110: 18
# of its 220 low words differ from these by at most 1.7e-33, which can change a result only where
# an intermediate falls within ~2^-110 of a rounding boundary (of the order of 2^-55 of the inputs
# in those cells): none in 10^8 inputs aimed at them and 2.5 * 10^7 others.

_S1 = _double("-0x1.5555555555555p-3")  # TAYLOR_SIN: a + a^3*(s1 + a^2*(s2 + ...)) ~ Taylor series of sin
_S2 = _double("0x1.1111111110ECEp-7")
_S3 = _double("-0x1.A01A019DB08B8p-13")
_S4 = _double("0x1.71DE27B9A7ED9p-19")
_S5 = _double("-0x1.ADDFFC2FCDF59p-26")
_SN3 = _double("-0x1.5555555555515p-3")  # sin r ~ r + r^3*(sn3 + r^2*sn5)        (|r| <= 1/256)
_SN5 = _double("0x1.11110e829872fp-7")
_CS2 = _double("0x1.0p-1")  # cos r ~ 1 - r^2*(cs2 + r^2*(cs4 + r^2*cs6))
_CS4 = _double("-0x1.5555555555535p-5")
_CS6 = _double("0x1.6c16bedd9e239p-10")
# reduction constants
_BIG = _double("0x1.8p45")  # _BIG + |x|: rounds |x| to a multiple of 1/128, index in the low bits
_HP0 = _double("0x1.921FB54442D18p0")  # pi/2 = _HP0 + _HP1 (double-double)
_HP1 = _double("0x1.1A62633145C07p-54")
_MP1 = _double("0x1.921FB58000000p0")  # pi/2 ~ _MP1 + _MP2 + _PP3 + _PP4 (short pieces: xn*_MP1 exact)
_MP2 = _double("-0x1.DDE973C000000p-27")
_PP3 = _double("-0x1.CB3B398000000p-55")
_PP4 = _double("-0x1.d747f23e32ed7p-83")
_HPINV = _double("0x1.45F306DC9C883p-1")  # 2/pi
_TOINT = _double("0x1.8p52")  # x*2/pi + _TOINT rounds to an integer n, read from the low bits
# branred.h constants (its _MP2 differs from usncs.h's)
_BR_MP1 = _double("0x1.921FB58000000p0")
_BR_MP2 = _double("-0x1.DDE9740000000p-27")
_SPLIT = 134217729.0  # 2^27 + 1 (Veltkamp split)
_T576 = 2.0**576
_TM600 = 2.0**-600
_TM24 = 2.0**-24
_BR_BIG = _double("0x1.8p52")
_BR_BIG1 = _double("0x1.8p54")

_SIN_TAYLOR_MAX = 0.126


_SINCOSTAB = np.array([float.fromhex(v) for v in _tables.SINCOSTAB])  # sin(k/128) hi, lo, cos(k/128) hi, lo
_TOVERP = np.array([float.fromhex(v) for v in _tables.TWO_OVER_PI])  # 2/pi in base-2^24 digits


@njit(inline="always")
def _taylor_sin(a, da):
    """sin(a + da) for |a| < 0.126: a + (P(a^2)*a - da/2)*a^2 + da."""
    xx = a * a
    p = fma(fma(fma(fma(_S5, xx, _S4), xx, _S3), xx, _S2), xx, _S1)
    return a + fma(xx, fma(p, a, -(0.5 * da)), da)


@njit(inline="always")
def _do_sin(x, dx):
    """sin(x + dx), |x| < ~0.86, |dx| tiny: Taylor near 0, else table point k/128 + remainder r."""
    if abs(x) < _SIN_TAYLOR_MAX:
        return _taylor_sin(x, dx)
    if x <= 0.0:
        dx = -dx
    ax = abs(x)
    u = _BIG + ax
    k = (_bits(u) & 0xFFFFFFFF) << 2
    r = ax - (u - _BIG)
    xx = r * r
    s = r + fma(r * xx, fma(_SN5, xx, _SN3), dx)  # sin(r + dx)
    c = fma(r, dx, xx * fma(fma(_CS6, xx, _CS4), xx, _CS2))  # 1 - cos(r + dx)
    sn = _SINCOSTAB[k]
    ssn = _SINCOSTAB[k + 1]
    cs = _SINCOSTAB[k + 2]
    ccs = _SINCOSTAB[k + 3]
    cor = fma(s, cs, fma(-c, sn, fma(s, ccs, ssn)))  # (ssn + s*ccs - sn*c) + cs*s
    return math.copysign(sn + cor, x)


@njit(inline="always")
def _do_cos(x, dx):
    """cos(x + dx), |x| < ~0.86: table point k/128 + remainder r (dx folded into r)."""
    if x < 0.0:
        dx = -dx
    ax = abs(x)
    u = _BIG + ax
    k = (_bits(u) & 0xFFFFFFFF) << 2
    r = ax - (u - _BIG) + dx
    xx = r * r
    s = fma(r * xx, fma(_SN5, xx, _SN3), r)  # sin r
    c = xx * fma(fma(_CS6, xx, _CS4), xx, _CS2)  # 1 - cos r
    sn = _SINCOSTAB[k]
    ssn = _SINCOSTAB[k + 1]
    cs = _SINCOSTAB[k + 2]
    ccs = _SINCOSTAB[k + 3]
    cor = fma(-s, sn, fma(-c, cs, fma(-s, ssn, ccs)))  # (ccs - s*ssn - cs*c) - sn*s
    return cs + cor


@njit(inline="always")
def _do_sincos(a, da, n):
    """Quadrant n of the reduced argument a + da."""
    if n & 1:
        v = _do_cos(a, da)
    else:
        v = _do_sin(a, da)
    return -v if n & 2 else v


@njit(inline="always")
def _reduce(x):
    """|x| < 105414350: x = n*pi/2 + (a + da); returns (a, da, n & 3)."""
    t = fma(x, _HPINV, _TOINT)
    xn = t - _TOINT
    y = fma(-xn, _MP2, fma(-xn, _MP1, x))
    n = _bits(t) & 3
    t2 = fma(-xn, _PP3, y)
    db = fma(-xn, _PP3, y - t2)
    b = fma(-xn, _PP4, t2)
    db = db + fma(-xn, _PP4, t2 - b)
    return b, db, n


@njit(inline="always")
def _branred_part(x):
    """One 26-bit half of the (scaled) argument times 2/pi: returns (b, bb, sum) as in glibc."""
    k = ((_bits(x) >> 52) & 2047) - 450
    k = k // 24 if k > 0 else 0
    gor = _float(_bits(_T576) - ((k * 24) << 52))  # 2^(576 - 24k)
    r0 = x * _TOVERP[k] * gor
    gor *= _TM24
    r1 = x * _TOVERP[k + 1] * gor
    gor *= _TM24
    r2 = x * _TOVERP[k + 2] * gor
    gor *= _TM24
    r3 = x * _TOVERP[k + 3] * gor
    gor *= _TM24
    r4 = x * _TOVERP[k + 4] * gor
    gor *= _TM24
    r5 = x * _TOVERP[k + 5] * gor
    s = (r0 + _BR_BIG) - _BR_BIG
    sm = s
    r0 -= s
    s = (r1 + _BR_BIG) - _BR_BIG
    sm += s
    r1 -= s
    s = (r2 + _BR_BIG) - _BR_BIG
    sm += s
    r2 -= s
    t = 0.0
    t += r5
    t += r4
    t += r3
    t += r2
    t += r1
    t += r0
    bb = (((((r0 - t) + r1) + r2) + r3) + r4) + r5
    s = (t + _BR_BIG) - _BR_BIG
    sm += s
    t -= s
    b = t + bb
    bb = (t - b) + bb
    s = (sm + _BR_BIG1) - _BR_BIG1
    sm -= s
    return b, bb, sm


@njit
def _branred(x):
    """105414350 <= |x| < inf: x = n*pi/2 + (a + aa) with 2/pi to ~1100 bits; (a, aa, n & 3).
    Plain double arithmetic (glibc's generic __branred, no fma)."""
    x = x * _TM600
    t = x * _SPLIT
    x1 = t - (t - x)
    x2 = x - x1
    b1, bb1, sum1 = _branred_part(x1)
    b2, bb2, sum2 = _branred_part(x2)
    sm = 0.0
    sm = sum1 + sum2
    b = b1 + b2
    if abs(b1) > abs(b2):
        bb = (b1 - b) + b2
    else:
        bb = (b2 - b) + b1
    if b > 0.5:
        b -= 1.0
        sm += 1.0
    elif b < -0.5:
        b += 1.0
        sm -= 1.0
    s = b + ((bb + bb1) + bb2)
    t = ((b - s) + bb) + (bb1 + bb2)
    b = s * _SPLIT
    t1 = b - (b - s)
    t2 = s - t1
    b = s * _HP0
    bb = (((t1 * _BR_MP1 - b) + t1 * _BR_MP2) + t2 * _BR_MP1) + ((t2 * _BR_MP2 + s * _HP1) + t * _HP0)
    s = b + bb
    t = (b - s) + bb
    return s, t, int(sm) & 3


@njit
def sin(x):
    """sin(x): glibc 2.36's x86-64 FMA result, bit for bit (section comment)."""
    k = (_bits(x) >> 32) & 0x7FFFFFFF
    if k < 0x3E500000:  # |x| < 2^-26: sin x = x (keeps -0, subnormals)
        return x
    if k < 0x3FEB6000:  # |x| < 0.855469
        return _do_sin(x, 0.0)
    if k < 0x400368FD:  # |x| < 2.426265: sin x = +-cos(pi/2 - |x|)
        return math.copysign(_do_cos(_HP0 - abs(x), _HP1), x)
    if k < 0x419921FB:  # |x| < 105414350
        a, da, n = _reduce(x)
        return _do_sincos(a, da, n)
    if k < 0x7FF00000:  # huge finite
        a, da, n = _branred(x)
        return _do_sincos(a, da, n)
    return _div(x, x)  # inf -> nan, nan -> nan


@njit
def cos(x):
    """cos(x): glibc 2.36's x86-64 FMA result, bit for bit (section comment)."""
    k = (_bits(x) >> 32) & 0x7FFFFFFF
    if k < 0x3E400000:  # |x| < 2^-27
        return 1.0
    if k < 0x3FEB6000:  # |x| < 0.855469
        return _do_cos(x, 0.0)
    if k < 0x400368FD:  # |x| < 2.426265: cos x = sin(pi/2 - |x|), 106-bit arg
        y = _HP0 - abs(x)
        a = y + _HP1
        da = (y - a) + _HP1
        return _do_sin(a, da)
    if k < 0x419921FB:  # |x| < 105414350
        a, da, n = _reduce(x)
        return _do_sincos(a, da, n + 1)
    if k < 0x7FF00000:
        a, da, n = _branred(x)
        return _do_sincos(a, da, n + 1)
    return _div(x, x)


# ----------------------------------------------------------------------------- float32 sin and cos
# Acrobot's first observation is gymnasium's: cos and sin of the float32 initial angles (|x| <= 0.1),
# computed by numpy in float32. numpy runs its own vector kernel (simd_sincos_f32 of numpy 2.4.6's
# loops_trigonometric.dispatch.cpp) on CPUs with FMA3 and the C library's sinf/cosf elsewhere, and the
# two differ on ~0.07 % (cos) and ~0.45 % (sin) of the inputs in [-0.1, 0.1]. These are the vector
# kernel's operations, one float32 lane at a time, every step rounded in float32 and every multiply-add
# fused as in numpy's binary (its rounding to the nearest quadrant is written as a multiply and an add,
# which GCC fused; for |x| < pi/4 that changes nothing). Compared with numpy's vector results over
# every float32 bit pattern: no difference. Constants: numpy's (polynomials "based on unpublished work
# by T. Myklebust", its comment says). Beyond |x| = 117435.992 (sin) / 71476.0625 (cos) numpy itself
# calls the C library's sinf/cosf, and so do these (never reached by Acrobot).
@intrinsic
def _fma32(typingctx, a, b, c):
    """a * b + c with one float32 rounding (``llvm.fma.f32``)."""

    def codegen(context, builder, signature, args):
        f = ir.FloatType()
        fn = builder.module.declare_intrinsic("llvm.fma", [f], ir.FunctionType(f, [f, f, f]))
        return builder.call(fn, args)

    return types.float32(types.float32, types.float32, types.float32), codegen


def _single(hex_literal: str) -> np.float32:
    value = np.float32(float.fromhex(hex_literal))
    assert float(value) == float.fromhex(hex_literal), hex_literal  # exact in float32
    return value


_F32_TWO_OVER_PI = _single("0x1.45f306p-1")
_F32_ROUND = _single("0x1.8p23")
_F32_PIO2 = (_single("-0x1.921fb0p+0"), _single("-0x1.5110b4p-22"), _single("-0x1.846988p-48"))  # -pi/2 in three pieces
_F32_COS = (_single("0x1.98e616p-16"), _single("-0x1.6c06dcp-10"), _single("0x1.55553cp-5"), np.float32(-0.5), np.float32(1.0))
_F32_SIN = (_single("0x1.7d3bbcp-19"), _single("-0x1.a06bbap-13"), _single("0x1.11119ap-7"), _single("-0x1.555556p-3"))
_F32_ZERO = np.float32(0.0)
_F32_SIN_MAX = np.float32(117435.992)
_F32_COS_MAX = np.float32(71476.0625)
_F32_NAN = np.uint32(0x7FC00000).view(np.float32)  # the quiet NaN numpy gives


@njit(inline="always")
def _sincos32(x, quadrant_shift):
    """sin (shift 0) or cos (shift 1) of float32 x: x = q pi/2 + r, a polynomial in r, by q's quadrant."""
    q = _fma32(x, _F32_TWO_OVER_PI, _F32_ROUND) - _F32_ROUND
    r = _fma32(q, _F32_PIO2[0], x)
    r = _fma32(q, _F32_PIO2[1], r)
    r = _fma32(q, _F32_PIO2[2], r)
    r2 = r * r
    n = np.int32(q) + quadrant_shift
    if (n & 1) == 0:
        p = _fma32(_fma32(_fma32(_F32_SIN[0], r2, _F32_SIN[1]), r2, _F32_SIN[2]), r2, _F32_SIN[3])
        v = _fma32(_fma32(p, r2, _F32_ZERO), r, r)  # the "+ 0" kept: it turns -0 into +0, as numpy's does
    else:
        c = _F32_COS
        v = _fma32(_fma32(_fma32(_fma32(c[0], r2, c[1]), r2, c[2]), r2, c[3]), r2, c[4])
    return _F32_ZERO - v if (n & 2) == 2 else v


@njit(inline="always")
def _trig32(x, cosine):
    x = np.float32(x)
    if x != x:
        return _F32_NAN
    if abs(x) <= (_F32_COS_MAX if cosine else _F32_SIN_MAX):
        return _sincos32(x, np.int32(1 if cosine else 0))
    return np.float32(math.cos(x) if cosine else math.sin(x))  # numpy's kernel hands these to the C library too


@njit(inline="always")
def sin32(x):
    """``np.sin`` of a float32 as numpy's vector kernel computes it (a float32; ``x`` a float32 value)."""
    return _trig32(x, False)


@njit(inline="always")
def cos32(x):
    """``np.cos`` of a float32 as numpy's vector kernel computes it."""
    return _trig32(x, True)


# ----------------------------------------------------------------------------- from Python
# Python code (CMA-ES's constants, Adam's bias correction, the mixing rule's log(1 - alpha), ...) calls
# these compiled, cached wrappers instead of math.exp/log/... (the C library's, machine-dependent).
@njit(cache=True)
def math_exp(x: float) -> float:
    """:func:`exp`, callable from Python."""
    return exp(x)


@njit(cache=True)
def math_log(x: float) -> float:
    """:func:`log`, callable from Python (log(0) = -inf, log of a negative number NaN, no exception)."""
    return log(x)


@njit(cache=True)
def math_log1p(x: float) -> float:
    """:func:`log1p`, callable from Python (log1p(-1) = -inf, no exception)."""
    return log1p(x)


@njit(cache=True)
def math_pow(x: float, y: float) -> float:
    """:func:`pow`, callable from Python (Python's ``x ** y`` on floats calls the C library's pow)."""
    return pow(x, y)
