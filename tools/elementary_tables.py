"""The tables of imix_cli.core.numerics.elementary, computed from their mathematical definitions: writes
imix_cli/core/numerics/elementary_tables.py (``--check``: recompute and compare, exit 1 on any difference).

    python tools/elementary_tables.py            # (re)write imix_cli/core/numerics/elementary_tables.py
    python tools/elementary_tables.py --check    # what tests/test_elementary.py runs

Why a generated file: the log table takes a search (~10 s), too long for every import. Every entry
is recomputed here (exact rationals via ``fractions``, transcendental values via ``decimal`` at 70-80
digits, rounded to double by Python's correctly rounded conversions); nothing is copied from a C
library. The definitions are those that ARM's optimized-routines (exp, log, pow) and IBM's
Accurate Mathematical Library (sin, cos) state for their tables, as glibc 2.36 ships them; for the
log table, whose comment only sketches a search, the reconstruction below reproduces all 128
entries, and so do the others.

Tables (N = 128):
  EXP_TAB[2k], EXP_TAB[2k+1]   2^(k/N) ~= H (1 + T): the bits of T, the bits of H - (k << 52)/N
  POW_INVC/LOGC/LOGCTAIL       pow's log: 1/c with few bits, log(c) split hi (multiple of 2^-43) + tail
  LOG_INVC/LOGC                log: 1/c chosen by a search so that log(c) is within ~2^-70 of a multiple of 2^-43
  SINCOSTAB                    sin(k/128) and cos(k/128), k < 110, each as a double and its rounded rest
  TWO_OVER_PI                  2/pi in base-2^24 digits (75 of them), for the reduction of huge arguments
"""

import struct
import sys
import time
from decimal import Decimal, getcontext, localcontext
from decimal import Decimal as D
from fractions import Fraction as F
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from imix_cli.core.numerics.elementary import fma  # noqa: E402

getcontext().prec = 70
N = 128
OUT = Path(__file__).resolve().parents[1] / "imix_cli" / "core" / "numerics" / "elementary_tables.py"


def asdouble(u):
    return struct.unpack("<d", struct.pack("<Q", u & 0xFFFFFFFFFFFFFFFF))[0]


def asuint64(x):
    return struct.unpack("<Q", struct.pack("<d", x))[0]


def dln(q):
    """Natural log of a positive rational (Fraction or float) as a 70-digit Decimal."""
    q = F(q)
    return D(q.numerator).ln() - D(q.denominator).ln()


def rn(x):
    """Round a Decimal or Fraction to the nearest double (float() of both is correctly rounded)."""
    return float(x)


