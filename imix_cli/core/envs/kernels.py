"""Compiled episodes: the built-in environments' dynamics and the MLP policy in one numba loop.

Why compiled: with importance mixing only ~2-3 members per seed and generation are fresh, so
a batched numpy rollout spends its time in per-step call overhead on tiny arrays (Acrobot's RK4
alone is ~190 numpy calls per step). Here each member's episode is one scalar loop, policy
and dynamics together, so a batch of 2 costs what its steps cost. Members run one after the
other, each from its own seed: member i's episode depends only on ``params[i]`` and
``seeds[i]``, never on the batch it is in.

What is implemented (the only implementation of these envs in imix; ``tests/test_envs.py``
and ``tests/test_continuous.py`` test it against gymnasium directly):

* **seeding** (:func:`uniform_row`): ``np.random.default_rng(s).uniform(low, high, size)``,
  i.e. the initial state of ``gymnasium``'s ``reset(seed=s)``: SeedSequence's entropy mixing
  (uint32 hashes whose multiplier sequence does not depend on the data, so it is precomputed),
  PCG64 seeding and XSL-RR output with the 128-bit state held as two uint64 words, and
  ``next_double = (x >> 11) * 2**-53``. Bit-identical to numpy for seeds in [0, 2**64).
* **MLP** (:func:`mlp_forward`): ``imix_cli.core.evaluation.policies``' layout (``W1`` (in x h1, row-major),
  ``b1``, ``W2``, ``b2``, ..., ``W_out``, ``b_out``; tanh hidden units; layer sizes given at
  run time), each output summed as ``((0 + w_0 x_0) + w_1 x_1) + ... + b``. Discrete actions:
  argmax by strict comparisons (ties to the lowest index, a NaN output never takes over);
  continuous: ``tanh``.
* **CartPole** (:func:`cartpole_step`): ``gymnasium``'s ``CartPoleEnv.step`` (Euler, its
  constants read from the class), expression for expression in the same order, so states are
  bit-identical to ``CartPole-v1``'s; the force is ``+-force_mag`` (discrete) or
  ``FORCE_MAG * clip(a, -1, 1)`` with NaN -> 0 (``imix/ContinuousCartPole*``).
* **Acrobot** (:func:`acrobot_step`): ``AcrobotEnv``'s ``_dsdt`` + ``rk4`` over ``[0, 0.2]``,
  ``wrap`` / ``bound`` and ``_terminal``, again in gymnasium's order; the only difference is
  that gymnasium squares with numpy's scalar ``x**2`` (libm ``pow``, not always correctly
  rounded) where this uses ``x * x``: next states differ by a few ulps on ~1 step in 400.

Math functions (``tanh``, ``cos``, ``sin``) are :mod:`imix_cli.core.numerics.elementary`'s, not the C library's,
whose last bits depend on the CPU (glibc runs an FMA build on CPUs that have FMA and an SSE2 build
on the others); they give what glibc's FMA build gives, bit for bit. A hidden layer's ``tanh`` runs
as a loop of its own over the layer's units, which compiles to vector instructions. No
``fastmath``: IEEE semantics, no reassociation, no FMA contraction beyond the fused
multiply-adds written out in :mod:`imix_cli.core.numerics.elementary`.

Compilation: ``@njit(cache=True)``: the machine code is written to numba's on-disk cache on
first use (in the Python environment, :func:`imix_cli.core.numerics.numba_cache.shared_cache_root`; numba's
``__pycache__`` or the user's cache directory when that is not writable) and loaded from there by every later process,
spawned workers included. numba invalidates a cached function when *its* file changes, not when
a callee in another file does (:mod:`imix_cli.core.numerics.elementary`'s functions are compiled in): imix's
cache locator (:mod:`imix_cli.core.numerics.numba_cache`) stamps these kernels with every compiled source of the package.
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium.envs.classic_control.acrobot import AcrobotEnv
from gymnasium.envs.classic_control.cartpole import CartPoleEnv
from numba import njit

from imix_cli.core.envs.continuous_cartpole import FORCE_MAG
from imix_cli.core.numerics import elementary as el

__all__ = [
    "uniform_row",
    "seeded_uniform_rows",
    "mlp_forward",
    "cartpole_step",
    "cartpole_steps",
    "cartpole_episodes",
    "acrobot_dsdt",
    "acrobot_step",
    "acrobot_steps",
    "acrobot_episodes",
    "acrobot_seeded_episodes",
    "FORCE_MAG",
]

# ============================================================================= seeding
_U = np.uint64
_M32 = _U(0xFFFFFFFF)
_INIT_A, _MULT_A, _INIT_B, _MULT_B = 0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R = _U(0xCA01F9DD), _U(0x4973F715)
_POOL = 4
_PCG_MULT_HI, _PCG_MULT_LO = _U(2549297995355413924), _U(4865540595714422341)  # PCG_DEFAULT_MULTIPLIER_128


def _hash_consts(init: int, mult: int, count: int) -> np.ndarray:
    """(count, 2) uint64: (xor constant, multiplier) of each successive SeedSequence hashmix call."""
    out, h = [], init
    for _ in range(count):
        nxt = (h * mult) & 0xFFFFFFFF
        out.append((h, nxt))
        h = nxt
    return np.array(out, dtype=np.uint64)


_HASH_A = _hash_consts(_INIT_A, _MULT_A, _POOL + _POOL * (_POOL - 1))
_HASH_B = _hash_consts(_INIT_B, _MULT_B, 8)


@njit(cache=True)
def _hashmix(v, xor_const, mult):
    v = ((v ^ xor_const) * mult) & _M32  # uint32 arithmetic in uint64 words
    return v ^ (v >> _U(16))


@njit(cache=True)
def _mix(x, y):
    r = (_MIX_L * x - _MIX_R * y) & _M32
    return r ^ (r >> _U(16))


@njit(cache=True)
def _mulhi64(a, b):
    """High 64 bits of the 128-bit product of two uint64."""
    s = _U(32)
    a0, a1, b0, b1 = a & _M32, a >> s, b & _M32, b >> s
    p00, p01, p10, p11 = a0 * b0, a0 * b1, a1 * b0, a1 * b1
    mid = (p00 >> s) + (p01 & _M32) + (p10 & _M32)
    return p11 + (p01 >> s) + (p10 >> s) + (mid >> s)


@njit(cache=True)
def _pcg_step(hi, lo, inc_hi, inc_lo):
    """state = state * MULT + inc (mod 2**128), as (hi, lo) words."""
    new_hi = hi * _PCG_MULT_LO + lo * _PCG_MULT_HI + _mulhi64(lo, _PCG_MULT_LO)
    new_lo = lo * _PCG_MULT_LO
    out_lo = new_lo + inc_lo
    carry = _U(1) if out_lo < new_lo else _U(0)
    return new_hi + inc_hi + carry, out_lo


@njit(cache=True)
def uniform_row(seed, low, high, out):
    """Fill ``out`` with ``np.random.default_rng(seed).uniform(low, high, out.size)`` (seed: uint64)."""
    seed = _U(seed)
    ent = (seed & _M32, seed >> _U(32), _U(0), _U(0))  # SeedSequence(seed) entropy words
    pool = np.empty(_POOL, dtype=np.uint64)
    k = 0
    for i in range(_POOL):
        pool[i] = _hashmix(ent[i], _HASH_A[k, 0], _HASH_A[k, 1])
        k += 1
    for i_src in range(_POOL):
        for i_dst in range(_POOL):
            if i_src != i_dst:
                pool[i_dst] = _mix(pool[i_dst], _hashmix(pool[i_src], _HASH_A[k, 0], _HASH_A[k, 1]))
                k += 1
    # generate_state(4, uint64): 8 uint32 words, little-endian pairs
    v = np.empty(4, dtype=np.uint64)
    for j in range(4):
        w0 = _hashmix(pool[(2 * j) % _POOL], _HASH_B[2 * j, 0], _HASH_B[2 * j, 1])
        w1 = _hashmix(pool[(2 * j + 1) % _POOL], _HASH_B[2 * j + 1, 0], _HASH_B[2 * j + 1, 1])
        v[j] = w0 | (w1 << _U(32))
    # pcg64_set_seed(state=(v0, v1), inc=(v2, v3)): state=0, inc=(initseq<<1)|1, step, +=, step
    inc_hi = (v[2] << _U(1)) | (v[3] >> _U(63))
    inc_lo = (v[3] << _U(1)) | _U(1)
    hi, lo = _pcg_step(_U(0), _U(0), inc_hi, inc_lo)
    lo2 = lo + v[1]
    hi = hi + v[0] + (_U(1) if lo2 < lo else _U(0))
    hi, lo = _pcg_step(hi, lo2, inc_hi, inc_lo)
    span = high - low
    for j in range(out.shape[0]):
        hi, lo = _pcg_step(hi, lo, inc_hi, inc_lo)
        x = hi ^ lo
        rot = hi >> _U(58)
        x = (x >> rot) | (x << ((_U(64) - rot) & _U(63)))
        out[j] = low + span * (np.float64(x >> _U(11)) * (1.0 / 9007199254740992.0))


@njit(cache=True)
def seeded_uniform_rows(seeds, low, high, size):
    """(n, size): row i is ``np.random.default_rng(seeds[i]).uniform(low, high, size)``."""
    out = np.empty((seeds.shape[0], size))
    for i in range(seeds.shape[0]):
        uniform_row(seeds[i], low, high, out[i])
    return out


# ============================================================================= policy
@njit(cache=True)
def mlp_forward(p, sizes, x, y):
    """Outputs of the MLP with flat parameters ``p`` and layer sizes ``sizes`` (in, hidden..., out).

    The input is ``x[:sizes[0]]``; ``x`` and ``y`` (both at least ``max(sizes)`` long) are
    overwritten alternately; the returned array (one of them) holds the outputs in its first
    ``sizes[-1]`` entries.
    """
    k = 0
    last = sizes.shape[0] - 2
    for layer in range(last + 1):
        n_in, n_out = sizes[layer], sizes[layer + 1]
        bias = k + n_in * n_out
        for j in range(n_out):
            acc = 0.0
            for i in range(n_in):
                acc += p[k + i * n_out + j] * x[i]
            y[j] = acc + p[bias + j]
        if layer < last:  # a loop of its own: it compiles to vector instructions (el.tanh_lanes)
            for j in range(n_out):
                y[j] = el.tanh_lanes(y[j])
        k = bias + n_out
        x, y = y, x
    return x


@njit(cache=True)
def _buffer_width(params, sizes):
    """The widest layer; raises if ``params``' rows do not have the MLP's parameter count
    (the kernels read parameters without bounds checks)."""
    width, count = sizes[0], 0
    for layer in range(sizes.shape[0] - 1):
        width = max(width, sizes[layer + 1])
        count += sizes[layer] * sizes[layer + 1] + sizes[layer + 1]
    if params.shape[1] != count:
        raise ValueError("params do not have the parameter count of the layer sizes")
    return width


@njit(cache=True)
def _record(trace, i, t, s):
    """``trace[i, t] = s`` as a loop: numba's general slice assignment compiles for seconds."""
    for j in range(s.shape[0]):
        trace[i, t, j] = s[j]


