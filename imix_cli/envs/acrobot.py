"""Batched Acrobot: gymnasium's Acrobot-v1 dynamics for n systems stepped at once in numpy.

Exactly the dynamics of ``gymnasium.envs.classic_control.acrobot.AcrobotEnv`` with its
defaults: ``book_or_nips="book"``, ``rk4`` over ``[0, dt]`` with ``dt = 0.2``, angles
wrapped into ``[-pi, pi]``, angular velocities clipped to ``+-4 pi`` / ``+-9 pi``, no
torque noise, termination when ``-cos(t1) - cos(t2 + t1) > 1``, reward ``-1`` per step and
``0`` on the terminating step (as gymnasium). There is no time limit here: the caller
caps the episode length. Each arithmetic operation of ``AcrobotEnv._dsdt`` / ``rk4`` is
applied in the same order (only exact rewrites: multiplications by 1.0 dropped, operands
of ``+``/``*`` swapped), with one deliberate exception: gymnasium squares numpy *scalars*
(``dtheta**2``, ``d2**2``), which calls libm ``pow`` and is not always correctly rounded,
while the default here uses ``x * x`` (correctly rounded, 30x faster than a vectorised
``pow``). The two differ by one ulp for ~0.1% of inputs, so next states differ by a few
ulps (< 1e-14) on ~1 step in 400 and are otherwise bit-identical; with
``AcrobotBatch(exact=True)`` they are bit-identical always. ``tests/test_envs.py`` checks
both over thousands of random steps and whole episodes.

State layout is "structure of arrays": ``(4, n)`` float64 rows ``theta1, theta2,
dtheta1, dtheta2``. Observations are ``(n, 6)`` float32 ``[cos t1, sin t1, cos t2,
sin t2, dt1, dt2]``, rounded exactly as gymnasium's ``_get_ob``.

Episode seeds: :meth:`AcrobotBatch.reset` draws member i's initial state as
``np.random.default_rng(seed_i).uniform(-0.1, 0.1, 4).astype(np.float32)`` (computed for
all seeds at once by :func:`imix_cli.envs.seeded_uniform`), which is
exactly the state of ``gym.make("Acrobot-v1").reset(seed=seed_i)`` (gymnasium seeds a
PCG64 generator from the same SeedSequence), so a member's episode depends on its seed only.
"""

from __future__ import annotations

import numpy as np
from gymnasium.envs.classic_control.acrobot import AcrobotEnv

from imix_cli.envs import seeded_uniform

__all__ = ["AcrobotBatch", "dsdt", "rk4_step", "initial_states", "OBS_DIM", "NUM_ACTIONS"]

OBS_DIM = 6
NUM_ACTIONS = 3

_E = AcrobotEnv
# The folded expressions below rely on gymnasium's default constants; fail loudly if they change.
assert (_E.LINK_LENGTH_1, _E.LINK_MASS_1, _E.LINK_MASS_2, _E.LINK_COM_POS_1, _E.LINK_COM_POS_2, _E.LINK_MOI) == (
    1.0, 1.0, 1.0, 0.5, 0.5, 1.0,
), "gymnasium's Acrobot constants changed"
assert _E.dt == 0.2 and _E.torque_noise_max == 0.0 and _E.book_or_nips == "book"

_m1, _m2 = _E.LINK_MASS_1, _E.LINK_MASS_2
_l1, _lc1, _lc2 = _E.LINK_LENGTH_1, _E.LINK_COM_POS_1, _E.LINK_COM_POS_2
_I1 = _I2 = _E.LINK_MOI
_g = 9.8
_PI = np.pi
_HALF_PI = np.pi / 2.0  # gymnasium writes both pi / 2.0 and pi / 2: the same double

