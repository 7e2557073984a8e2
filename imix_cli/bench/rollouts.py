"""``imix bench rollouts``: env-steps/s of imix's evaluator next to a naive loop and SyncVectorEnv
(the policies: see :mod:`imix_cli.bench`)."""

from __future__ import annotations

import numpy as np

from imix_cli.bench.common import EPISODE_CAP, ROLLOUT_ENVS, median_rate, si, table


def bench_policies(env: str, batch: int) -> np.ndarray:
    """The fixed parameter matrices (batch, d) of the rollout benchmark (module docstring)."""
    from imix_cli.core.evaluation import make_evaluator

    d = make_evaluator(env).num_params
    rng = np.random.default_rng(0)
    if env == "acrobot":
        return 0.5 * rng.standard_normal((batch, d))
    # CartPole: layer 1 unit 0 = tanh(k . obs), layer 2 unit 0 copies it, outputs (-h, +h).
    W1, W2, W3 = np.zeros((4, 8)), np.zeros((8, 8)), np.zeros((8, 2))
    W1[:, 0] = [0.1, 0.3, 2.0, 0.5]  # x, x_dot, theta, theta_dot
    W2[0, 0] = 1.0
    W3[0] = [-1.0, 1.0]
    base = np.concatenate([W1.ravel(), np.zeros(8), W2.ravel(), np.zeros(8), W3.ravel(), np.zeros(2)])
    assert base.size == d
    return base + 0.1 * rng.standard_normal((batch, d))


def _naive_rollouts(env: str, params: np.ndarray, seeds: np.ndarray) -> tuple[int, None]:
    """One episode at a time: gymnasium.make + a numpy MLP forward pass per step. (Env steps, None)."""
    import gymnasium as gym

    from imix_cli.core.evaluation.policies import unpack

    e = gym.make(ROLLOUT_ENVS[env], max_episode_steps=EPISODE_CAP)
    obs_dim, n_act = e.observation_space.shape[0], e.action_space.n
    total = 0
    try:
        for p, seed in zip(params, seeds):
            (W1, b1), (W2, b2), (W3, b3) = [(W[0], b[0]) for W, b in unpack(p[None], obs_dim, n_act)]
            obs, _ = e.reset(seed=int(seed))
            done = False
            while not done:
                h = np.tanh(obs @ W1 + b1)
                h = np.tanh(h @ W2 + b2)
                action = int(np.argmax(h @ W3 + b3))
                obs, _, terminated, truncated, _ = e.step(action)
                total += 1
                done = terminated or truncated
    finally:
        e.close()
    return total, None


def _batched_rollouts(evaluator, params: np.ndarray, seeds: np.ndarray):
    """The batched evaluator: (env steps, episode lengths)."""
    _, steps = evaluator.evaluate(params, seeds)
    return int(steps.sum()), steps


def _make_sync_vector_env(env: str, batch: int):
    import gymnasium as gym

    def make():
        return gym.make(ROLLOUT_ENVS[env], max_episode_steps=EPISODE_CAP)

    return gym.vector.SyncVectorEnv([make] * batch)


def _sync_vector_rollouts(venv, params: np.ndarray, seeds: np.ndarray):
    """gymnasium's SyncVectorEnv stepping the same batched policy until every episode ended."""
    from imix_cli.core.evaluation.policies import BatchPolicy

    obs_dim, n_act = venv.single_observation_space.shape[0], venv.single_action_space.n
    policy = BatchPolicy(params, obs_dim, n_act)
    obs, _ = venv.reset(seed=[int(s) for s in seeds])
    alive = np.ones(len(params), dtype=bool)
    total = 0
    while alive.any():
        obs, _, terminated, truncated, _ = venv.step(policy(obs))
        total += int(np.count_nonzero(alive))
        alive &= ~(terminated | truncated)
    return total, None


def rollout_rows(sizes=(2, 50, 1250), envs=("cartpole", "acrobot"), repeats: int = 3, min_seconds: float = 1.0,
                 naive_members: int = 20, echo=None) -> list[dict]:  # fmt: skip
    """Measure the batched evaluator and both baselines; one dict per (env, batch size)."""
    from imix_cli.core.evaluation import make_evaluator

    rows = []
    for env in envs:
        ev = make_evaluator(env)
        params_all = bench_policies(env, max(sizes))
        ev.evaluate(params_all[:1], np.arange(1))  # compiles (first run) or loads the kernels: not timed
        n_naive = min(naive_members, max(sizes))
        naive_rate, _ = median_rate(_naive_rollouts, (env, params_all[:n_naive], np.arange(n_naive)))
        for b in sizes:
            params, seeds = params_all[:b], np.arange(b)
            rate, steps = median_rate(_batched_rollouts, (ev, params, seeds), repeats, min_seconds)
            venv = _make_sync_vector_env(env, b)
            try:
                sync_rate, _ = median_rate(_sync_vector_rollouts, (venv, params, seeds))
            finally:
                venv.close()
            row = {
                "env": env, "batch": b, "mean_episode": float(np.mean(steps)), "batched": rate,
                "sync_vector_env": sync_rate, "naive": naive_rate,
            }  # fmt: skip
            rows.append(row)
            if echo:
                echo(f"  {env} B={b}: {si(rate)} steps/s (SyncVectorEnv {si(sync_rate)}, naive {si(naive_rate)})")
    return rows


def format_rollouts(rows: list[dict]) -> str:
    header = ["env", "batch", "mean episode", "batched (steps/s)", "SyncVectorEnv (steps/s)", "naive loop (steps/s)",
              "× SyncVectorEnv", "× naive"]  # fmt: skip
    body = [
        [r["env"], r["batch"], f"{r['mean_episode']:.0f}", si(r["batched"]), si(r["sync_vector_env"]), si(r["naive"]),
         f"{r['batched'] / r['sync_vector_env']:.1f}", f"{r['batched'] / r['naive']:.0f}"]
        for r in rows
    ]  # fmt: skip
    return table(header, body, "lrrrrrrr")
