"""``imix bench``: speed benchmarks, each next to its baseline measured in the same run.

Sections (give any of them; default ``rollouts mixing memory``; ``all`` runs every one)::

    rollouts   env-steps/s of imix's evaluator (imix_cli.evaluation.make_evaluator: compiled
               episodes, policy included) for CartPole and Acrobot at several batch sizes (2: what
               importance mixing leaves fresh per seed; 50: one population), next to a naive loop
               (gymnasium.make + numpy MLP per step, one episode at a time) and gymnasium's
               SyncVectorEnv stepping the same batched numpy policy; ratios of the three.
    mixing     one importance-mixing step (paper, eim, sun2009) against plain sampling of the
               same population (N = 50, K = 3), d = 130 (the paper's CartPole) to 10^6.
    memory     wall time, CPU time and peak RSS (VmHWM) of `imix run algo=snes env=cartpole
               eim=true seeds=25` in a subprocess: its main process and its worker processes.
    breakdown  where a run's time goes: evaluation, mixing (or plain sampling) and ES update
               of a lockstep run in this process (seeds of one worker, paper dimensions).
    grid       wall time and total env steps of the paper's main grid (4 ES x CartPole,
               Acrobot x 25 seeds at the paper's generation counts), with EIM and without
               mixing, through imix_cli.runner.run into a temporary folder. Takes minutes.
    peers      the same task in a peer library, in this run: evosax SNES and OpenES + gymnax
               CartPole-v1 / Acrobot-v1 (both capped at 200 steps), the same 8-8 tanh MLP, pop 50,
               no mixing, the whole loop jitted with the seeds vmapped (JAX on CPU); next to
               `imix run algo=snes env=<env> eim=true` and `eim=false` (in this process, all
               cores, a temporary results folder). Wall times (JAX's compile time included and
               shown), env steps, final scores and ratios. Default 25 seeds x 1000 generations
               (minutes); --quick: 3 x 100. Needs the `peers` extra (pip install 'imix-cli[peers]');
               without it the section says so and the command still exits 0.

Policies of the rollout benchmark (fixed, so episodes have realistic lengths): CartPole, a
hand-built balancing controller written as an MLP (action = sign of 2 theta + 0.5 theta_dot
+ 0.3 x_dot + 0.1 x through one tanh unit per layer) plus N(0, 0.1^2) noise on every parameter
(numpy seed 0): a late-training population, mean episode ~190 steps. Acrobot, random
N(0, 0.5^2) parameters (seed 0): an early-training population, mean episode ~195 steps of
the 200-step cap. Episode seeds 0..B-1.

Timings are medians of repeats; the machine may be shared, so compare the ratios (measured
in the same run) rather than absolute numbers across runs. Exit status 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

__all__ = ["SECTIONS", "main", "mixing_rows", "mixing_times", "peer_rows", "rollout_rows"]

SECTIONS = ("rollouts", "mixing", "memory", "breakdown", "grid", "peers")
DEFAULT_SECTIONS = ("rollouts", "mixing", "memory")
ROLLOUT_ENVS = {"cartpole": "CartPole-v1", "acrobot": "Acrobot-v1"}  # gymnasium ids of the baselines
EPISODE_CAP = 200
PAPER_GRID = ["algo=openes,snes,cem,cmaes", "env=cartpole,acrobot"]  # as `make reproduce` (estool weight decay: the default)


class BenchError(ValueError):
    """Bad arguments: one line, exit status 2."""


# ------------------------------------------------------------------------------ helpers
def _median_rate(fn, args: tuple, min_repeats: int = 1, min_seconds: float = 0.0) -> tuple[float, object]:
    """Median of ``units / seconds`` over repeats of ``fn(*args) -> (units, result)``; at least
    ``min_repeats`` repeats and ``min_seconds`` in total."""
    rates, started, result = [], time.perf_counter(), None
    while len(rates) < min_repeats or time.perf_counter() - started < min_seconds:
        t = time.perf_counter()
        units, result = fn(*args)
        rates.append(units / max(time.perf_counter() - t, 1e-12))
    return float(np.median(rates)), result


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def _table(header: list[str], rows: list[list], align: str) -> str:
    """A markdown table; ``align`` has one of 'l'/'r' per column."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" if a == "l" else "---:" for a in align) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _si(x: float) -> str:
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if abs(x) >= scale:
            return f"{x / scale:.2f}{unit}"
    return f"{x:.0f}"


