"""NaN/inf episode returns (a user's env can produce them) never crash a run: ranked last, counted."""

import gymnasium as gym
import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleEnv

from imix_cli.commands.cli import main
from imix_cli.running.files.results import read_run_csv


class FaultyRewardCartPole(CartPoleEnv):
    """CartPole whose reward is NaN on step 3 when the cart starts right of centre, +inf when it starts left."""

    def reset(self, *, seed=None, options=None):
        obs, info = super().reset(seed=seed, options=options)
        self._fault = np.nan if obs[0] > 0 else np.inf
        self._t = 0
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = super().step(action)
        self._t += 1
        return obs, (self._fault if self._t == 3 else reward), terminated, truncated, info


gym.register("imix_test/FaultyRewardCartPole-v0", entry_point=FaultyRewardCartPole, max_episode_steps=50)


def test_nonfinite_returns_are_counted_not_fatal(tmp_path, capsys):
    env = ["env=gym", "env.id=imix_test/FaultyRewardCartPole-v0"]
    args = [*env, "seeds=1", "generations=4", "popsize=10", "workers=1", "progress=false", f"results_dir={tmp_path}"]
    for algo in ("openes", "snes", "cem", "cmaes"):
        assert main(["run", f"algo={algo}", *args]) == 0
        frame = read_run_csv(tmp_path / "default" / f"{algo}-imix_test_FaultyRewardCartPole-v0-none-popsize=10" / "seed_0.csv")
        # every episode lasts >= 3 steps, so every generation's returns are all non-finite
        assert (frame["nonfinite"] == 10).all()
        # the summary shows the count (4 generations x 10 members) in its non-finite column; its
        # evaluation count is 40 too, so the column is picked by its header, not searched for
        header, line = capsys.readouterr().out.splitlines()[:2]
        column = header.split().index("non-finite") - len(header.split())  # from the right: the run name has no spaces, the score has
        assert int(line.split()[column]) == 40