@njit(cache=True)
def _argmax(y, n):
    """Index of the largest of ``y[:n]``: strict comparisons, ties to the lowest, NaN never wins."""
    best, a = y[0], 0
    for j in range(1, n):
        if y[j] > best:
            best, a = y[j], j
    return a


# ============================================================================= CartPole
_CP = CartPoleEnv()  # gymnasium's constants, used as its step() uses them
assert _CP.kinematics_integrator == "euler" and not _CP._sutton_barto_reward, "gymnasium's CartPole defaults changed"
_GRAVITY, _MASSPOLE, _TOTAL_MASS = float(_CP.gravity), float(_CP.masspole), float(_CP.total_mass)
_LENGTH, _PML, _TAU = float(_CP.length), float(_CP.polemass_length), float(_CP.tau)
_CP_FORCE_MAG = float(_CP.force_mag)
_X_THRESHOLD, _THETA_THRESHOLD = float(_CP.x_threshold), float(_CP.theta_threshold_radians)
assert _CP_FORCE_MAG == FORCE_MAG  # imix/ContinuousCartPole's newtons per unit of action
del _CP


@njit(cache=True)
def cartpole_step(s, force):
    """One ``CartPoleEnv.step`` of state ``s`` (4,) float64 in place, with the given force; terminated?"""
    x, x_dot, theta, theta_dot = s[0], s[1], s[2], s[3]
    costheta = el.cos(theta)
    sintheta = el.sin(theta)
    temp = (force + _PML * (theta_dot * theta_dot) * sintheta) / _TOTAL_MASS
    thetaacc = (_GRAVITY * sintheta - costheta * temp) / (_LENGTH * (4.0 / 3.0 - _MASSPOLE * (costheta * costheta) / _TOTAL_MASS))
    xacc = temp - _PML * thetaacc * costheta / _TOTAL_MASS
    x = x + _TAU * x_dot
    x_dot = x_dot + _TAU * xacc
    theta = theta + _TAU * theta_dot
    theta_dot = theta_dot + _TAU * thetaacc
    s[0], s[1], s[2], s[3] = x, x_dot, theta, theta_dot
    return x < -_X_THRESHOLD or x > _X_THRESHOLD or theta < -_THETA_THRESHOLD or theta > _THETA_THRESHOLD


