"""Your own environment for imix: a module whose import registers a gymnasium id.

imix runs it as ``env=gym env.id=myenvs:Reach1D-v0`` with this folder on the import path (the README:
``PYTHONPATH=examples imix run ...``). ``imix eval`` and ``imix render`` import it only when you name it
again (``import=myenvs``): a run folder's files never make imix import a module.

Reach1D: a point on a line starts in [-1, 1] and steps 0.1 left or right; each step costs its distance
to x = 1, and reaching it ends the episode (at most 30 steps). A tiny task that an ES learns in a few
dozen generations.
"""

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class Reach1D(gym.Env):
    """Walk left or right to reach x = 1 (discrete actions: 0 left, 1 right)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode=None):
        self.render_mode = render_mode
        self.observation_space = spaces.Box(-10.0, 10.0, (1,), dtype=np.float32)
        self.action_space = spaces.Discrete(2)
        self.x = 0.0

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.x = float(self.np_random.uniform(-1, 1))
        return np.array([self.x], dtype=np.float32), {}

    def step(self, action):
        self.x += 0.1 if action == 1 else -0.1
        distance = abs(self.x - 1.0)
        return np.array([self.x], dtype=np.float32), -distance, distance < 0.05, False, {}

    def render(self):
        """A 32 x 64 strip: the target column grey, the point white."""
        frame = np.zeros((32, 64, 3), dtype=np.uint8)
        frame[:, int(np.clip((1.0 + 2) * 16, 0, 63))] = 96
        frame[:, int(np.clip((self.x + 2) * 16, 0, 63))] = 255
        return frame


gym.register("Reach1D-v0", entry_point=Reach1D, max_episode_steps=30)
