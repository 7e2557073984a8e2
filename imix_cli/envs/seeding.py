"""Episode seeding: ``np.random.default_rng(s).uniform(low, high, size)`` for many seeds at once.

Used by the batched environments (:mod:`imix_cli.envs.cartpole`, :mod:`.acrobot`,
:mod:`.continuous_cartpole`) to start each member's episode exactly where gymnasium's
``reset(seed=s)`` would. Re-exported as :func:`imix_cli.envs.seeded_uniform`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["seeded_uniform"]

# --------------------------------------------------------------------------------------
# Episode seeding: ``np.random.default_rng(s).uniform(low, high, size)`` for many s at once.
#
# gymnasium's ``reset(seed=s)`` seeds ``np.random.Generator(PCG64(SeedSequence(s)))``, the same
# generator as ``np.random.default_rng(s)``; classic-control envs then draw their initial state
# with ``uniform(low, high, size)``. Building one generator per episode costs ~8 us in Python,
# which is 10-40% of a batched evaluation, so the same arithmetic is done here on arrays of
# seeds: SeedSequence's entropy mixing (uint32 hashes whose multiplier sequence does not depend
# on the data, so it is precomputed), PCG64 seeding and XSL-RR output with 128-bit state held
# as two uint64 words, and ``next_double = (x >> 11) * 2**-53``. Bit-identical to numpy
# (checked in tests/test_envs.py); seeds must be integers in [0, 2**64).
# --------------------------------------------------------------------------------------
_M32 = 0xFFFFFFFF
_INIT_A, _MULT_A, _INIT_B, _MULT_B = 0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R = 0xCA01F9DD, 0x4973F715
_POOL = 4
_PCG_MULT = (2549297995355413924, 4865540595714422341)  # PCG_DEFAULT_MULTIPLIER_128 (high, low)


def _hash_consts(init: int, mult: int, count: int) -> list[tuple[int, int]]:
    """(xor constant, multiplier) of each successive hashmix call."""
    out, h = [], init
    for _ in range(count):
        nxt = (h * mult) & _M32
        out.append((h, nxt))
        h = nxt
    return out


_HASH_A = _hash_consts(_INIT_A, _MULT_A, _POOL + _POOL * (_POOL - 1))
_HASH_B = _hash_consts(_INIT_B, _MULT_B, 8)


def _hashmix(v: np.ndarray, consts: tuple[int, int]) -> np.ndarray:
    v = (v ^ np.uint32(consts[0])) * np.uint32(consts[1])
    return v ^ (v >> np.uint32(16))


def _mix(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    r = np.uint32(_MIX_L) * x - np.uint32(_MIX_R) * y
    return r ^ (r >> np.uint32(16))


def _mulhi64(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """High 64 bits of the 128-bit product of uint64 arrays."""
    m, s = np.uint64(_M32), np.uint64(32)
    a0, a1, b0, b1 = a & m, a >> s, b & m, b >> s
    p00, p01, p10, p11 = a0 * b0, a0 * b1, a1 * b0, a1 * b1
    mid = (p00 >> s) + (p01 & m) + (p10 & m)
    return p11 + (p01 >> s) + (p10 >> s) + (mid >> s)


def _pcg_step(hi, lo, inc_hi, inc_lo):
    """state = state * MULT + inc (mod 2**128)."""
    mh, ml = np.uint64(_PCG_MULT[0]), np.uint64(_PCG_MULT[1])
    new_hi = hi * ml + lo * mh + _mulhi64(lo, ml)
    new_lo = lo * ml
    out_lo = new_lo + inc_lo
    carry = (out_lo < new_lo).astype(np.uint64)
    return new_hi + inc_hi + carry, out_lo


def seeded_uniform(seeds, low: float, high: float, size: int) -> np.ndarray:
    """(n, size) float64 array: row i equals ``np.random.default_rng(seeds[i]).uniform(low, high, size)``."""
    seeds = np.asarray(seeds).reshape(-1)
    if seeds.size and (seeds.dtype.kind not in "iu" or seeds.min() < 0):
        raise ValueError("seeds must be non-negative integers below 2**64")
    s = seeds.astype(np.uint64)
    with np.errstate(over="ignore"):
        # SeedSequence(s).pool: entropy words [lo32, hi32] (zero words hash like absent ones)
        ent = [s & np.uint64(_M32), s >> np.uint64(32), np.zeros_like(s), np.zeros_like(s)]
        ent = [e.astype(np.uint32) for e in ent]
        k = iter(_HASH_A)
        pool = [_hashmix(ent[i], next(k)) for i in range(_POOL)]
        for i_src in range(_POOL):
            for i_dst in range(_POOL):
                if i_src != i_dst:
                    pool[i_dst] = _mix(pool[i_dst], _hashmix(pool[i_src], next(k)))
        # generate_state(4, uint64): 8 uint32 words, little-endian pairs
        w = [_hashmix(pool[i % _POOL], _HASH_B[i]).astype(np.uint64) for i in range(8)]
        v = [w[2 * j] | (w[2 * j + 1] << np.uint64(32)) for j in range(4)]
        # pcg64_set_seed(state=(v0, v1), inc=(v2, v3)); srandom: state=0, inc=(initseq<<1)|1, step, +=, step
        inc_hi = (v[2] << np.uint64(1)) | (v[3] >> np.uint64(63))
        inc_lo = (v[3] << np.uint64(1)) | np.uint64(1)
        zero = np.zeros_like(s)
        hi, lo = _pcg_step(zero, zero, inc_hi, inc_lo)
        lo2 = lo + v[1]
        hi = hi + v[0] + (lo2 < lo).astype(np.uint64)
        hi, lo = _pcg_step(hi, lo2, inc_hi, inc_lo)
        low, high = float(low), float(high)
        span = high - low
        out = np.empty((s.size, size))
        for j in range(size):
            hi, lo = _pcg_step(hi, lo, inc_hi, inc_lo)
            x, rot = hi ^ lo, hi >> np.uint64(58)
            x = (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))
            out[:, j] = low + span * ((x >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0))
    return out