@njit(cache=True)
def continuous_force(a):
    """``FORCE_MAG * clip(a, -1, 1)``, a NaN action pushing with force 0."""
    if a != a:
        a = 0.0
    elif a > 1.0:
        a = 1.0
    elif a < -1.0:
        a = -1.0
    return FORCE_MAG * a


@njit(cache=True)
def cartpole_steps(states, forces):
    """Test entry point: one step of each state (n, 4) with its force: (next states, terminated)."""
    out = states.copy()
    terminated = np.empty(states.shape[0], dtype=np.bool_)
    for i in range(states.shape[0]):
        terminated[i] = cartpole_step(out[i], forces[i])
    return out, terminated


#: Lanes of :func:`_cartpole_episodes_in_lanes` and :func:`_acrobot_episodes_in_lanes`, and the batch from which
#: :func:`cartpole_episodes` and :func:`acrobot_episodes` use them: a step of 8 lanes costs ~4 steps of one episode
#: alone (CartPole, the 2x8 tanh policy: ~1,000 against ~245 ns), so 8 members (one lane-step each, then a tail) already
#: gain; the compiled loop hands over the fresh members of up to SEEDS_PER_CALL seeds at once.
#: Once no member waits and fewer than ``ALONE_BELOW`` lanes still run (a population's last, longest episodes), each
#: finishes alone: a lane-step costs about as much with two lanes running as with eight.
LANES = 8
LANES_FROM = 8
ALONE_BELOW = 4


