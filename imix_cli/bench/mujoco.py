"""``imix bench mujoco``: imix's cost per MuJoCo env step next to a plain gymnasium loop, and how much of a step is the physics.

Measured pair by pair (each repeat times the gymnasium loop, then imix, on the same machine
state; the ratio is the median of the repeats' ratios), for a linear policy without mixing:

* ``gymnasium loop``: ``gym.make(id)``, then one episode after the other: ``reset(seed=s)``,
  ``tanh(obs @ W + b)`` in numpy, ``env.step(action)`` until the episode ends -- the plainest
  way to run these policies in the same venv;
* ``physics``: the part of that loop spent in gymnasium's ``_step_mujoco_simulation`` (timed in
  place): the ctrl copy, ``mj_step(nstep=frame_skip)`` and ``mj_rnePostConstraint``, binding
  calls included. Any path that reproduces gymnasium's episodes bit for bit runs the same
  physics: this is the floor, up to the binding calls (imix's compiled step calls MuJoCo's C
  functions directly, so it can land a little below it);
* ``imix evaluator``: the same parameters and episode seeds through imix's pool evaluator with
  one worker (:class:`imix_cli.core.evaluation.parallel.PoolEvaluator`, the direct MuJoCo path;
  the episodes are the loop's, bit for bit: the step counts are checked equal), and the same
  pool evaluator on gymnasium's env (``IMIX_MUJOCO_BACKEND=gymnasium``: imix before the direct path);
* ``imix run``: ``imix run algo=snes env=<env> policy.hidden=[] evaluator=pool
  evaluator_workers=1 seeds=1`` (no mixing, no mean-policy episodes, no checkpoints) in this
  process: the wall time of its generations after the first (the first one also starts the
  worker process) over their env steps, from the CSV; the ES update and the IPC are included.
  Its policies are the ES's own (mean episode length shown), so its ratio compares similar,
  not identical, episodes.

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
    """``imix run`` (linear policy, no mixing, pool evaluator with one worker) in a temporary folder: (seconds, env steps)
    of its generations after the first, from the CSV's clock (the first one also starts the worker process).

    The run is the ``imix`` command in a child process, as a user starts it: the bench is one of that command's
    subcommands, so it never imports the command line back (the clock is the CSV's, so the child's start-up is not timed)."""
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    from imix_cli.running.files.results import read_run_csv

    with tempfile.TemporaryDirectory(prefix="imix-bench-mujoco-") as tmp:
        args = ["run", "algo=snes", f"env={env}", "policy.hidden=[]", "evaluator=pool", "evaluator_workers=1", "seeds=1",
                f"generations={generations}", f"popsize={popsize}", "eval_mean_every=0", "checkpoint_every=0", "progress=false",
                f"results_dir={tmp}"]  # fmt: skip
        done = subprocess.run([sys.executable, "-m", "imix_cli.commands.cli", *args], capture_output=True, text=True)  # the run's summary: not this table's
        if done.returncode != 0:
            raise RuntimeError(f"imix {' '.join(args)} failed: {done.stderr.strip()}")
        (csv,) = Path(tmp).rglob("seed_0.csv")
        frame = read_run_csv(csv)
        return float(frame["wall_time"].iloc[-1] - frame["wall_time"].iloc[0]), int(frame["env_steps"].iloc[-1] - frame["env_steps"].iloc[0])


def _gymnasium_backend_pool(env_id: str):
    """A pool evaluator (one worker) running gymnasium's env (``IMIX_MUJOCO_BACKEND=gymnasium`` while its worker starts), warmed up."""
    import os

    from imix_cli.core.evaluation import MUJOCO_BACKEND_VARIABLE
    from imix_cli.core.evaluation.parallel import PoolEvaluator

    saved = os.environ.get(MUJOCO_BACKEND_VARIABLE)
    os.environ[MUJOCO_BACKEND_VARIABLE] = "gymnasium"
    try:
        pool = PoolEvaluator(env_id, None, hidden=(), workers=1)
        pool.evaluate(np.zeros((1, pool.num_params)), np.zeros(1, dtype=np.int64))  # the worker starts now, under the variable
    finally:
        if saved is None:
            del os.environ[MUJOCO_BACKEND_VARIABLE]
        else:
            os.environ[MUJOCO_BACKEND_VARIABLE] = saved
    return pool