# ------------------------------------------------------------------------------ rollouts
def bench_policies(env: str, batch: int) -> np.ndarray:
    """The fixed parameter matrices (batch, d) of the rollout benchmark (module docstring)."""
    from imix_cli.evaluation import make_evaluator

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


def _naive_rollouts(env: str, params: np.ndarray, seeds: np.ndarray) -> int:
    """One episode at a time: gymnasium.make + a numpy MLP forward pass per step. Env steps."""
    import gymnasium as gym

    from imix_cli.policies import unpack

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
    from imix_cli.policies import BatchPolicy

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
    from imix_cli.evaluation import make_evaluator

    rows = []
    for env in envs:
        ev = make_evaluator(env)
        params_all = bench_policies(env, max(sizes))
        ev.evaluate(params_all[:1], np.arange(1))  # compiles (first run) or loads the kernels: not timed
        n_naive = min(naive_members, max(sizes))
        naive_rate, _ = _median_rate(_naive_rollouts, (env, params_all[:n_naive], np.arange(n_naive)))
        for b in sizes:
            params, seeds = params_all[:b], np.arange(b)
            rate, steps = _median_rate(_batched_rollouts, (ev, params, seeds), repeats, min_seconds)
            venv = _make_sync_vector_env(env, b)
            try:
                sync_rate, _ = _median_rate(_sync_vector_rollouts, (venv, params, seeds))
            finally:
                venv.close()
            row = {
                "env": env, "batch": b, "mean_episode": float(np.mean(steps)), "batched": rate,
                "sync_vector_env": sync_rate, "naive": naive_rate,
            }  # fmt: skip
            rows.append(row)
            if echo:
                echo(f"  {env} B={b}: {_si(rate)} steps/s (SyncVectorEnv {_si(sync_rate)}, naive {_si(naive_rate)})")
    return rows


def format_rollouts(rows: list[dict]) -> str:
    header = ["env", "batch", "mean episode", "batched (steps/s)", "SyncVectorEnv (steps/s)", "naive loop (steps/s)",
              "× SyncVectorEnv", "× naive"]  # fmt: skip
    body = [
        [r["env"], r["batch"], f"{r['mean_episode']:.0f}", _si(r["batched"]), _si(r["sync_vector_env"]), _si(r["naive"]),
         f"{r['batched'] / r['sync_vector_env']:.1f}", f"{r['batched'] / r['naive']:.0f}"]
        for r in rows
    ]  # fmt: skip
    return _table(header, body, "lrrrrrrr")


# ------------------------------------------------------------------------------ mixing
def mixing_times(dim: int, popsize: int = 50, generations: int = 3, repeats: int = 5, seed: int = 0,
                 variants=("paper", "eim", "sun2009")):  # fmt: skip
    """Median seconds of one ``mix`` per variant and of ``new_dist.sample(popsize)``, and reuse rates.

    The archive holds ``generations`` earlier generations with a realistic small move of the
    search distribution between them (high overlap, as OpenES/SNES see in the paper). Samples
    are float32 from d = 10^5 on (both sides), as the library recommends for memory.
    """
    from imix_cli.mixing import DiagonalGaussian, mix

    rng = np.random.default_rng(seed)
    dtype = np.float32 if dim >= 100_000 else np.float64
    # A move of ~0.05 sigma per coordinate in total Mahalanobis length keeps overlap high.
    step = 0.05 / np.sqrt(dim)
    dists = [
        DiagonalGaussian(np.full(dim, step * k), np.full(dim, 0.25 * (1 - 0.001 * k) ** (1 / np.sqrt(dim))), dtype=dtype)
        for k in range(generations + 1)
    ]
    archive = []
    for dist in dists[:-1]:
        archive.insert(0, mix(dist, archive, popsize, rng, variant="eim"))
    new = dists[-1]
    results = {"sample": median_time(lambda: new.sample(popsize, rng), repeats)}
    reuse = {}
    for variant in variants:
        results[variant] = median_time(
            lambda v=variant: mix(new, archive, popsize, rng, variant=v, eim_generations=generations), repeats
        )
        reuse[variant] = mix(new, archive, popsize, rng, variant=variant, eim_generations=generations).reused / popsize
    return results, reuse