@njit(cache=True)
def _cartpole_force(continuous, a0, a1):
    """The force of a step from the policy's outputs: ``FORCE_MAG * tanh(a0)`` (continuous), else
    ``+-force_mag`` by the argmax of (a0, a1) (strict comparison: a tie or a NaN pushes left)."""
    if continuous:
        return continuous_force(el.tanh(a0))
    return _CP_FORCE_MAG if a1 > a0 else -_CP_FORCE_MAG


@njit(cache=True)
def _cartpole_reward(sparse, last, total):
    """(reward, running total) of a step: 1; or, sparse, 0 until the episode's ``last`` step, which pays its total."""
    if sparse:
        total += 1.0
        return (total if last else 0.0), total
    return 1.0, total


@njit(cache=True)
def cartpole_episodes(params, seeds, sizes, continuous, sparse, max_steps, returns, steps, trace):
    """One CartPole episode per member: ``returns[i]``, ``steps[i]`` of ``params[i]`` from ``seeds[i]``.

    ``continuous``: one tanh output as ``imix/ContinuousCartPole`` (force ``FORCE_MAG * a``),
    else the argmax of two outputs as CartPole-v1 (``+-force_mag``). ``sparse``: the Hard
    variant's reward (0 but on the last step: terminated or the ``max_steps``-th, which pays
    the episode's total); the return is the same. Reward 1 per step otherwise. ``trace``
    (B, max_steps + 1, 4), if not empty, receives each member's states from the initial one on.
    From :data:`LANES_FROM` members on, :func:`_cartpole_episodes_in_lanes` runs them (the same numbers).
    """
    if params.shape[0] >= LANES_FROM and max_steps > 0:
        _cartpole_episodes_in_lanes(params, seeds, sizes, continuous, sparse, max_steps, returns, steps, trace)
        return
    width = _buffer_width(params, sizes)
    x, y = np.empty(width), np.empty(width)
    s = np.empty(4)
    for i in range(params.shape[0]):
        uniform_row(seeds[i], -0.05, 0.05, s)
        if trace.shape[0] > 0:
            _record(trace, i, 0, s)
        returns[i], steps[i] = _cartpole_run(params[i], sizes, continuous, sparse, max_steps, s, (0, 0.0, 0.0), trace, i, x, y)


