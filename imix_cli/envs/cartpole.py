"""Per-member-seeded CartPole episodes, stepped with gymnasium's ``CartPoleVectorEnv`` arithmetic.

The dynamics are gymnasium's ``CartPoleVectorEnv.step`` (Euler steps of ``tau = 0.02`` s, its
constants, read from the class), operation for operation in the same order on the same
``(4, n)`` state layout, so next states and observations are bit-identical to it. What is left
out is bookkeeping that costs more than the physics at the batch sizes the ES uses: the
``action_space.contains`` assertion, step counters and truncation (the caller caps episodes),
and next-step autoreset (a terminated member keeps being integrated; callers mask it). All
temporaries are preallocated per batch size, and ``|x| > a`` replaces ``x < -a or x > a``
(the same truth value for every float, NaN included).

Initial states: ``reset(seeds)`` gives member i ``np.random.default_rng(seed_i).uniform(-0.05,
0.05, 4)`` (computed for all seeds at once by :func:`imix_cli.envs.seeded_uniform`), which is
exactly the state of ``gym.make("CartPole-v1").reset(seed=seed_i)`` (gymnasium seeds a PCG64
generator from the same SeedSequence), so a member's episode depends on its seed only.
"""

from __future__ import annotations

import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv

from imix_cli.envs import seeded_uniform

__all__ = ["CartPoleBatch", "initial_states", "OBS_DIM", "NUM_ACTIONS"]

OBS_DIM = 4
NUM_ACTIONS = 2

_P = CartPoleVectorEnv(num_envs=1)  # gymnasium's constants, used exactly as its step() uses them
assert _P.kinematics_integrator == "euler" and not _P._sutton_barto_reward, "gymnasium's CartPole defaults changed"
_PML, _TOTAL_MASS, _GRAVITY = _P.polemass_length, _P.total_mass, _P.gravity
_LENGTH, _MASSPOLE, _TAU = _P.length, _P.masspole, _P.tau
_FOUR_THIRDS = 4.0 / 3.0
_LIMITS = np.array([[_P.x_threshold], [_P.theta_threshold_radians]])  # |x|, |theta| beyond: terminated
# gymnasium: force = sign(action - 0.5) * force_mag, i.e. -force_mag for 0 and +force_mag for 1
_FORCE = np.sign(np.array([0, 1]) - 0.5) * _P.force_mag
del _P


def initial_states(seeds: np.ndarray) -> np.ndarray:
    """(n, 4) float64 initial states, identical to ``CartPole-v1.reset(seed=s)`` per seed."""
    return seeded_uniform(seeds, -0.05, 0.05, 4)


class CartPoleBatch:
    """n CartPole episodes stepped together (no time limit, no autoreset).

    ``reset(seeds)`` / ``set_state(states)`` start the episodes and return observations
    (n, 4) float32; ``step(actions)`` takes int actions (n,) in {0, 1} and returns
    ``(obs, reward, terminated)`` as ``CartPoleVectorEnv.step`` would for members not awaiting
    an autoreset. The returned arrays are internal buffers (observations a transposed view),
    overwritten by the next ``step``. ``select(rows)`` keeps only the given members (compaction).
    ``max_episode_steps`` is accepted for compatibility and unused: the caller caps episodes.
    """

    def __init__(self, max_episode_steps: int = 200):
        self.max_episode_steps = int(max_episode_steps)
        self._alloc(0)

    def _alloc(self, n: int) -> None:
        self.s = np.empty((4, n))  # x, x_dot, theta, theta_dot
        self._next = np.empty((4, n))
        self._t = np.empty((5, n))  # cos, sin and three scalar-row temporaries
        self._acc = np.empty((2, n))  # xacc, thetaacc: the derivatives of rows 1 and 3
        self._pair = np.empty((2, n))
        self._obs = np.empty((4, n), dtype=np.float32)  # handed out transposed, as (n, 4)
        self._reward = np.ones(n)
        self._beyond = np.empty((2, n), dtype=bool)
        self._terminated = np.empty(n, dtype=bool)

    @property
    def n(self) -> int:
        return self.s.shape[1]

    @property
    def state(self) -> np.ndarray:
        """Current states (n, 4) float64 ``[x, x_dot, theta, theta_dot]`` (a copy)."""
        return self.s.T.copy()

    def set_state(self, states: np.ndarray) -> np.ndarray:
        states = np.asarray(states, dtype=np.float64).reshape(-1, 4)
        self._alloc(states.shape[0])
        self.s[...] = states.T
        np.copyto(self._obs, self.s)  # what reset() returns: state.T.astype(float32)
        return self._obs.T

    def reset(self, seeds: np.ndarray) -> np.ndarray:
        """Start one episode per seed (gymnasium's ``reset(seed=s)`` initial states)."""
        return self.set_state(initial_states(seeds))

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s, new, acc, pair = self.s, self._next, self._acc, self._pair
        theta, theta_dot = s[2], s[3]
        costheta, sintheta, temp, a, b = self._t
        force = _FORCE[actions]
        np.cos(theta, out=costheta)
        np.sin(theta, out=sintheta)
        # temp = (force + polemass_length * theta_dot**2 * sintheta) / total_mass
        np.square(theta_dot, out=a)
        np.multiply(a, _PML, out=a)
        np.multiply(a, sintheta, out=a)
        np.add(force, a, out=temp)
        np.divide(temp, _TOTAL_MASS, out=temp)
        # thetaacc = (gravity * sintheta - costheta * temp) / (length * (4/3 - masspole * costheta**2 / total_mass))
        np.multiply(sintheta, _GRAVITY, out=a)
        np.multiply(costheta, temp, out=b)
        np.subtract(a, b, out=a)
        np.square(costheta, out=b)
        np.multiply(b, _MASSPOLE, out=b)
        np.divide(b, _TOTAL_MASS, out=b)
        np.subtract(_FOUR_THIRDS, b, out=b)
        np.multiply(b, _LENGTH, out=b)
        np.divide(a, b, out=acc[1])
        # xacc = temp - polemass_length * thetaacc * costheta / total_mass
        np.multiply(acc[1], _PML, out=a)
        np.multiply(a, costheta, out=a)
        np.divide(a, _TOTAL_MASS, out=a)
        np.subtract(temp, a, out=acc[0])
        # Euler, two rows per call: (x, theta) += tau * (x_dot, theta_dot), then
        # (x_dot, theta_dot) += tau * (xacc, thetaacc), each from the old state
        np.multiply(s[1::2], _TAU, out=pair)
        np.add(s[0::2], pair, out=new[0::2])
        np.multiply(acc, _TAU, out=pair)
        np.add(s[1::2], pair, out=new[1::2])
        self._next, self.s = s, new
        # terminated = x < -x_max | x > x_max | theta < -theta_max | theta > theta_max
        np.abs(new[0::2], out=pair)
        np.greater(pair, _LIMITS, out=self._beyond)
        terminated = np.logical_or(self._beyond[0], self._beyond[1], out=self._terminated)
        np.copyto(self._obs, new)  # gymnasium: state.T.astype(float32)
        return self._obs.T, self._reward, terminated

    def select(self, rows: np.ndarray) -> None:
        """Continue only the members at ``rows``."""
        self.set_state(self.s[:, rows].T)