# --------------------------------------------------------------------------------------------
# exp table: 2^(k/N) = H[k] * (1 + T[k]), H = RN(2^(k/N)), T = RN((2^(k/N) - H)/H)
# --------------------------------------------------------------------------------------------
def exp_table():
    ln2 = D(2).ln()
    tab = []
    for k in range(N):
        e = (D(k) / D(N) * ln2).exp()
        H = rn(e)
        T = rn((e - D(H)) / D(H))
        tab.append(asuint64(T))
        tab.append((asuint64(H) - (k << 52) // N) & 0xFFFFFFFFFFFFFFFF)
    return tab


# --------------------------------------------------------------------------------------------
# pow's log table.  z in [OFF, 2 OFF), OFF = 0x1.69555p-1, split by the top 7 mantissa bits of
# (asuint64(z) - asuint64(OFF)) into N subintervals; for subinterval i with centre m
#   invc = m < 1 ? round(N/m)/N : round(2N/m)/(2N)     (so z*invc - 1 is exact)
#   logc = round(2^43 log c)/2^43, logctail = RN(log c - logc),   c = 1/invc
# --------------------------------------------------------------------------------------------
POW_OFF = 0x3FE6955500000000


def pow_log_table():
    invcs, logcs, tails = [], [], []
    for i in range(N):
        zlo = F(asdouble(POW_OFF + (i << 45)))
        zhi = F(asdouble(POW_OFF + ((i + 1) << 45)))
        m = (zlo + zhi) / 2
        invc = F(round(N / m), N) if m < 1 else F(round(2 * N / m), 2 * N)
        lc = -dln(invc)
        logc = (lc * 2**43).to_integral_value() / D(2**43)  # exact in double: |logc| < 1, 43 frac bits
        invcs.append(rn(invc))
        logcs.append(rn(logc))
        tails.append(rn(lc - logc))
    return invcs, logcs, tails


# --------------------------------------------------------------------------------------------
# log's table.  z in [OFF, 2 OFF), OFF = 0x1.6p-1, subinterval i = top 7 bits of asuint64(z)-OFF:
# [0x1.6p-1 + i 2^-8, +2^-8) for i < 80 and [1 + (i-80) 2^-7, +2^-7) for i >= 80.
# glibc's comment: "c is near the center of the subinterval and is chosen by trying +-2^29
# floating point invc candidates around 1/center and selecting one for which
#   1) the rounding error in 0x1.8p9 + logc is 0,
#   2) the rounding error in z - chi - clo is < 0x1p-66 and
#   3) the rounding error in (double)log(c) is minimized (< 0x1p-66)."
# Reconstruction (verified against all 128 entries shipped in glibc 2.36):
#   candidates  invc = RN(1/centre) + j ulp,  |j| <= 2^29
#   logc        = RN(log c), c = 1/invc exactly
#   1)+3)       minimise |log c - logc| where logc must be a multiple of 2^-43 (ulp of 768);
#               equivalently minimise the distance of log c to the 2^-43 grid
#   2)          chi = RN(c), clo = RN(c - chi); z - chi is exact, and for the widest |z - chi|
#               in the subinterval (just above 2^-9 for i < 80, 2^-8 for i >= 80) the rounding
#               error of (z - chi) - clo is the distance of clo to the grid 2^-61 (resp. 2^-60).
#               Accept when that distance times invc (the error it causes in r = (z-chi-clo)*invc)
#               is < 2^-66.  (Across the table the accepted maximum is 0.9925*2^-66 and the smallest
#               rejected better-log candidate has 1.0056*2^-66, so the rule is pinned down.)
# The search is done per grid point: for each multiple K*2^-43 in range, the real j* with
# -log(invc0 + j* ulp) = K*2^-43 is computed in double-double, and integers j within a small
# distance of j* are candidates; these few are then evaluated exactly in Decimal/Fraction.
# --------------------------------------------------------------------------------------------
LOG_GRID = 2.0**-43


@njit
def _scan(mlo, mhi, D0hi, D0lo, Phi, Plo, thr):
    """For m in [mlo, mhi]: j*(m) = D0 + P*expm1(-m*2^-43); return the m whose j* is within thr
    of an integer.  Double-double; |j*| < 2^30 so the fraction is accurate to ~2^-40."""
    out = []
    for m in range(mlo, mhi + 1):
        t = m * LOG_GRID  # exact
        p1 = Phi * t
        e1 = fma(Phi, t, -p1)  # Phi*t = p1 + e1 exactly
        s = D0hi - p1  # two-sum
        bb = s - D0hi
        err = (D0hi - (s - bb)) + (-p1 - bb)
        lo = err + D0lo - e1 - Plo * t + Phi * (t * t) * 0.5 - Phi * (t * t * t) / 6.0
        f = (s - np.floor(s + 0.5)) + lo
        f -= np.floor(f + 0.5)
        if abs(f) < thr:
            out.append(m)
    return out


def _log_entry(i):
    centre = F(11, 16) + F(2 * i + 1, 512) if i < 80 else 1 + F(2 * (i - 80) + 1, 256)
    a = rn(1 / centre)
    u = 2.0 ** (int(np.frexp(a)[1]) - 53)
    G = D(LOG_GRID)
    K0 = int((-dln(a) / G).to_integral_value())
    E0 = (-(K0 * G)).exp()
    D0 = (E0 - D(a)) / D(u)  # j* for m = 0
    P = E0 / D(u)
    D0hi = rn(D0)
    D0lo = rn(D0 - D(D0hi))
    Phi = rn(P)
    Plo = rn(P - D(Phi))
    span = int(D(2**29 * u) / D(a) / G) + 4
    # |log c - K 2^-43| ~= (u/a)|j - j*| must be < 2^-66: keep |j - j*| < 1.05 * 2^-66 a/u
    thr = 1.05 * 2.0**-66 * a / u
    best = None
    for m in _scan(-span, span, D0hi, D0lo, Phi, Plo, thr):
        jstar = D0 + P * ((-(m * G)).exp() - 1)
        j = int(jstar.to_integral_value())
        if abs(j) > 2**29:
            continue
        invc = a + j * u  # exact: same binade throughout the window
        lc = -dln(invc)
        grid = (lc / G).to_integral_value() * G
        err = abs(lc - grid)
        if err >= D(2) ** -66:  # criterion 3
            continue
        c = 1 / F(invc)  # criterion 2
        chi = rn(c)
        clo = rn(c - F(chi))
        g2 = 2 ** (61 if i < 80 else 60)
        q = F(clo) * g2
        dist = abs(q - round(q)) / g2
        if dist * F(invc) >= F(1, 2**66):
            continue
        if best is None or err < best[0]:
            best = (err, invc)
    invc = best[1]
    logc = rn(-dln(invc))
    assert logc == float(grid_round(-dln(invc)))  # criterion 1: logc is a multiple of 2^-43
    return invc, logc


def grid_round(x):
    G = D(LOG_GRID)
    return (x / G).to_integral_value() * G


def log_table():
    invcs, logcs = [], []
    for i in range(N):
        invc, logc = _log_entry(i)
        invcs.append(invc)
        logcs.append(logc)
    return invcs, logcs


def sincos_table():
    """[sin(k/128) hi, lo, cos(k/128) hi, lo] for k = 0..109, hi = RN(f), lo = RN(f - hi)."""

    def series(x, first, n):  # sum_{j} (-1)^j x^(n+2j)/(n+2j)!
        term, total = first, Decimal(0)
        while term != 0 and abs(term) > Decimal(10) ** -70:
            total += term
            term = -term * x * x / ((n + 1) * (n + 2))
            n += 2
        return total

    out = []
    with localcontext() as ctx:
        ctx.prec = 80
        for k in range(110):
            x = Decimal(k) / 128
            for v in (series(x, x, 1), series(x, Decimal(1), 0)):
                hi = float(v)  # Decimal -> float is correctly rounded
                out += [hi, float(v - Decimal(hi))]
    return out


def two_over_pi_digits(ndig=75):
    """2/pi = sum_i TOVERP[i] * 2^(-24(i+1)), digits in [0, 2^24)."""
    bits = 24 * ndig + 64
    one = 1 << bits

    def atan_inv(m):  # atan(1/m) * 2^bits, integer series
        total, term, n, sign = 0, one // m, 1, 1
        while term:
            total += sign * (term // n)
            term //= m * m
            n += 2
            sign = -sign
        return total

    pi = 16 * atan_inv(5) - 4 * atan_inv(239)  # Machin; error a few units of 2^-bits
    two_over_pi = (2 << (2 * bits)) // pi  # (2/pi) * 2^bits
    v = two_over_pi >> (bits - 24 * ndig)  # keep 24*ndig fraction bits
    return [float((v >> (24 * (ndig - 1 - i))) & 0xFFFFFF) for i in range(ndig)]


def compute() -> dict:
    started = time.time()
    tables = {"EXP_TAB": exp_table()}
    tables["POW_INVC"], tables["POW_LOGC"], tables["POW_LOGCTAIL"] = pow_log_table()
    tables["LOG_INVC"], tables["LOG_LOGC"] = log_table()
    tables["SINCOSTAB"] = sincos_table()
    tables["TWO_OVER_PI"] = two_over_pi_digits()
    print(f"tables computed in {time.time() - started:.1f} s", file=sys.stderr)
    return tables


def render(tables: dict) -> str:
    out = ['"""GENERATED by tools/elementary_tables.py from the tables\' definitions (see there) -- do not edit."""', "", "# fmt: off"]
    for name, values in tables.items():
        if name == "EXP_TAB":
            body = ",\n".join("    " + ", ".join(f"0x{v:016x}" for v in values[k : k + 4]) for k in range(0, len(values), 4))
            out.append(f"{name} = [\n{body},\n]\n")
        else:
            body = ",\n".join("    " + ", ".join(f'"{v.hex()}"' for v in values[k : k + 4]) for k in range(0, len(values), 4))
            out.append(f"{name} = [\n{body},\n]\n")
    return "\n".join(out)


if __name__ == "__main__":
    text = render(compute())
    if "--check" in sys.argv:
        same = OUT.read_text() == text
        print(f"{OUT.name}: {'reproduced exactly' if same else 'DIFFERS from its definitions'}")
        sys.exit(0 if same else 1)
    OUT.write_text(text)
    print(f"wrote {OUT}")