@njit(cache=True)
def _cartpole_run(p, sizes, continuous, sparse, max_steps, s, at, trace, i, x, y):
    """Member ``i``'s episode (parameters ``p``) alone, from state ``s`` at ``at`` = (step, return, running total) to its
    end: (return, steps). The whole episode of :func:`cartpole_episodes`, or the rest of one begun in a lane
    (:func:`_cartpole_episodes_in_lanes`)."""
    t, ret, total = at
    record = trace.shape[0] > 0
    while t < max_steps:
        for j in range(4):
            x[j] = np.float64(np.float32(s[j]))  # the observation is the state as float32
        out = mlp_forward(p, sizes, x, y)
        terminated = cartpole_step(s, _cartpole_force(continuous, out[0], out[1] if not continuous else 0.0))
        t += 1
        if record:
            _record(trace, i, t, s)
        reward, total = _cartpole_reward(sparse, terminated or t == max_steps, total)
        ret += reward
        if terminated:
            break
    return ret, t


@njit(cache=True)
def _mlp_lanes(params_t, sizes, x, y):
    """:func:`mlp_forward` of :data:`LANES` members at once: member g's parameters are ``params_t[:, g]`` and
    its inputs ``x[:sizes[0], g]``; each member's operations are mlp_forward's, in its order, while the loops
    over the members, innermost, compile to vector instructions. Returns the buffer holding the outputs."""
    k = 0
    last = sizes.shape[0] - 2
    acc = np.empty(LANES)
    for layer in range(last + 1):
        n_in, n_out = sizes[layer], sizes[layer + 1]
        bias = k + n_in * n_out
        for j in range(n_out):
            for g in range(LANES):
                acc[g] = 0.0
            for i in range(n_in):
                row = k + i * n_out + j
                for g in range(LANES):
                    acc[g] += params_t[row, g] * x[i, g]
            for g in range(LANES):
                y[j, g] = acc[g] + params_t[bias + j, g]
        if layer < last:
            for j in range(n_out):
                for g in range(LANES):
                    y[j, g] = el.tanh_lanes(y[j, g])
        k = bias + n_out
        x, y = y, x
    return x


@njit(cache=True)
def _load_lane(params, seeds, member, lane, params_t, s, trace):
    """Start ``member``'s episode in ``lane``: its parameters into ``params_t[:, lane]``, its initial state."""
    for q in range(params.shape[1]):
        params_t[q, lane] = params[member, q]
    uniform_row(seeds[member], -0.05, 0.05, s[lane])
    if trace.shape[0] > 0:
        _record(trace, member, 0, s[lane])


@njit(cache=True)
def _cartpole_episodes_in_lanes(params, seeds, sizes, continuous, sparse, max_steps, returns, steps, trace):
    """:func:`cartpole_episodes`, :data:`LANES` episodes stepped together: one policy evaluation for all of them
    (:func:`_mlp_lanes`), then each one's step; a lane whose episode ends takes the next member. Why: a step of
    one episode is a chain of dependent operations (the policy's layers, then the dynamics), so one episode at a
    time leaves the CPU waiting; eight independent ones fill it (~2x the steps per second on a population).
    Every member's numbers are those of the one-at-a-time loop, bit for bit (tests/test_envs.py)."""
    n = params.shape[0]
    width = _buffer_width(params, sizes)
    params_t = np.zeros((params.shape[1], LANES))
    x, y = np.zeros((width, LANES)), np.zeros((width, LANES))
    s = np.zeros((LANES, 4))
    member = np.full(LANES, -1)
    t = np.zeros(LANES, dtype=np.int64)
    ret, total = np.zeros(LANES), np.zeros(LANES)
    x1, y1 = np.empty(width), np.empty(width)
    record = trace.shape[0] > 0
    started = 0
    for g in range(min(LANES, n)):
        _load_lane(params, seeds, started, g, params_t, s, trace)
        member[g] = started
        started += 1
    running = started
    while running > 0:
        for g in range(LANES):
            for j in range(4):
                x[j, g] = np.float64(np.float32(s[g, j]))  # idle lanes compute on their last state, unused
        out = _mlp_lanes(params_t, sizes, x, y)
        for g in range(LANES):
            i = member[g]
            if i < 0:
                continue
            terminated = cartpole_step(s[g], _cartpole_force(continuous, out[0, g], out[1, g] if not continuous else 0.0))
            t[g] += 1
            if record:
                _record(trace, i, t[g], s[g])
            last = terminated or t[g] == max_steps
            reward, total[g] = _cartpole_reward(sparse, last, total[g])
            ret[g] += reward
            if last:
                returns[i], steps[i] = ret[g], t[g]
                ret[g], total[g], t[g] = 0.0, 0.0, 0
                if started < n:
                    _load_lane(params, seeds, started, g, params_t, s, trace)
                    member[g] = started
                    started += 1
                else:
                    member[g] = -1
                    running -= 1
        if started == n and 0 < running < ALONE_BELOW:  # the last episodes: each finishes alone
            for g in range(LANES):
                i = member[g]
                if i >= 0:
                    returns[i], steps[i] = _cartpole_run(params[i], sizes, continuous, sparse, max_steps, s[g], (t[g], ret[g], total[g]), trace, i, x1, y1)
            running = 0