def mixing_rows(dims=(130, 1_000, 100_000, 1_000_000), repeats: int = 5, variants=("paper", "eim", "sun2009")) -> list[dict]:
    rows = []
    for dim in dims:
        results, reuse = mixing_times(dim, repeats=repeats, variants=variants)
        for v in variants:
            rows.append({"dim": dim, "sample": results["sample"], "variant": v, "mix": results[v], "reuse": reuse[v]})
    return rows


def format_mixing(rows: list[dict]) -> str:
    body = [
        [r["dim"], f"{r['sample'] * 1e3:.3f}", r["variant"], f"{r['mix'] * 1e3:.3f}", f"{r['mix'] / r['sample']:.2f}",
         f"{r['reuse']:.2f}"]
        for r in rows
    ]  # fmt: skip
    return _table(["d", "plain sample (ms)", "variant", "mix (ms)", "mix / sample", "reuse"], body, "rrlrrr")


# ------------------------------------------------------------------------------ memory
_MEMORY_CHILD = """\
import json, os, resource, sys, threading, time

def hwm_kb(pid):  # peak resident set size of a live process (its own address space)
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
    except (OSError, StopIteration, ValueError):
        return 0

def descendants(pid):
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            kids = [int(k) for k in f.read().split()]
    except OSError:
        return []
    return kids + [d for k in kids for d in descendants(k)]

peaks, done = {}, threading.Event()

def poll():  # ru_maxrss would count the RSS a process inherits at fork; VmHWM does not
    while not done.is_set():
        for pid in descendants(os.getpid()):
            peaks[pid] = max(peaks.get(pid, 0), hwm_kb(pid))
        done.wait(0.05)

threading.Thread(target=poll, daemon=True).start()
from imix_cli.cli import main
code = main(["run", *sys.argv[1:]])
done.set()
me, workers = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
worker_peaks = [kb for kb in peaks.values() if kb > 0]
print("IMIX_BENCH " + json.dumps({
    "code": code, "main_kb": hwm_kb(os.getpid()), "worker_kb": max(worker_peaks, default=0),
    "workers_total_kb": sum(worker_peaks), "processes": len(worker_peaks),
    "main_cpu": me.ru_utime + me.ru_stime, "worker_cpu": workers.ru_utime + workers.ru_stime,
}))
"""


def memory_row(overrides: list[str], seeds: int, generations: int | None, workers: int | None) -> dict:
    """Run ``imix run <overrides> seeds=<seeds>`` in a subprocess; wall time and peak RSS."""
    with tempfile.TemporaryDirectory(prefix="imix-bench-") as tmp:
        args = [*overrides, f"seeds={seeds}", "progress=false", f"results_dir={tmp}", "experiment=bench"]
        if generations is not None:
            args.append(f"generations={generations}")
        if workers is not None:
            args.append(f"workers={workers}")
        started = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", _MEMORY_CHILD, *args], capture_output=True, text=True, check=False)
        wall = time.perf_counter() - started
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("IMIX_BENCH ")), None)
    if proc.returncode != 0 or line is None:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"imix run {' '.join(args)} failed: {tail}")
    info = json.loads(line.split(" ", 1)[1])
    if info["code"] != 0:
        raise RuntimeError(f"imix run {' '.join(args)} exited with {info['code']}")
    return {
        "command": "imix run " + " ".join(a for a in args if not a.startswith(("results_dir=", "experiment="))),
        "wall": wall, "main_mb": info["main_kb"] / 1024, "worker_mb": info["worker_kb"] / 1024,
        "total_mb": (info["main_kb"] + info["workers_total_kb"]) / 1024, "processes": 1 + info["processes"],
        "main_cpu": info["main_cpu"], "worker_cpu": info["worker_cpu"],
    }  # fmt: skip