# Scalar prefixes that Python folds before touching arrays in gymnasium's expressions.
_D1_C0 = _m1 * _lc1**2  # d1 = m1*lc1**2 + m2*(l1**2 + lc2**2 + 2*l1*lc2*cos t2) + I1 + I2
_D1_C1 = _l1**2 + _lc2**2  # (m2 == 1.0 and 2*l1*lc2 == 1.0: those products are exact no-ops)
_D2_C0 = _lc2**2  # d2 = m2*(lc2**2 + l1*lc2*cos t2) + I2
_D2_C1 = _l1 * _lc2
_PHI2_C = _m2 * _lc2 * _g  # phi2 = m2*lc2*g*cos(t1 + t2 - pi/2)
_PHI1_A = -_m2 * _l1 * _lc2  # phi1 = -m2*l1*lc2*dt2**2*sin t2 - 2*m2*l1*lc2*dt2*dt1*sin t2
_PHI1_C = (_m1 * _lc1 + _m2 * _l1) * _g  # + (m1*lc1 + m2*l1)*g*cos(t1 - pi/2) + phi2
_DD2_A = _m2 * _l1 * _lc2  # book: (a + d2/d1*phi1 - m2*l1*lc2*dt1**2*sin t2 - phi2)
_DD2_DEN = _m2 * _lc2**2 + _I2  # / (m2*lc2**2 + I2 - d2**2/d1)
assert 2 * _m2 * _l1 * _lc2 == 1.0 and 2 * _l1 * _lc2 == 1.0 and _m2 == 1.0

_DT = _E.dt
_DT2 = (_DT - 0) / 2.0  # rk4 with t = [0, dt]
_DT6 = (_DT - 0) / 6.0
_TWO_PI = _PI - (-_PI)  # wrap(): diff = M - m
_MAX_VEL = np.array([[_E.MAX_VEL_1], [_E.MAX_VEL_2]])
_TORQUES = np.array(_E.AVAIL_TORQUE, dtype=np.float64)


def initial_states(seeds: np.ndarray) -> np.ndarray:
    """(n, 4) float32 initial states, identical to ``Acrobot-v1.reset(seed=s)`` per seed."""
    return seeded_uniform(seeds, -0.1, 0.1, 4).astype(np.float32)