def mujoco_rows(envs=MUJOCO_BENCH_ENVS, popsize: int = 50, repeats: int = 3, run_generations: int = 5, echo=None) -> list[dict]:
    """One dict per env: per-step costs (seconds) and the pairwise ratios' medians."""
    from imix_cli.core.evaluation.parallel import PoolEvaluator
    from imix_cli.core.registry import ENV_SPECS

    rows = []
    run_generations = max(int(run_generations), 2)
    for env in envs:
        env_id = ENV_SPECS[env].gym_id
        pool = PoolEvaluator(env_id, None, hidden=(), workers=1)
        before = _gymnasium_backend_pool(env_id)
        try:
            params, seeds = _linear_policies(pool, popsize), np.arange(popsize)
            # not timed: the workers load the model (and the compiled step), make their envs or MjData for the whole batch
            pool.evaluate(params, seeds)
            before.evaluate(params, seeds)
            gym_costs, physics_costs, eval_costs, run_costs, eval_ratios, run_ratios, physics_ratios = ([] for _ in range(7))
            before_costs, before_ratios = [], []
            run_episode = 0.0
            for _ in range(repeats):
                g_seconds, g_physics, g_steps = _gym_loop(env_id, params, seeds, pool.obs_dim, pool.out_dim)
                started = time.perf_counter()
                _, steps = pool.evaluate(params, seeds)
                e_seconds = time.perf_counter() - started
                if int(steps.sum()) != g_steps:
                    raise RuntimeError(f"{env_id}: imix's episodes took {int(steps.sum())} steps, gymnasium's {g_steps}: not the same episodes")
                started = time.perf_counter()
                _, before_steps = before.evaluate(params, seeds)
                b_seconds = time.perf_counter() - started
                assert int(before_steps.sum()) == g_steps
                before_costs.append(b_seconds / g_steps)
                gym_costs.append(g_seconds / g_steps)
                before_ratios.append(before_costs[-1] / gym_costs[-1])
                physics_costs.append(g_physics / g_steps)
                eval_costs.append(e_seconds / g_steps)
                eval_ratios.append(eval_costs[-1] / gym_costs[-1])
                physics_ratios.append(physics_costs[-1] / gym_costs[-1])
                r_seconds, r_steps = _imix_run(env, run_generations, popsize)
                run_costs.append(r_seconds / r_steps)
                run_ratios.append(run_costs[-1] / gym_costs[-1])
                run_episode = r_steps / ((run_generations - 1) * popsize)
            row = {
                "env": env_id, "episode": g_steps / popsize, "run_episode": run_episode,
                "gym": float(np.median(gym_costs)), "physics": float(np.median(physics_costs)),
                "evaluator": float(np.median(eval_costs)), "run": float(np.median(run_costs)),
                "evaluator_ratio": float(np.median(eval_ratios)), "run_ratio": float(np.median(run_ratios)),
                "physics_ratio": float(np.median(physics_ratios)), "repeats": repeats,
                "before": float(np.median(before_costs)), "before_ratio": float(np.median(before_ratios)),
            }  # fmt: skip
            rows.append(row)
            if echo:
                echo(f"  {env_id}: imix {row['evaluator_ratio']:.2f}x the gymnasium loop's cost per step (physics {row['physics_ratio']:.2f}x)")
        finally:
            pool.close()
            before.close()
    return rows


def format_mujoco(rows: list[dict]) -> str:
    def us(seconds: float) -> str:
        return f"{seconds * 1e6:.1f}"

    header = ["env", "mean episode (loop / run)", "gymnasium loop (µs/step)", "physics (µs/step)", "imix evaluator (µs/step)",
              "imix run (µs/step)", "imix on gymnasium's env (µs/step)", "evaluator / loop", "run / loop", "on gymnasium's env / loop",
              "physics / loop (floor)"]  # fmt: skip
    body = [
        [r["env"], f"{r['episode']:.0f} / {r['run_episode']:.0f}", us(r["gym"]), us(r["physics"]), us(r["evaluator"]), us(r["run"]),
         us(r["before"]), f"{r['evaluator_ratio']:.2f}", f"{r['run_ratio']:.2f}", f"{r['before_ratio']:.2f}", f"{r['physics_ratio']:.2f}"]
        for r in rows
    ]  # fmt: skip
    return table(header, body, "lrrrrrrrrrr")