def format_memory(row: dict) -> str:
    body = [[f"`{row['command']}`", f"{row['wall']:.1f}", f"{row['main_cpu']:.1f} / {row['worker_cpu']:.1f}",
             f"{row['main_mb']:.0f}", f"{row['worker_mb']:.0f}", f"{row['total_mb']:.0f} ({row['processes']} processes)"]]  # fmt: skip
    header = ["command", "wall (s)", "CPU (s): main / all workers", "main process peak RSS (MB)",
              "largest worker peak RSS (MB)", "sum of peaks (MB)"]  # fmt: skip
    return _table(header, body, "lrrrrr")


# ------------------------------------------------------------------------------ breakdown
def _timed(fn, clock: dict, key: str):
    """``fn`` that adds its wall time to ``clock[key]``."""

    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            clock[key] += time.perf_counter() - t

    return wrapper


def breakdown_rows(configs, seeds: int, generations: int | None) -> list[dict]:
    """Lockstep runs in this process: seconds in evaluation, mixing/sampling and ES update."""
    from imix_cli import generation, runner
    from imix_cli.config import validate_overrides
    from imix_cli.evaluation import make_evaluator

    rows = []
    for overrides in configs:
        gens = [] if generations is None else [f"generations={generations}"]
        spec = validate_overrides([*overrides, f"seeds={seeds}", "workers=1", *gens])[0]
        ev = make_evaluator(spec.evaluator_key, spec.env_max_steps)
        states = [runner.new_seed_state(spec, s, ev.num_params) for s in range(seeds)]
        clock = {"evaluate": 0.0, "mix": 0.0, "ask": 0.0, "tell": 0.0}
        ev.evaluate = _timed(ev.evaluate, clock, "evaluate")
        for st in states:
            st.es.ask, st.es.tell = _timed(st.es.ask, clock, "ask"), _timed(st.es.tell, clock, "tell")
        original_mix = generation.mix  # the one generation step (imix_cli.generation) mixes through it
        generation.mix = _timed(original_mix, clock, "mix")
        try:
            started = time.perf_counter()
            for _ in range(spec.generations):
                runner.advance_lockstep(states, spec, ev)
            total = time.perf_counter() - started
        finally:
            generation.mix = original_mix
        rows.append({
            "run": spec.run_name, "seeds": seeds, "generations": spec.generations, "dim": ev.num_params, "total": total,
            **clock, "env_steps": sum(st.env_steps for st in states),
        })  # fmt: skip
    return rows


def format_breakdown(rows: list[dict]) -> str:
    body = []
    for r in rows:
        sampling = r["mix"] + r["ask"]
        other = r["total"] - r["evaluate"] - sampling - r["tell"]
        shares = [f"{100 * x / r['total']:.1f}%" for x in (r["evaluate"], sampling, r["tell"], sampling + r["tell"], other)]
        body.append([r["run"], r["seeds"], r["generations"], r["dim"], f"{r['total']:.1f}", *shares])
    header = ["run", "seeds", "generations", "d", "time (s)", "evaluation", "mixing / sampling", "ES update",
              "mixing + update", "other"]  # fmt: skip
    return _table(header, body, "lrrrrrrrrr")