def _pow2(x: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``x ** 2`` rounded as gymnasium's scalar ``np.float64 ** 2`` (libm ``pow``), ~30x slower."""
    return np.float_power(x, 2.0, out=out)


def _mul2(x: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``x * x``: correctly rounded; differs from libm ``pow(x, 2)`` by 1 ulp for ~0.1% of x."""
    return np.multiply(x, x, out=out)


class _Work:
    """Preallocated temporaries for n systems."""

    def __init__(self, n: int, exact: bool = False):
        self.n = n
        self.exact = exact
        self.square = _pow2 if exact else _mul2
        self.k = np.empty((4, 4, n))  # k1..k4, rows d(t1), d(t2), d(dt1), d(dt2)
        self.y = np.empty((4, n))  # intermediate rk4 state
        self.trig = np.empty((3, n))  # cos t2 | cos(t1 + t2 - pi/2) | cos(t1 - pi/2)
        self.t = np.empty((8, n))  # scalar-row temporaries
        self.obs = np.empty((OBS_DIM, n), dtype=np.float32)  # handed out transposed, as (n, 6)
        self.ob_trig = np.empty((3, n))  # cos t1, cos t2, cos(t2 + t1)
        self.mask = np.empty((2, n), dtype=bool)


def _derivs(s: np.ndarray, torque: np.ndarray, out: np.ndarray, w: _Work) -> None:
    """Write ``AcrobotEnv._dsdt`` (first 4 components) of states ``s`` (4, n) into ``out`` (4, n)."""
    th1, th2, dth1, dth2 = s
    trig, t = w.trig, w.t
    c2, phi2, c1m = trig
    d1, d2, s2, a_, b_, num, den, tmp = t
    np.add(th1, th2, out=phi2)
    np.subtract(phi2, _HALF_PI, out=phi2)
    np.subtract(th1, _HALF_PI, out=c1m)
    np.copyto(c2, th2)
    np.cos(trig, out=trig)  # cos t2, cos(t1 + t2 - pi/2), cos(t1 - pi/2)
    np.sin(th2, out=s2)
    # d1 = ((m1*lc1**2 + (l1**2 + lc2**2 + c2)) + I1) + I2
    np.add(c2, _D1_C1, out=d1)
    np.add(d1, _D1_C0, out=d1)
    np.add(d1, _I1, out=d1)
    np.add(d1, _I2, out=d1)
    # d2 = (lc2**2 + l1*lc2*c2) + I2
    np.multiply(c2, _D2_C1, out=d2)
    np.add(d2, _D2_C0, out=d2)
    np.add(d2, _I2, out=d2)
    # phi2 = m2*lc2*g * cos(t1 + t2 - pi/2)
    np.multiply(phi2, _PHI2_C, out=phi2)
    # phi1 = ((A - B) + C) + phi2, A = (-m2*l1*lc2 * dt2**2) * s2, B = (dt2*dt1)*s2, C = (..)*g*cos(t1 - pi/2)
    sq = w.square
    sq(dth2, out=a_)
    np.multiply(a_, _PHI1_A, out=a_)
    np.multiply(a_, s2, out=a_)
    np.multiply(dth2, dth1, out=b_)
    np.multiply(b_, s2, out=b_)
    np.subtract(a_, b_, out=a_)
    np.multiply(c1m, _PHI1_C, out=c1m)
    np.add(a_, c1m, out=a_)
    phi1 = np.add(a_, phi2, out=a_)
    # ddtheta2 = (((a + (d2/d1)*phi1) - (m2*l1*lc2*dt1**2)*s2) - phi2) / ((m2*lc2**2 + I2) - d2**2/d1)
    np.divide(d2, d1, out=num)
    np.multiply(num, phi1, out=num)
    np.add(torque, num, out=num)
    sq(dth1, out=tmp)
    np.multiply(tmp, _DD2_A, out=tmp)
    np.multiply(tmp, s2, out=tmp)
    np.subtract(num, tmp, out=num)
    np.subtract(num, phi2, out=num)
    sq(d2, out=den)
    np.divide(den, d1, out=den)
    np.subtract(_DD2_DEN, den, out=den)
    dd2 = np.divide(num, den, out=out[3])
    # ddtheta1 = -(d2*ddtheta2 + phi1) / d1
    np.multiply(d2, dd2, out=tmp)
    np.add(tmp, phi1, out=tmp)
    np.negative(tmp, out=tmp)
    np.divide(tmp, d1, out=out[2])
    out[0] = dth1
    out[1] = dth2


def rk4_step(
    s: np.ndarray, torque: np.ndarray, out: np.ndarray | None = None, w: _Work | None = None, exact: bool = False
) -> np.ndarray:
    """One ``rk4(_dsdt, [s, torque], [0, dt])`` step for states ``s`` (4, n) -> (4, n) (no wrap/clip)."""
    n = s.shape[1]
    w = w if w is not None and w.n == n else _Work(n, exact)
    out = np.empty((4, n)) if out is None else out
    k, y = w.k, w.y
    _derivs(s, torque, k[0], w)
    np.multiply(k[0], _DT2, out=y)
    np.add(s, y, out=y)
    _derivs(y, torque, k[1], w)
    np.multiply(k[1], _DT2, out=y)
    np.add(s, y, out=y)
    _derivs(y, torque, k[2], w)
    np.multiply(k[2], _DT, out=y)
    np.add(s, y, out=y)
    _derivs(y, torque, k[3], w)
    # y0 + dt/6 * (((k1 + 2*k2) + 2*k3) + k4)
    np.multiply(k[1], 2, out=y)
    np.add(k[0], y, out=y)
    np.multiply(k[2], 2, out=k[0])
    np.add(y, k[0], out=y)
    np.add(y, k[3], out=y)
    np.multiply(y, _DT6, out=y)
    np.add(s, y, out=out)
    return out


def _wrap_and_bound(s: np.ndarray, mask: np.ndarray) -> None:
    """In place: ``wrap`` the angles into [-pi, pi] (gymnasium's repeated +-2 pi), clip velocities."""
    ang = s[:2]
    while np.greater(ang, _PI, out=mask).any():
        np.subtract(ang, _TWO_PI, out=ang, where=mask)
    while np.less(ang, -_PI, out=mask).any():
        np.add(ang, _TWO_PI, out=ang, where=mask)
    np.clip(s[2:], -_MAX_VEL, _MAX_VEL, out=s[2:])


def dsdt(s_augmented: np.ndarray, exact: bool = False) -> np.ndarray:
    """Vectorised ``AcrobotEnv._dsdt``: (5, n) ``[t1, t2, dt1, dt2, torque]`` -> (5, n) derivatives."""
    s_augmented = np.asarray(s_augmented, dtype=np.float64)
    n = s_augmented.shape[1]
    out = np.zeros((5, n))
    _derivs(s_augmented[:4], s_augmented[4], out[:4], _Work(n, exact))
    return out


class AcrobotBatch:
    """n Acrobot-v1 systems stepped together (no time limit, no autoreset).

    ``reset(seeds)`` / ``set_state(states)`` start n episodes and return observations
    (n, 6) float32; ``step(actions)`` takes int actions (n,) in {0, 1, 2} and returns
    ``(obs, reward, terminated)``. Terminated systems keep being integrated (callers mask
    them). ``select(rows)`` keeps only the given systems (compaction).

    ``exact=True`` rounds the three squares of ``_dsdt`` with libm ``pow`` like gymnasium's
    scalar ``x**2`` instead of ``x * x``: next states then equal gymnasium's bit for bit
    (so whole chaotic episodes match), about 25% slower. The default differs by
    at most a few ulps on ~1 step in 400 (see the module docstring).
    """

    def __init__(self, exact: bool = False):
        self.exact = bool(exact)
        self.s = np.empty((4, 0))
        self._w = _Work(0, self.exact)
        self._next = self.s

    @property
    def n(self) -> int:
        return self.s.shape[1]

    @property
    def state(self) -> np.ndarray:
        """Current states, (n, 4) float64 ``[theta1, theta2, dtheta1, dtheta2]`` (a copy)."""
        return self.s.T.copy()

    def _alloc(self, n: int) -> None:
        self.s = np.empty((4, n))
        self._next = np.empty((4, n))
        self._w = _Work(n, self.exact)

    def reset(self, seeds: np.ndarray) -> np.ndarray:
        """Start one episode per seed (gymnasium's ``reset(seed=s)`` initial states)."""
        s32 = initial_states(seeds)
        self._alloc(len(s32))
        self.s[...] = s32.T
        # gymnasium's first observation is computed from the float32 state, in float32
        c, sn = np.cos(s32[:, :2].T), np.sin(s32[:, :2].T)
        ob = self._w.obs
        ob[0], ob[1], ob[2], ob[3] = c[0], sn[0], c[1], sn[1]
        ob[4:] = s32[:, 2:].T
        return ob.T

    def set_state(self, states: np.ndarray) -> np.ndarray:
        """Start from given states (n, 4) (float64 math from here on, as after a gymnasium step)."""
        states = np.asarray(states, dtype=np.float64)
        self._alloc(states.shape[0])
        self.s[...] = states.T
        return self._observe()

    def _observe(self) -> np.ndarray:
        """Observations (n, 6) float32: a transposed view of an internal buffer (overwritten by ``step``)."""
        s, w = self.s, self._w
        ob, trig = w.obs, w.ob_trig
        np.copyto(trig[:2], s[:2])
        np.add(s[1], s[0], out=trig[2])
        np.cos(trig, out=trig)
        ob[0] = trig[0]
        ob[2] = trig[1]
        np.sin(s[0], out=ob[1])
        np.sin(s[1], out=ob[3])
        ob[4:] = s[2:]
        return ob.T

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        torque = _TORQUES[actions]
        ns = rk4_step(self.s, torque, out=self._next, w=self._w)
        _wrap_and_bound(ns, self._w.mask)
        self._next, self.s = self.s, ns
        obs = self._observe()
        trig = self._w.ob_trig  # cos t1, cos t2, cos(t2 + t1) of the new state
        terminated = np.negative(trig[0]) - trig[2] > 1.0
        reward = terminated - 1.0  # -1, or 0 on the terminating step
        return obs, reward, terminated

    def select(self, rows: np.ndarray) -> None:
        s = self.s[:, rows]
        self._alloc(s.shape[1])
        self.s[...] = s