# ============================================================================= Acrobot
_E = AcrobotEnv
assert _E.dt == 0.2 and _E.torque_noise_max == 0.0 and _E.book_or_nips == "book", "gymnasium's Acrobot changed"
_M1, _M2 = float(_E.LINK_MASS_1), float(_E.LINK_MASS_2)
_L1, _LC1, _LC2 = float(_E.LINK_LENGTH_1), float(_E.LINK_COM_POS_1), float(_E.LINK_COM_POS_2)
_I1 = _I2 = float(_E.LINK_MOI)
_G = 9.8
_PI = math.pi
_MAX_VEL_1, _MAX_VEL_2 = float(_E.MAX_VEL_1), float(_E.MAX_VEL_2)
_TORQUES = np.array(_E.AVAIL_TORQUE, dtype=np.float64)
_DT = _E.dt - 0  # rk4 over t = [0, dt]
_DT2 = _DT / 2.0
_DT6 = _DT / 6.0
del _E


@njit(cache=True)
def acrobot_dsdt(t1, t2, dt1, dt2, a, k):
    """``AcrobotEnv._dsdt`` (book): the four derivatives into ``k`` (4,), gymnasium's expressions."""
    c2, s2 = el.cos(t2), el.sin(t2)
    d1 = _M1 * (_LC1 * _LC1) + _M2 * (_L1 * _L1 + _LC2 * _LC2 + 2 * _L1 * _LC2 * c2) + _I1 + _I2
    d2 = _M2 * (_LC2 * _LC2 + _L1 * _LC2 * c2) + _I2
    phi2 = _M2 * _LC2 * _G * el.cos(t1 + t2 - _PI / 2.0)
    phi1 = -_M2 * _L1 * _LC2 * (dt2 * dt2) * s2 - 2 * _M2 * _L1 * _LC2 * dt2 * dt1 * s2 + (_M1 * _LC1 + _M2 * _L1) * _G * el.cos(t1 - _PI / 2) + phi2
    ddt2 = (a + d2 / d1 * phi1 - _M2 * _L1 * _LC2 * (dt1 * dt1) * s2 - phi2) / (_M2 * (_LC2 * _LC2) + _I2 - (d2 * d2) / d1)
    ddt1 = -(d2 * ddt2 + phi1) / d1
    k[0], k[1], k[2], k[3] = dt1, dt2, ddt1, ddt2


@njit(cache=True)
def _wrap(x):
    while x > _PI:
        x = x - (_PI - (-_PI))
    while x < -_PI:
        x = x + (_PI - (-_PI))
    return x


@njit(cache=True)
def _bound(x, m):
    """Python's ``min(max(x, -m), m)`` (a NaN stays NaN)."""
    if -m > x:
        x = -m
    if m < x:
        x = m
    return x


@njit(cache=True)
def acrobot_step(s, torque, k, y):
    """One ``AcrobotEnv.step`` of state ``s`` (4,) in place (rk4, wrap, bound); terminated?

    ``k`` (4, 4) and ``y`` (4,) are scratch space.
    """
    acrobot_dsdt(s[0], s[1], s[2], s[3], torque, k[0])
    for j in range(4):
        y[j] = s[j] + _DT2 * k[0, j]
    acrobot_dsdt(y[0], y[1], y[2], y[3], torque, k[1])
    for j in range(4):
        y[j] = s[j] + _DT2 * k[1, j]
    acrobot_dsdt(y[0], y[1], y[2], y[3], torque, k[2])
    for j in range(4):
        y[j] = s[j] + _DT * k[2, j]
    acrobot_dsdt(y[0], y[1], y[2], y[3], torque, k[3])
    for j in range(4):
        s[j] = s[j] + _DT6 * (k[0, j] + 2 * k[1, j] + 2 * k[2, j] + k[3, j])
    s[0] = _wrap(s[0])
    s[1] = _wrap(s[1])
    s[2] = _bound(s[2], _MAX_VEL_1)
    s[3] = _bound(s[3], _MAX_VEL_2)
    return -el.cos(s[0]) - el.cos(s[1] + s[0]) > 1.0


