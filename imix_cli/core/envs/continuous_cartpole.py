"""ContinuousCartPole and ContinuousCartPoleHard (paper section 4.3), registered and batched.

Dynamics: gymnasium's ``CartPoleEnv`` exactly (Euler steps of 0.02 s, same constants, same
expressions in the same order, termination at |x| > 2.4 or |theta| > 12 degrees), with one
change: the action is a Box ``[-1, 1]`` of shape ``(1,)`` and the force on the cart is

    force = FORCE_MAG * a,   FORCE_MAG = 10 N (CartPoleEnv.force_mag)

so ``a = +1`` / ``a = -1`` are exactly discrete CartPole's two pushes (gymnasium applies
+-``force_mag`` = +-10 N; the paper's "forces of -1 and +1 unit" are these pushes in units of
``force_mag``) and ``|a| < 1`` is a weaker push, as the paper's "continuous-valued force in
[-1, 1]". With a = +-1 a trajectory is bit-identical to ``CartPole-v1``'s (tests check it).
Actions are clipped to [-1, 1]; a NaN action pushes with force 0 (a broken policy must not
freeze the physics into a never-ending, full-reward episode).

Episodes: 200 steps (``TimeLimit``, registered ``max_episode_steps=200``), reward threshold 195,
initial state ``uniform(-0.05, 0.05, 4)`` from ``reset(seed=...)`` as CartPole.

* ``imix/ContinuousCartPole-v0`` (:class:`ContinuousCartPoleEnv`): reward 1 per step, the
  terminating step included (CartPole's dense reward), so the return is the episode length.
* ``imix/ContinuousCartPoleHard-v0``: the same env with :class:`SparseEpisodeReward` applied
  *outside* the ``TimeLimit`` (``EnvSpec.additional_wrappers``): reward 0 on every step but the
  episode's last (terminated or truncated), which carries the episode's total dense reward.
  Over any episode the sparse sum equals the dense return. Being outside the time limit, the
  wrapper sees whatever step ends the episode, including with ``gym.make(id, max_episode_steps=N)``.

The ES does not step these registered envs: ``imix_cli.core.evaluation`` runs whole episodes in
the compiled kernel :func:`imix_cli.core.envs.kernels.cartpole_episodes` (same force mapping, the
Hard variant's sparse reward paid on termination or at the step cap);
``tests/test_continuous.py`` checks its episodes against these registered envs.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import logger, spaces
from gymnasium.envs.classic_control.cartpole import CartPoleEnv

__all__ = [
    "FORCE_MAG",
    "OBS_DIM",
    "ACTION_DIM",
    "ContinuousCartPoleEnv",
    "SparseEpisodeReward",
    "cartpole_dynamics",
]

OBS_DIM = 4
ACTION_DIM = 1
FORCE_MAG = 10.0  # newtons per unit of action: CartPoleEnv.force_mag


def cartpole_dynamics(p, state: np.ndarray, force):
    """One Euler step of ``CartPoleEnv``'s dynamics: ``(new state, terminated)``.

    ``p`` holds the physical constants (a ``CartPoleEnv``), ``state`` is ``(4,)`` or ``(4, n)``
    float64 ``[x, x_dot, theta, theta_dot]`` and ``force`` a scalar or ``(n,)``. The expressions
    are gymnasium's, operation for operation.
    """
    x, x_dot, theta, theta_dot = state
    costheta = np.cos(theta)
    sintheta = np.sin(theta)
    temp = (force + p.polemass_length * np.square(theta_dot) * sintheta) / p.total_mass
    thetaacc = (p.gravity * sintheta - costheta * temp) / (p.length * (4.0 / 3.0 - p.masspole * np.square(costheta) / p.total_mass))
    xacc = temp - p.polemass_length * thetaacc * costheta / p.total_mass
    x = x + p.tau * x_dot
    x_dot = x_dot + p.tau * xacc
    theta = theta + p.tau * theta_dot
    theta_dot = theta_dot + p.tau * thetaacc
    new_state = np.stack((x, x_dot, theta, theta_dot)).astype(np.float64, copy=False)
    terminated = (x < -p.x_threshold) | (x > p.x_threshold) | (theta < -p.theta_threshold_radians) | (theta > p.theta_threshold_radians)
    return new_state, terminated


def action_to_force(action) -> np.ndarray:
    """``FORCE_MAG * clip(a, -1, 1)`` (float64), NaN actions giving force 0."""
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    return FORCE_MAG * np.where(np.isnan(a), 0.0, a)


class ContinuousCartPoleEnv(CartPoleEnv):
    """CartPole with a continuous force ``10 N * a``, ``a`` in ``[-1, 1]`` (module docstring).

    Rendering, reset and the observation space are ``CartPoleEnv``'s.
    """

    def __init__(self, render_mode: str | None = None):
        super().__init__(render_mode=render_mode)
        assert self.force_mag == FORCE_MAG and self.kinematics_integrator == "euler"
        self.action_space = spaces.Box(-1.0, 1.0, shape=(ACTION_DIM,), dtype=np.float32)

    def step(self, action):
        assert self.state is not None, "Call reset before using step method."
        force = action_to_force(np.asarray(action).reshape(-1)[0])
        state, terminated = cartpole_dynamics(self, np.asarray(self.state, dtype=np.float64), force)
        self.state = state
        terminated = bool(terminated)
        if not terminated:
            reward = 1.0
        elif self.steps_beyond_terminated is None:
            self.steps_beyond_terminated = 0
            reward = 1.0
        else:
            if self.steps_beyond_terminated == 0:
                logger.warn(
                    "You are calling 'step()' even though this environment has already returned terminated = True. "
                    "You should always call 'reset()' once you receive 'terminated = True' -- any further steps are undefined behavior."
                )
            self.steps_beyond_terminated += 1
            reward = 0.0
        if self.render_mode == "human":
            self.render()
        return np.array(self.state, dtype=np.float32), reward, terminated, False, {}


class SparseEpisodeReward(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Reward 0 on every step but the episode's last, which carries the episode's total reward.

    Apply it outside the ``TimeLimit`` so truncation counts as the last step. ``info["dense_reward"]``
    keeps the wrapped env's reward of each step.
    """

    def __init__(self, env: gym.Env):
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self._total = 0.0

    def reset(self, **kwargs):
        self._total = 0.0
        return self.env.reset(**kwargs)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._total += float(reward)
        info = dict(info)
        info["dense_reward"] = reward
        return obs, (self._total if terminated or truncated else 0.0), terminated, truncated, info
