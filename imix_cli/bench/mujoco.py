"""``imix bench mujoco``: imix's cost per MuJoCo env step next to a plain gymnasium loop, and how much of a step is the physics.

Measured pair by pair (each repeat times the gymnasium loop, then imix, on the same machine
state; the ratio is the median of the repeats' ratios), for a linear policy without mixing:

* ``gymnasium loop``: ``gym.make(id)``, then one episode after the other: ``reset(seed=s)``,
  ``tanh(obs @ W + b)`` in numpy, ``env.step(action)`` until the episode ends -- the plainest
  way to run these policies in the same venv;
* ``physics``: the part of that loop spent in ``mj_step(nstep=frame_skip)`` and
  ``mj_rnePostConstraint`` (gymnasium's ``_step_mujoco_simulation``, timed in place). Any path
  that reproduces gymnasium's episodes bit for bit runs the same physics: this is the floor;
* ``imix evaluator``: the same parameters and episode seeds through imix's pool evaluator with
  one worker (:class:`imix_cli.parallel_evaluation.PoolEvaluator`, the direct MuJoCo path;
  the episodes are the loop's, bit for bit: the step counts are checked equal);
* ``imix run``: ``imix run algo=snes env=<env> policy.hidden=[] evaluator=pool
  evaluator_workers=1 seeds=1`` (no mixing, no mean-policy episodes, no checkpoints) in this
  process: wall time over the run's env steps, ES update and files included. Its policies are
  the ES's own (mean episode length shown), so its ratio compares similar, not identical, episodes.

The parameters: ``popsize`` linear policies N(0, sigma^2) (numpy seed 0, sigma the paper's 0.25,
what the ES samples first), episode seeds 0..popsize-1.
"""

from __future__ import annotations

import time

import numpy as np

from imix_cli.bench.common import table

MUJOCO_BENCH_ENVS = ("halfcheetah", "hopper")


def _linear_policies(evaluator, popsize: int) -> np.ndarray:
    return 0.25 * np.random.default_rng(0).standard_normal((popsize, evaluator.num_params))


def _gym_loop(env_id: str, params: np.ndarray, seeds: np.ndarray, obs_dim: int, act_dim: int) -> tuple[float, float, int]:
    """Plain gymnasium, one episode after the other: (seconds, seconds in the physics, env steps)."""
    import gymnasium as gym

    env = gym.make(env_id)
    sim = env.unwrapped
    physics = [0.0]
    step_simulation = sim._step_mujoco_simulation

    def timed_simulation(ctrl, n_frames):
        t = time.perf_counter()
        step_simulation(ctrl, n_frames)
        physics[0] += time.perf_counter() - t

    sim._step_mujoco_simulation = timed_simulation  # an instance attribute: this env only
    steps = 0
    started = time.perf_counter()
    for p, seed in zip(params, seeds):
        W, b = p[: obs_dim * act_dim].reshape(obs_dim, act_dim), p[obs_dim * act_dim :]
        obs, _ = env.reset(seed=int(seed))
        done = False
        while not done:
            action = np.tanh(obs @ W + b).astype(np.float32)
            obs, _, terminated, truncated, _ = env.step(action)
            steps += 1
            done = terminated or truncated
    seconds = time.perf_counter() - started
    env.close()
    return seconds, physics[0], steps


def _imix_run(env: str, generations: int, popsize: int) -> tuple[float, int]:
    """``imix run`` (linear policy, no mixing, pool evaluator with one worker) in a temporary folder: (seconds, env steps)."""
    import tempfile
    from pathlib import Path

    from imix_cli.cli import main
    from imix_cli.results import read_run_csv

    with tempfile.TemporaryDirectory(prefix="imix-bench-mujoco-") as tmp:
        args = ["run", "algo=snes", f"env={env}", "policy.hidden=[]", "evaluator=pool", "evaluator_workers=1", "seeds=1",
                f"generations={generations}", f"popsize={popsize}", "eval_mean_every=0", "checkpoint_every=0", "progress=false",
                f"results_dir={tmp}"]  # fmt: skip
        started = time.perf_counter()
        if main(args) != 0:
            raise RuntimeError(f"imix {' '.join(args)} failed")
        seconds = time.perf_counter() - started
        (csv,) = Path(tmp).rglob("seed_0.csv")
        return seconds, int(read_run_csv(csv)["env_steps"].iloc[-1])