@njit(cache=True)
def _acrobot_observe(s, x):
    """gymnasium's ``_get_ob`` (float32) into ``x[:6]`` as float64."""
    x[0] = np.float64(np.float32(el.cos(s[0])))
    x[1] = np.float64(np.float32(el.sin(s[0])))
    x[2] = np.float64(np.float32(el.cos(s[1])))
    x[3] = np.float64(np.float32(el.sin(s[1])))
    x[4] = np.float64(np.float32(s[2]))
    x[5] = np.float64(np.float32(s[3]))


@njit(cache=True)
def acrobot_steps(states, actions):
    """Test entry point: one step of each state (n, 4) with its action in {0, 1, 2}:
    (next states, observations (n, 6) float32, terminated)."""
    n = states.shape[0]
    out = states.copy()
    obs = np.empty((n, 6), dtype=np.float32)
    terminated = np.empty(n, dtype=np.bool_)
    k, y, x = np.empty((4, 4)), np.empty(4), np.empty(6)
    for i in range(n):
        terminated[i] = acrobot_step(out[i], _TORQUES[actions[i]], k, y)
        _acrobot_observe(out[i], x)
        for j in range(6):
            obs[i, j] = np.float32(x[j])
    return out, obs, terminated


@njit(cache=True)
def acrobot_first_observations(states32):
    """(n, 6) first observations of float32 initial states ``states32`` (n, 4): gymnasium's ``_get_ob``,
    cos and sin of the angles in float32 as numpy's vector kernel computes them (el.cos32, el.sin32)."""
    obs = np.empty((states32.shape[0], 6))
    for i in range(states32.shape[0]):
        for j in range(2):
            obs[i, 2 * j] = np.float64(el.cos32(states32[i, j]))
            obs[i, 2 * j + 1] = np.float64(el.sin32(states32[i, j]))
        obs[i, 4] = np.float64(states32[i, 2])
        obs[i, 5] = np.float64(states32[i, 3])
    return obs


@njit(cache=True)
def acrobot_episodes(params, states0, obs0, sizes, max_steps, returns, steps, trace):
    """One Acrobot episode per member from initial states ``states0`` (B, 4) (float32 values)
    and first observations ``obs0`` (B, 6): reward -1 per step, 0 on the terminating step.

    The first observation comes from the caller because gymnasium computes it with numpy's
    float32 ``cos``/``sin``, which are not libm's. ``trace`` as in :func:`cartpole_episodes`.
    From :data:`LANES_FROM` members on, :func:`_acrobot_episodes_in_lanes` runs them (the same numbers).
    """
    if params.shape[0] >= LANES_FROM and max_steps > 0:
        _acrobot_episodes_in_lanes(params, states0, obs0, sizes, max_steps, returns, steps, trace)
        return
    width = _buffer_width(params, sizes)
    x, y = np.empty(width), np.empty(width)
    s, k, ys = np.empty(4), np.empty((4, 4)), np.empty(4)
    for i in range(params.shape[0]):
        for j in range(4):
            s[j] = states0[i, j]
        for j in range(6):
            x[j] = obs0[i, j]
        if trace.shape[0] > 0:
            _record(trace, i, 0, s)
        returns[i], steps[i] = _acrobot_run(params[i], sizes, max_steps, s, (0, 0.0), trace, i, (x, y, k, ys))


@njit(cache=True)
def _acrobot_run(p, sizes, max_steps, s, at, trace, i, buffers):
    """Member ``i``'s episode (parameters ``p``) alone, from state ``s`` and the observation in ``buffers[0]`` at ``at`` =
    (step, return) to its end: (return, steps). The whole episode of :func:`acrobot_episodes`, or the rest of one begun
    in a lane (:func:`_acrobot_episodes_in_lanes`). ``buffers``: the MLP's two and the rk4 step's two."""
    x, y, k, ys = buffers
    t, ret = at
    record = trace.shape[0] > 0
    while t < max_steps:
        out = mlp_forward(p, sizes, x, y)
        terminated = acrobot_step(s, _TORQUES[_argmax(out, 3)], k, ys)
        t += 1
        if record:
            _record(trace, i, t, s)
        ret += 0.0 if terminated else -1.0
        if terminated:
            break
        _acrobot_observe(s, x)
    return ret, t


