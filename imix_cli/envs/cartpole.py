"""Per-member-seeded CartPole episodes on gymnasium's own ``CartPoleVectorEnv``.

The dynamics are gymnasium's: each step is one ``CartPoleVectorEnv.step`` call. This module
only fixes two things that would otherwise make a member's episode depend on its batch:

* initial states: ``CartPoleVectorEnv.reset`` draws all n states from one generator
  (shape ``(4, n)``), so they depend on n and on the member's position. :meth:`CartPoleBatch.reset`
  overwrites ``env.state`` after the reset with ``np.random.default_rng(seed_i).uniform(-0.05,
  0.05, 4)`` (computed for all seeds at once by :func:`imix_cli.envs.seeded_uniform`), which is
  exactly the state of ``gym.make("CartPole-v1").reset(seed=seed_i)`` (gymnasium seeds a
  PCG64 generator from the same SeedSequence);
* next-step autoreset: a member that terminated is re-drawn from the env's generator on the
  following step; callers mask finished members and ignore their later data.

Compaction: ``select(rows)`` moves the given members into a (cached) ``CartPoleVectorEnv``
with exactly ``len(rows)`` sub-environments (reset, then its state overwritten). The vector
env's step counters restart there, so its own truncation (``max_episode_steps``) can only
come later than the caller's step cap, which is the one that counts.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv

from imix_cli.envs import seeded_uniform

__all__ = ["CartPoleBatch", "initial_states", "OBS_DIM", "NUM_ACTIONS"]

OBS_DIM = 4
NUM_ACTIONS = 2


def initial_states(seeds: np.ndarray) -> np.ndarray:
    """(n, 4) float64 initial states, identical to ``CartPole-v1.reset(seed=s)`` per seed."""
    return seeded_uniform(seeds, -0.05, 0.05, 4)


class CartPoleBatch:
    """n CartPole episodes on a gymnasium ``CartPoleVectorEnv`` of exactly n sub-envs.

    ``reset(seeds)`` / ``set_state(states)`` start the episodes and return observations
    (n, 4) float32; ``step(actions)`` takes int actions (n,) in {0, 1} and returns
    ``(obs, reward, terminated)`` straight from ``CartPoleVectorEnv.step``. ``select(rows)``
    keeps only the given members. Vector envs are cached per size (LRU, ``cache_size``).
    """

    def __init__(self, max_episode_steps: int = 200, cache_size: int = 32):
        self.max_episode_steps = int(max_episode_steps)
        self.cache_size = int(cache_size)
        self._envs: OrderedDict[int, CartPoleVectorEnv] = OrderedDict()
        self.env: CartPoleVectorEnv | None = None

    def _get_env(self, n: int) -> CartPoleVectorEnv:
        env = self._envs.pop(n, None)
        if env is None:
            env = CartPoleVectorEnv(num_envs=n, max_episode_steps=self.max_episode_steps)
            env.reset(seed=0)  # seeds the (irrelevant) autoreset generator once, deterministically
        self._envs[n] = env
        while len(self._envs) > self.cache_size:
            self._envs.popitem(last=False)
        return env

    @property
    def n(self) -> int:
        return 0 if self.env is None else self.env.num_envs

    @property
    def state(self) -> np.ndarray:
        """Current states (n, 4) float64 ``[x, x_dot, theta, theta_dot]`` (a copy)."""
        return self.env.state.T.copy()

    def set_state(self, states: np.ndarray) -> np.ndarray:
        states = np.asarray(states, dtype=np.float64).reshape(-1, 4)
        env = self._get_env(states.shape[0])
        env.reset()  # clears step counters and pending autoresets
        env.state[...] = states.T
        self.env = env
        return env.state.T.astype(np.float32)  # what reset() would have returned

    def reset(self, seeds: np.ndarray) -> np.ndarray:
        """Start one episode per seed (gymnasium's ``reset(seed=s)`` initial states)."""
        return self.set_state(initial_states(seeds))

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        obs, reward, terminated, _truncated, _ = self.env.step(actions)
        return obs, reward, terminated

    def select(self, rows: np.ndarray) -> None:
        """Continue only the members at ``rows`` (none of which may be awaiting an autoreset)."""
        self.set_state(self.env.state[:, rows].T)
