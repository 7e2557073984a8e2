"""Where does imix's ARS part from sb3-contrib's on Swimmer? The checks behind docs/ars.md's study.

imix's ARS and sb3-contrib's are the same method with the same policy, yet sb3-contrib reaches the
ARS paper's threshold on more Swimmer seeds. Each check runs one half of the pipeline both ways:

* ``hybrid``: sb3-contrib's own ``ARS`` class (its update, its float32 weights, its RNG), with its
  candidates' episodes and the mean policy's measurements made by imix's evaluator -- 300
  iterations (600 episodes) per seed; prints each seed's return after 100 and 600 episodes and
  the episodes to 325;
* ``policy``: the returns of a few fixed random policies over 12 episodes, imix's evaluator against
  sb3-contrib's ``evaluate_policy`` on a ``DummyVecEnv``;
* ``pairs``: the spread of a mirrored pair's r+ - r- over 15 repeats in both loops, at theta = 0
  and at a given trained policy (common random numbers would shrink it).

    python benchmarks/ars_sb3_gap.py hybrid [first_seed last_seed]
    python benchmarks/ars_sb3_gap.py policy
    python benchmarks/ars_sb3_gap.py pairs [policy_<k>_mean.npz]

Needs the ars and mujoco extras (sb3-contrib, torch, mujoco).
"""

from __future__ import annotations

import sys

import numpy as np

SWIMMER, OBS, ACT, THRESHOLD = "Swimmer-v5", 8, 2, 325.0


def _imix_evaluator():
    from imix_cli.evaluation import make_evaluator

    return make_evaluator(SWIMMER, None, hidden=(), output="clip")


def _as_imix(weights) -> np.ndarray:
    """sb3-contrib's LinearPolicy weights (nn.Linear(8, 2).weight, (2, 8), flattened) as imix parameters."""
    from imix_cli.policies import with_zero_biases

    w = np.asarray(weights, dtype=np.float64).reshape(-1, ACT, OBS).transpose(0, 2, 1).reshape(-1, OBS * ACT)
    return with_zero_biases(w, OBS, ACT, ())


def _as_sb3(weights: np.ndarray) -> np.ndarray:
    """imix's bias-free weights W (8 x 2, row-major) as sb3-contrib's flattened (2, 8) weight."""
    return np.asarray(weights, dtype=np.float64).reshape(OBS, ACT).T.reshape(-1).astype(np.float32)


def _sb3_model(seed: int = 0, cls=None):
    import gymnasium as gym
    import torch
    from sb3_contrib import ARS
    from stable_baselines3.common.vec_env import DummyVecEnv

    torch.set_num_threads(1)
    return (cls or ARS)("LinearPolicy", DummyVecEnv([lambda: gym.make(SWIMMER)]), seed=seed, n_delta=1, n_top=1, learning_rate=0.02, delta_std=0.01)


def hybrid(first: int = 0, last: int = 10) -> None:
    import torch
    from sb3_contrib import ARS

    evaluator = _imix_evaluator()

    class OnImixEpisodes(ARS):
        def evaluate_candidates(self, candidate_weights, callback, async_eval):
            returns, steps = evaluator.evaluate(_as_imix(candidate_weights.cpu().numpy()), self.episode_rng.integers(0, 2**62, size=self.pop_size))
            self.num_timesteps += int(steps.sum())
            return torch.as_tensor(returns, dtype=torch.float32)

    reached_seeds, at_100 = 0, []
    for seed in range(first, last):
        model = _sb3_model(seed, OnImixEpisodes)
        model.episode_rng = np.random.default_rng(seed)
        reached, scores = None, []
        for iteration in range(1, 301):
            model.learn(total_timesteps=1, reset_num_timesteps=False)
            if iteration % 10 == 0:
                params = np.repeat(_as_imix(model.weights.numpy()), 3, axis=0)
                scores.append(float(evaluator.evaluate(params, model.episode_rng.integers(0, 2**62, size=3))[0].mean()))
                reached = reached or (2 * iteration if scores[-1] >= THRESHOLD else None)
        reached_seeds += reached is not None
        at_100.append(scores[4])
        print(f"seed {seed}: {scores[4]:.0f} after 100 episodes, {scores[-1]:.0f} after 600, episodes to {THRESHOLD:.0f}: {reached}", flush=True)
    print(f"reached {reached_seeds}/{last - first}; median after 100 episodes {np.median(at_100):.1f}")


def policy() -> None:
    from stable_baselines3.common.evaluation import evaluate_policy

    evaluator, model, rng = _imix_evaluator(), _sb3_model(), np.random.default_rng(5)
    for k in range(3):
        weights = 0.3 * rng.normal(size=OBS * ACT)
        ours = evaluator.evaluate(np.repeat(_as_imix(_as_sb3(weights).astype(np.float64)), 12, axis=0), rng.integers(0, 2**62, size=12))[0]
        model.policy.load_from_vector(_as_sb3(weights))
        theirs, _ = evaluate_policy(model.policy, model.env, n_eval_episodes=12, return_episode_rewards=True, warn=False)
        print(f"policy {k}: imix {ours.mean():.1f} ± {ours.std():.1f}, sb3-contrib {np.mean(theirs):.1f} ± {np.std(theirs):.1f}")


def pairs(trained: str | None = None) -> None:
    from stable_baselines3.common.evaluation import evaluate_policy

    from imix_cli.running.policy_files import read_policy

    evaluator, model, rng = _imix_evaluator(), _sb3_model(), np.random.default_rng(3)
    points = [("theta = 0", np.zeros(OBS * ACT))] + ([("trained", read_policy(trained).params[: OBS * ACT])] if trained else [])
    for name, mean in points:
        delta = rng.standard_normal(OBS * ACT)
        plus, minus = mean + 0.01 * delta, mean - 0.01 * delta
        ours, theirs = [], []
        for _ in range(15):
            r = evaluator.evaluate(np.concatenate([_as_imix(_as_sb3(plus)), _as_imix(_as_sb3(minus))]), rng.integers(0, 2**62, size=2))[0]
            ours.append(r[0] - r[1])
            pair = []
            for w in (plus, minus):
                model.policy.load_from_vector(_as_sb3(w))
                pair.append(evaluate_policy(model.policy, model.env, n_eval_episodes=1, return_episode_rewards=True, warn=False)[0][0])
            theirs.append(pair[0] - pair[1])
        print(f"{name}: r+ - r- imix mean {np.mean(ours):.2f} sd {np.std(ours):.2f}; sb3-contrib mean {np.mean(theirs):.2f} sd {np.std(theirs):.2f}")


if __name__ == "__main__":
    what, args = (sys.argv[1] if len(sys.argv) > 1 else "policy"), sys.argv[2:]
    {"hybrid": lambda: hybrid(*map(int, args)), "policy": policy, "pairs": lambda: pairs(*args)}[what]()