# ------------------------------------------------------------------------------ grid
def grid_rows(seeds: int | None, generations: int | None, algos, envs, extra: list[str], echo=None) -> list[dict]:
    """The paper's main grid, without mixing and with EIM, through imix_cli.runner.run."""
    from imix_cli.config import validate_overrides
    from imix_cli.runner import run

    rows = []
    with tempfile.TemporaryDirectory(prefix="imix-bench-grid-") as tmp:
        for eim in ("false", "true"):
            overrides = [f"algo={','.join(algos)}", f"env={','.join(envs)}", f"eim={eim}", *extra,
                         "progress=false", f"results_dir={tmp}", "experiment=grid"]  # fmt: skip
            if seeds is not None:
                overrides.append(f"seeds={seeds}")
            if generations is not None:
                overrides.append(f"generations={generations}")
            for spec in validate_overrides(overrides):
                before = _cpu_seconds()
                summary = run(spec, echo=lambda *_: None)
                cpu = _cpu_seconds() - before
                row = {"run": spec.run_name, "mixing": spec.mixing, "seeds": spec.seeds, "generations": spec.generations,
                       "wall": summary["wall_time"], "env_steps": summary["env_steps"],
                       "evaluations": summary["evaluations"], "final": summary["final_mean_score"], "cpu": cpu}  # fmt: skip
                rows.append(row)
                if echo:
                    echo(f"  {row['run']}: {row['wall']:.1f} s ({row['cpu']:.1f} s CPU), {row['env_steps']:,} env steps")
    return rows


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process and of its finished children (the pool workers)."""
    me, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + children.ru_utime + children.ru_stime


def format_grid(rows: list[dict]) -> str:
    body = [[r["run"], r["seeds"], r["generations"], f"{r['wall']:.1f}", f"{r['cpu']:.1f}", f"{r['env_steps']:,}",
             f"{r['evaluations']:,}", f"{r['final']:.1f}"] for r in rows]  # fmt: skip
    groups = [(f"**total, mixing={m}**", [r for r in rows if r["mixing"] == m]) for m in ("none", "eim")]
    for label, sel in [*groups, ("**grid total**", rows)]:
        if sel:
            body.append([label, "", "", f"**{sum(r['wall'] for r in sel):.1f}**", f"{sum(r['cpu'] for r in sel):.1f}",
                         f"**{sum(r['env_steps'] for r in sel):,}**", f"{sum(r['evaluations'] for r in sel):,}", ""])  # fmt: skip
    header = ["run", "seeds", "generations", "wall (s)", "CPU (s)", "env steps", "evaluations", "final mean score"]
    return _table(header, body, "lrrrrrrr")


# ------------------------------------------------------------------------------ peers
QUICK_PEERS = (3, 100)  # --quick: seeds, generations
PEER_POPSIZE = 50
PEER_SIGMA, PEER_LR = 0.25, 0.01  # imix's defaults (conf/config.yaml): initial std, OpenES's Adam rate
PEER_IDS = {"cartpole": "CartPole-v1", "acrobot": "Acrobot-v1"}  # gymnax ids, capped at EPISODE_CAP
PEERS_INSTALL = "pip install 'imix-cli[peers]'  (jax, evosax, gymnax)"


def peers_available(echo) -> bool:
    """Whether jax, evosax and gymnax import; if not, say how to install them."""
    try:
        import evosax  # noqa: F401
        import gymnax  # noqa: F401
        import jax  # noqa: F401
    except ImportError as err:
        echo(f"The peers are not installed ({err.name or err}): {PEERS_INSTALL}")
        return False
    return True


def _peer_run(algo: str, env: str, seeds: int, generations: int) -> dict:
    """evosax ``algo`` (SNES / Open_ES) on gymnax ``env``: every generation of every seed in one
    jitted function (lax.scan over generations, vmap over seeds and members, lax.scan over the
    200 steps of an episode, as gymnax is meant to be used). Returns wall/compile seconds,
    env steps (steps before each episode's end) and the final population mean return."""
    import gymnax
    import jax
    import jax.numpy as jnp
    import optax
    from evosax.algorithms import SNES, Open_ES

    from imix_cli.policies import num_params

    environment, env_params = gymnax.make(PEER_IDS[env])
    env_params = env_params.replace(max_steps_in_episode=EPISODE_CAP)
    obs_dim = environment.observation_space(env_params).shape[0]
    n_act = environment.action_space(env_params).n
    sizes = [obs_dim, 8, 8, n_act]
    dim = num_params(obs_dim, n_act)

    def policy(flat, obs):  # imix_cli.policies' layout: W1 (in x 8), b1, W2, b2, W3, b3
        k, x = 0, obs
        for layer, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
            W, bias = flat[k : k + a * b].reshape(a, b), flat[k + a * b : k + a * b + b]
            k += a * b + b
            x = x @ W + bias
            x = jnp.tanh(x) if layer < 2 else x
        return jnp.argmax(x)

    def episode(flat, key):
        k_reset, k_step = jax.random.split(key)
        obs, state = environment.reset(k_reset, env_params)

        def step(carry, _):
            obs, state, ret, alive, n = carry
            obs, state, reward, done, _ = environment.step(k_step, state, policy(flat, obs), env_params)
            return (obs, state, ret + reward * alive, alive * (1.0 - done), n + alive.astype(jnp.int32)), None

        init = (obs, state, jnp.float32(0.0), jnp.float32(1.0), jnp.int32(0))
        (_, _, ret, _, n), _ = jax.lax.scan(step, init, None, length=EPISODE_CAP)
        return ret, n

    solution = jnp.zeros(dim)
    if algo == "snes":
        es = SNES(population_size=PEER_POPSIZE, solution=solution)
        es_params = es.default_params.replace(std_init=jnp.asarray(PEER_SIGMA))
    else:
        es = Open_ES(population_size=PEER_POPSIZE, solution=solution, optimizer=optax.adam(PEER_LR),
                     std_schedule=optax.constant_schedule(PEER_SIGMA))  # fmt: skip
        es_params = es.default_params

    def one_seed(key):
        key, k_init = jax.random.split(key)
        state = es.init(k_init, solution, es_params)

        def generation(carry, _):
            state, key = carry
            key, k_ask, k_eval, k_tell = jax.random.split(key, 4)
            population, state = es.ask(k_ask, state, es_params)
            returns, steps = jax.vmap(episode)(population, jax.random.split(k_eval, PEER_POPSIZE))
            state, _ = es.tell(k_tell, population, -returns, state, es_params)  # evosax minimises
            return (state, key), (returns.mean(), steps.sum())

        _, (mean_returns, steps) = jax.lax.scan(generation, (state, key), None, length=generations)
        return mean_returns[-1], steps.sum()

    keys = jax.random.split(jax.random.key(0), seeds)
    started = time.perf_counter()
    compiled = jax.jit(jax.vmap(one_seed)).lower(keys).compile()
    compile_seconds = time.perf_counter() - started
    final, steps = jax.block_until_ready(compiled(keys))
    wall = time.perf_counter() - started
    return {"run": f"evosax {es.__class__.__name__} + gymnax", "env": env, "eim": False, "seeds": seeds,
            "generations": generations, "wall": wall, "compile": compile_seconds,
            "env_steps": int(np.asarray(steps, dtype=np.int64).sum()), "final": float(np.mean(final))}  # fmt: skip


def _imix_run(env: str, eim: bool, seeds: int, generations: int) -> dict:
    """``imix run algo=snes env=<env> eim=<eim>`` in this process (its worker pool, all cores)."""
    from imix_cli.config import validate_overrides
    from imix_cli.runner import run

    with tempfile.TemporaryDirectory(prefix="imix-bench-peers-") as tmp:
        overrides = ["algo=snes", f"env={env}", f"eim={str(eim).lower()}", f"seeds={seeds}", f"generations={generations}",
                     "progress=false", f"results_dir={tmp}", "experiment=peers"]  # fmt: skip
        (spec,) = validate_overrides(overrides)
        started = time.perf_counter()
        summary = run(spec, echo=lambda *_: None)
        wall = time.perf_counter() - started
    return {"run": f"imix run algo=snes eim={str(eim).lower()}", "env": env, "eim": eim, "seeds": seeds,
            "generations": generations, "wall": wall, "compile": None, "env_steps": summary["env_steps"],
            "final": summary["final_mean_score"]}  # fmt: skip


def peer_rows(envs, seeds: int, generations: int, echo=None) -> list[dict]:
    """The peers and imix's SNES with and without EIM on each env, one after the other."""
    rows = []
    for env in envs:
        for fn, args in (
            (_peer_run, ("snes", env)), (_peer_run, ("openes", env)), (_imix_run, (env, True)), (_imix_run, (env, False)),
        ):  # fmt: skip
            row = fn(*args, seeds, generations)
            rows.append(row)
            if echo:
                echo(f"  {row['run']}, {env}: {row['wall']:.1f} s, {row['env_steps']:,} env steps, final {row['final']:.1f}")
    return rows


def format_peers(rows: list[dict]) -> str:
    body = [[r["run"], r["env"], r["seeds"], r["generations"], f"{r['wall']:.1f}",
             "" if r["compile"] is None else f"{r['compile']:.1f}", f"{r['env_steps']:,}", f"{r['final']:.1f}"]
            for r in rows]  # fmt: skip
    header = ["run", "env", "seeds", "generations", "wall (s)", "of which JAX compile (s)", "env steps", "final mean score"]
    return _table(header, body, "llrrrrrr")


def format_peer_ratios(rows: list[dict]) -> str:
    """imix SNES + EIM against each other row of the same env: wall time and env steps ratios."""
    body = []
    for env in dict.fromkeys(r["env"] for r in rows):
        ours = next(r for r in rows if r["env"] == env and r["run"].startswith("imix") and r["eim"])
        for other in (r for r in rows if r["env"] == env and r is not ours):
            body.append([env, f"imix SNES + EIM vs {other['run']}", f"{other['wall'] / ours['wall']:.2f}",
                         f"{other['env_steps'] / max(ours['env_steps'], 1):.1f}"])  # fmt: skip
    return _table(["env", "comparison", "× faster (wall)", "× fewer env steps"], body, "llrr")


# ------------------------------------------------------------------------------ command line
class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit status 2 (argparse would print the usage too)
        raise BenchError(message)


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 1")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 0")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="imix bench",
        description=__doc__.replace("``", "`"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n  imix bench\n  imix bench rollouts --sizes 50 250 1250\n  imix bench grid\n"
        "  imix bench all --seeds 5 --generations 50\n  imix bench peers --quick",
    )
    p.add_argument("sections", nargs="*", metavar="section", help=f"any of {', '.join(SECTIONS)}, all (default: {' '.join(DEFAULT_SECTIONS)})")
    p.add_argument("--grid", action="store_true", help="also run the grid section")
    g = p.add_argument_group("rollouts")
    g.add_argument("--sizes", type=_positive_int, nargs="+", default=[2, 50, 1250], metavar="B", help="batch sizes (default: 2 50 1250)")
    g.add_argument("--envs", nargs="+", choices=sorted(ROLLOUT_ENVS), default=["cartpole", "acrobot"], help="environments (rollouts, grid, breakdown, peers)")
    g.add_argument("--repeats", type=_positive_int, default=3, help="timed repeats per measurement (default: 3)")
    g.add_argument("--min-seconds", type=_positive_float, default=1.0, help="minimum time per batched measurement (default: 1)")
    g.add_argument("--naive-members", type=_positive_int, default=20, help="episodes of the naive loop (default: 20)")
    g = p.add_argument_group("mixing")
    g.add_argument("--dims", type=_positive_int, nargs="+", default=[130, 1_000, 100_000, 1_000_000], metavar="D", help="dimensions (default: 130 1000 100000 1000000)")
    g = p.add_argument_group("memory, breakdown, grid, peers")
    g.add_argument("--seeds", type=_positive_int, default=None, help="seeds per run (default: 25; breakdown: 13, one worker's share)")
    g.add_argument("--generations", type=_positive_int, default=None, help="generations per run (default: the paper's, per algorithm)")
    g.add_argument("--workers", type=_positive_int, default=None, help="memory run's worker processes (default: all cores)")
    g.add_argument("--quick", action="store_true", help=f"peers: {QUICK_PEERS[0]} seeds x {QUICK_PEERS[1]} generations unless --seeds/--generations say otherwise")
    g.add_argument("--algos", nargs="+", choices=["openes", "snes", "cem", "cmaes"], default=["openes", "snes", "cem", "cmaes"], help="grid and breakdown algorithms")
    return p


