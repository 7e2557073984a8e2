"""sb3-contrib's ARS as imix's peer on MuJoCo: rl-zoo3's hyper-parameters, the same episode budget, CSVs imix can plot.

Why this peer: sb3-contrib's ``ARS`` with rl-zoo3's tuned settings is what researchers run for
Augmented Random Search today; ``algo=ars`` must be measured against it, episode for episode.

Each seed trains one ARS iteration at a time (``learn`` until one more iteration is done), and
every ``eval_every`` iterations measures the current (mean) policy on ``eval_episodes`` fresh
episodes of its own env -- as ``imix run ... eval_mean_every`` does; those episodes are not
counted as training episodes. One CSV per seed, ``<results_dir>/<experiment>/sb3_ars-<EnvId>/seed_<k>.csv``,
with imix's column names (generation, evaluations, env_steps, mean_policy_score,
mean_policy_episodes, wall_time); a seed whose CSV exists is skipped.

Hyper-parameters: rl-zoo3 2.9.2's hyperparams/ars.yml for the -v4 envs (:data:`ZOO_ARS`), run here
on the -v5 envs. The policy is imix's ``+ars=<env>`` one (linear, no bias, clipped actions). What
differs from imix's ARS (docs/ars.md): sb3-contrib's sigma_R is the unbiased std (ddof 1; the ARS
paper's code and imix: ddof 0); its state normalisation (VecNormalize) keeps updating (imix:
frozen after a warm-up). Both train Hopper and Walker2d with ``alive_bonus_offset`` -1.

    python -m imix_cli.bench.ars_peer --envs swimmer --seeds 3 --episodes 1000 [--experiment ars]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from imix_cli.core.registry import ENV_SPECS
from imix_cli.messages import install_extra

#: rl-zoo3 2.9.2, hyperparams/ars.yml, "Params closest to original paper" (the -v4 entries).
ZOO_ARS = {
    "swimmer": {"n_delta": 1, "n_top": 1, "learning_rate": 0.02, "delta_std": 0.01, "alive_bonus_offset": 0.0, "normalize": False},
    "hopper": {"n_delta": 8, "n_top": 4, "learning_rate": 0.01, "delta_std": 0.025, "alive_bonus_offset": -1.0, "normalize": True},
    "halfcheetah": {"n_delta": 32, "n_top": 4, "learning_rate": 0.02, "delta_std": 0.03, "alive_bonus_offset": 0.0, "normalize": True},
    "walker2d": {"n_delta": 40, "n_top": 30, "learning_rate": 0.03, "delta_std": 0.025, "alive_bonus_offset": -1.0, "normalize": True},
}
PEER_NAME = "sb3_ars"
INSTALL = install_extra("ars") + "  (sb3-contrib)"


def run_seed(env_name: str, seed: int, episodes: int, eval_every: int, eval_episodes: int) -> list[dict]:
    """Train sb3-contrib ARS on ``env_name`` for ``episodes`` training episodes; the rows of its CSV."""
    import gymnasium as gym
    import torch
    from sb3_contrib import ARS

    torch.set_num_threads(1)  # a linear policy: threads only contend (imix's episodes run on one thread too)
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    settings = dict(ZOO_ARS[env_name])
    normalize = settings.pop("normalize")
    gym_id = ENV_SPECS[env_name].gym_id
    venv = DummyVecEnv([lambda: gym.make(gym_id)])
    if normalize:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
    model = ARS("LinearPolicy", venv, seed=seed, verbose=0, **settings)
    eval_env = gym.make(gym_id)
    eval_seeds = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0x6D65616E,)))
    per_iteration = 2 * model.n_delta * model.n_eval_episodes
    rows, started, iteration, mean_policy_episodes = [], time.perf_counter(), 0, 0
    while iteration * per_iteration < episodes:
        model.learn(total_timesteps=1, reset_num_timesteps=False)  # exactly one iteration (SB3 adds num_timesteps to it)
        iteration += 1
        score = float("nan")
        if iteration % eval_every == 0:
            score = _mean_policy_return(model, venv if normalize else None, eval_env, eval_seeds, eval_episodes)
            mean_policy_episodes += eval_episodes
        rows.append({
            "algo": PEER_NAME, "env": env_name, "seed": seed, "generation": iteration - 1,
            "evaluations": iteration * per_iteration, "env_steps": int(model.num_timesteps),
            "mean_policy_score": score, "mean_policy_episodes": mean_policy_episodes,
            "wall_time": time.perf_counter() - started,
        })  # fmt: skip
    eval_env.close()
    venv.close()
    return rows


def _mean_policy_return(model, normalizer, env, seeds: np.random.Generator, episodes: int) -> float:
    """The current policy's mean return over fresh episodes (its training normaliser applied, not updated)."""
    total = 0.0
    for _ in range(episodes):
        obs, _ = env.reset(seed=int(seeds.integers(0, 2**31 - 1)))
        done, ret = False, 0.0
        while not done:
            x = normalizer.normalize_obs(obs) if normalizer is not None else obs
            action, _ = model.policy.predict(x, deterministic=True)
            obs, reward, terminated, truncated, _ = env.step(action)
            ret += float(reward)
            done = terminated or truncated
        total += ret
    return total / episodes


def seed_csv(results_dir: str, experiment: str, env_name: str, seed: int) -> Path:
    return Path(results_dir) / experiment / f"{PEER_NAME}-{ENV_SPECS[env_name].gym_id}" / f"seed_{seed}.csv"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m imix_cli.bench.ars_peer", description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", choices=sorted(ZOO_ARS), default=["swimmer"])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--seed", type=int, default=None, help="run only this seed (to spread seeds over processes)")
    parser.add_argument("--episodes", type=int, default=1000, help="training episodes per seed (whole iterations)")
    parser.add_argument("--eval-every", type=int, default=10, help="iterations between measurements of the mean policy")
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument("--results-dir", default="results")
    parser.add_argument("--experiment", default="ars")
    args = parser.parse_args(argv)
    for name, value in (("--seeds", args.seeds), ("--episodes", args.episodes), ("--eval-every", args.eval_every), ("--eval-episodes", args.eval_episodes)):
        if value < 1:
            parser.error(f"{name}={value}: must be >= 1")
    try:
        import sb3_contrib  # noqa: F401
    except ImportError:
        parser.error(f"sb3-contrib is not installed: {INSTALL}")
    import pandas as pd

    from imix_cli.running.files.results import atomic_write_bytes

    for env_name in args.envs:
        for seed in range(args.seeds) if args.seed is None else [args.seed]:
            path = seed_csv(args.results_dir, args.experiment, env_name, seed)
            if path.exists():
                print(f"{path}: exists, skipped", flush=True)
                continue
            rows = run_seed(env_name, seed, args.episodes, args.eval_every, args.eval_episodes)
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(path, pd.DataFrame(rows).to_csv(index=False).encode())
            print(f"{path}: {rows[-1]['evaluations']} episodes, {rows[-1]['wall_time']:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