@njit(cache=True)
def _load_acrobot_lane(params, states0, obs0, member, lane, params_t, s, x, trace):
    """Start ``member``'s episode in ``lane``: its parameters, initial state and first observation."""
    for q in range(params.shape[1]):
        params_t[q, lane] = params[member, q]
    for j in range(4):
        s[lane, j] = states0[member, j]
    for j in range(6):
        x[j, lane] = obs0[member, j]
    if trace.shape[0] > 0:
        _record(trace, member, 0, s[lane])


@njit(cache=True)
def _acrobot_episodes_in_lanes(params, states0, obs0, sizes, max_steps, returns, steps, trace):
    """:func:`acrobot_episodes`, :data:`LANES` episodes stepped together, as
    :func:`_cartpole_episodes_in_lanes` does for CartPole: one policy evaluation for all of them
    (:func:`_mlp_lanes`), then each one's rk4 step; a lane whose episode ends takes the next member. One
    episode's step is a chain of dependent operations (the policy's layers, then four derivative evaluations);
    eight independent ones keep the CPU busy. Every member's numbers are those of the one-at-a-time loop, bit for
    bit (tests/test_envs.py)."""
    n = params.shape[0]
    width = _buffer_width(params, sizes)
    params_t = np.zeros((params.shape[1], LANES))
    x, y = np.zeros((width, LANES)), np.zeros((width, LANES))
    s, k, ys = np.zeros((LANES, 4)), np.empty((4, 4)), np.empty(4)
    obs = np.empty(6)
    x1, y1 = np.empty(width), np.empty(width)
    member = np.full(LANES, -1)
    t = np.zeros(LANES, dtype=np.int64)
    ret = np.zeros(LANES)
    record = trace.shape[0] > 0
    started = 0
    for g in range(min(LANES, n)):
        _load_acrobot_lane(params, states0, obs0, started, g, params_t, s, x, trace)
        member[g] = started
        started += 1
    running = started
    while running > 0:
        out = _mlp_lanes(params_t, sizes, x, y)  # idle lanes compute on their last observation, unused
        for g in range(LANES):
            i = member[g]
            if i < 0:
                continue
            terminated = acrobot_step(s[g], _TORQUES[_argmax(out[:, g], 3)], k, ys)
            t[g] += 1
            if record:
                _record(trace, i, t[g], s[g])
            ret[g] += 0.0 if terminated else -1.0
            if terminated or t[g] == max_steps:
                returns[i], steps[i] = ret[g], t[g]
                ret[g], t[g] = 0.0, 0
                if started < n:
                    _load_acrobot_lane(params, states0, obs0, started, g, params_t, s, x, trace)
                    member[g] = started
                    started += 1
                else:
                    member[g] = -1
                    running -= 1
            else:
                _acrobot_observe(s[g], obs)
                for j in range(6):
                    x[j, g] = obs[j]
        if started == n and 0 < running < ALONE_BELOW:  # the last episodes: each finishes alone
            for g in range(LANES):
                i = member[g]
                if i >= 0:
                    for j in range(6):
                        x1[j] = x[j, g]
                    returns[i], steps[i] = _acrobot_run(params[i], sizes, max_steps, s[g], (t[g], ret[g]), trace, i, (x1, y1, k, ys))
            running = 0


@njit(cache=True)
def acrobot_seeded_episodes(params, seeds, sizes, max_steps, returns, steps, trace):
    """One Acrobot episode per member from episode seed ``seeds[i]`` (uint64), as ``reset(seed=s)`` starts it:
    gymnasium's float32 initial state (uniform in [-0.1, 0.1]) and its first observation computed in float32
    (:func:`acrobot_first_observations`), then :func:`acrobot_episodes`. The one copy of that sequence:
    :class:`imix_cli.core.evaluation.AcrobotEvaluator` and the compiled generation loop both run it."""
    s32 = seeded_uniform_rows(seeds, -0.1, 0.1, 4).astype(np.float32)
    obs0 = acrobot_first_observations(s32)
    acrobot_episodes(params, s32.astype(np.float64), obs0, sizes, max_steps, returns, steps, trace)