def parse_args(argv: list[str]) -> argparse.Namespace:
    args = build_parser().parse_args(argv)
    sections = []
    for s in args.sections:
        if s == "all":
            sections.extend(SECTIONS)
        elif s in SECTIONS:
            sections.append(s)
        else:
            raise BenchError(f"unknown section {s!r}; valid: {', '.join(SECTIONS)}, all")
    if not sections:
        sections = list(DEFAULT_SECTIONS)
    if args.grid:
        sections.append("grid")
    args.sections = list(dict.fromkeys(sections))  # unique, in order
    return args


def _machine() -> str:
    import platform

    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load = " ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "n/a"
    return f"{platform.processor() or platform.machine()}, {cpus} cores, Python {platform.python_version()}, numpy {np.__version__}, load average {load}"


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parse_args(argv)
    except BenchError as err:
        print(f"imix bench: error: {err} (see imix bench --help)", file=sys.stderr)
        return 2
    except SystemExit as exit_:  # --help
        return exit_.code if isinstance(exit_.code, int) else 0

    def echo(text=""):
        print(text, flush=True)

    echo(f"# imix bench ({time.strftime('%Y-%m-%d %H:%M')}): {_machine()}")
    echo(f"command: imix bench {' '.join(argv)}".rstrip())
    for section in args.sections:
        echo()
        started = time.perf_counter()
        if section == "rollouts":
            echo("## Rollouts: env steps per second on one core, policy included (see imix bench --help for the policies)")
            rows = rollout_rows(args.sizes, args.envs, args.repeats, args.min_seconds, args.naive_members)
            echo(format_rollouts(rows))
        elif section == "mixing":
            echo("## One importance-mixing step vs plain sampling of the same population (N = 50, K = 3)")
            echo(format_mixing(mixing_rows(args.dims, max(args.repeats, 3))))
        elif section == "memory":
            echo("## A 25-seed run: wall time and peak memory")
            seeds = args.seeds or 25
            echo(format_memory(memory_row(["algo=snes", "env=cartpole", "eim=true"], seeds, args.generations, args.workers)))
        elif section == "breakdown":
            echo("## Where a run's time goes (lockstep seeds of one worker, in-process)")
            configs = [[f"algo={a}", f"env={e}", "eim=true"] for e in args.envs for a in args.algos]
            echo(format_breakdown(breakdown_rows(configs, args.seeds or 13, args.generations)))
        elif section == "peers":
            seeds = args.seeds or (QUICK_PEERS[0] if args.quick else 25)
            generations = args.generations or (QUICK_PEERS[1] if args.quick else 1000)
            echo(f"## Peers: evosax + gymnax (JAX, jitted, no mixing) vs imix, {seeds} seeds x {generations} generations, pop 50")
            if not peers_available(echo):
                echo(f"({section}: skipped)")
                continue
            rows = peer_rows(args.envs, seeds, generations, echo=echo)
            echo(format_peers(rows))
            echo()
            echo("## Ratios: imix SNES + EIM against each other run on the same env")
            echo(format_peer_ratios(rows))
        elif section == "grid":
            echo("## The paper's main grid (as `make reproduce`), without mixing and with EIM")
            extra = [o for o in PAPER_GRID if not o.startswith(("algo=", "env="))]
            echo(format_grid(grid_rows(args.seeds, args.generations, args.algos, args.envs, extra, echo=echo)))
        echo(f"({section}: {time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