def mujoco_rows(envs=MUJOCO_BENCH_ENVS, popsize: int = 50, repeats: int = 3, run_generations: int = 5, echo=None) -> list[dict]:
    """One dict per env: per-step costs (seconds) and the pairwise ratios' medians."""
    from imix_cli.parallel_evaluation import PoolEvaluator
    from imix_cli.registry import ENV_SPECS

    rows = []
    for env in envs:
        env_id = ENV_SPECS[env].gym_id
        pool = PoolEvaluator(env_id, None, hidden=(), workers=1)
        try:
            params, seeds = _linear_policies(pool, popsize), np.arange(popsize)
            pool.evaluate(params[:1], seeds[:1])  # the worker starts and loads the model: not timed
            gym_costs, physics_costs, eval_costs, run_costs, eval_ratios, run_ratios, physics_ratios = ([] for _ in range(7))
            run_episode = 0.0
            for _ in range(repeats):
                g_seconds, g_physics, g_steps = _gym_loop(env_id, params, seeds, pool.obs_dim, pool.out_dim)
                started = time.perf_counter()
                _, steps = pool.evaluate(params, seeds)
                e_seconds = time.perf_counter() - started
                if int(steps.sum()) != g_steps:
                    raise RuntimeError(f"{env_id}: imix's episodes took {int(steps.sum())} steps, gymnasium's {g_steps}: not the same episodes")
                gym_costs.append(g_seconds / g_steps)
                physics_costs.append(g_physics / g_steps)
                eval_costs.append(e_seconds / g_steps)
                eval_ratios.append(eval_costs[-1] / gym_costs[-1])
                physics_ratios.append(physics_costs[-1] / gym_costs[-1])
                r_seconds, r_steps = _imix_run(env, run_generations, popsize)
                run_costs.append(r_seconds / r_steps)
                run_ratios.append(run_costs[-1] / gym_costs[-1])
                run_episode = r_steps / (run_generations * popsize)
            row = {
                "env": env_id, "episode": g_steps / popsize, "run_episode": run_episode,
                "gym": float(np.median(gym_costs)), "physics": float(np.median(physics_costs)),
                "evaluator": float(np.median(eval_costs)), "run": float(np.median(run_costs)),
                "evaluator_ratio": float(np.median(eval_ratios)), "run_ratio": float(np.median(run_ratios)),
                "physics_ratio": float(np.median(physics_ratios)), "repeats": repeats,
            }  # fmt: skip
            rows.append(row)
            if echo:
                echo(f"  {env_id}: imix {row['evaluator_ratio']:.2f}x the gymnasium loop's cost per step (physics {row['physics_ratio']:.2f}x)")
        finally:
            pool.close()
    return rows


def format_mujoco(rows: list[dict]) -> str:
    def us(seconds: float) -> str:
        return f"{seconds * 1e6:.1f}"

    header = ["env", "mean episode (loop / run)", "gymnasium loop (µs/step)", "physics (µs/step)", "imix evaluator (µs/step)",
              "imix run (µs/step)", "evaluator / loop", "run / loop", "physics / loop (floor)"]  # fmt: skip
    body = [
        [r["env"], f"{r['episode']:.0f} / {r['run_episode']:.0f}", us(r["gym"]), us(r["physics"]), us(r["evaluator"]), us(r["run"]),
         f"{r['evaluator_ratio']:.2f}", f"{r['run_ratio']:.2f}", f"{r['physics_ratio']:.2f}"]
        for r in rows
    ]  # fmt: skip
    return table(header, body, "lrrrrrrrr")
