"""Episode cost of the MuJoCo envs through imix's evaluators (the numbers behind the study's budget).

    python benchmarks/mujoco_speed.py [Swimmer-v5,Hopper-v5,...] [--workers 2]

For each env: environment steps per second of one batch of 20 linear policies drawn from
N(0, 0.1^2) (what a run starts with; episode seeds 0..19), through the local evaluator and
through ``evaluator=pool`` with ``--workers`` processes, plus the raw single-env stepping rate
of ``gym.make(id)`` with zero actions (resets included) as the baseline measured in the same
run. Results of local and pool are checked equal. Compare ratios, not absolute numbers, across
machines: a shared machine lowers everything and removes the pool's gain.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

ENVS = ("Swimmer-v5", "Hopper-v5", "HalfCheetah-v5", "Walker2d-v5", "Ant-v5")


def raw_rate(env_id: str, seconds: float = 1.0) -> float:
    import gymnasium as gym

    env = gym.make(env_id)
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    n, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        _, _, terminated, truncated, _ = env.step(action)
        n += 1
        if terminated or truncated:
            env.reset()
    env.close()
    return n / (time.perf_counter() - start)


def main() -> None:
    from imix_cli.core.evaluation import make_evaluator
    from imix_cli.core.evaluation.parallel import PoolEvaluator

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("envs", nargs="?", default=",".join(ENVS))
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    print(f"| env | d (linear) | mean episode | raw gym.make (steps/s) | local evaluator (steps/s) | pool({args.workers}) (steps/s) | pool / local |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for env_id in args.envs.split(","):
        ev = make_evaluator(env_id, hidden=())
        params = np.random.default_rng(0).normal(0.0, 0.1, (20, ev.num_params))
        seeds = np.arange(20)
        ev.evaluate(params, seeds)  # makes the envs
        start = time.perf_counter()
        returns, steps = ev.evaluate(params, seeds)
        local = time.perf_counter() - start
        pool = PoolEvaluator(env_id, hidden=(), workers=args.workers)
        try:
            pool.evaluate(params, seeds)
            start = time.perf_counter()
            pool_returns, _ = pool.evaluate(params, seeds)
            pooled = time.perf_counter() - start
        finally:
            pool.close()
        assert np.array_equal(returns, pool_returns)
        print(
            f"| {env_id} | {ev.num_params} | {steps.mean():.0f} | {raw_rate(env_id):,.0f} | {steps.sum() / local:,.0f} | "
            f"{steps.sum() / pooled:,.0f} | {local / pooled:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
