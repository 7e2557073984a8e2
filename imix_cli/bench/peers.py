"""``imix bench peers``: evosax + gymnax (JAX, jitted, no mixing) against ``imix run`` on the same task."""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from functools import partial

import numpy as np

from imix_cli.bench.common import EPISODE_CAP, table
from imix_cli.core.algorithms.base import Params
from imix_cli.messages import install_extra

QUICK_PEERS = (3, 100)  # --quick: seeds, generations
# imix's defaults (the paper's): population size, initial std, Adam's learning rate
PEER_POPSIZE, PEER_SIGMA, PEER_LR = Params.popsize, Params.sigma, Params.lr
PEER_IDS = {"cartpole": "CartPole-v1", "acrobot": "Acrobot-v1"}  # gymnax ids, capped at EPISODE_CAP
PEERS_INSTALL = install_extra("peers") + "  (jax, evosax, gymnax)"


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


def gymnax_episode(env: str):
    """``(episode, dim)`` for gymnax ``env`` (a key of :data:`PEER_IDS`): ``episode(flat, key)`` plays one
    episode of at most EPISODE_CAP steps with imix's policy (:mod:`imix_cli.core.evaluation.policies`: two tanh layers of 8,
    argmax over actions) of parameters ``flat`` and returns ``(return, steps)``; ``dim`` is the parameter count.
    Pure JAX, to be vmapped and jitted by the caller (``imix bench peers``, ``benchmarks/adapters.py``)."""
    import gymnax
    import jax
    import jax.numpy as jnp

    from imix_cli.core.evaluation.policies import num_params

    environment, env_params = gymnax.make(PEER_IDS[env])
    env_params = env_params.replace(max_steps_in_episode=EPISODE_CAP)
    obs_dim = environment.observation_space(env_params).shape[0]
    n_act = environment.action_space(env_params).n
    sizes = [obs_dim, 8, 8, n_act]

    def policy(flat, obs):  # imix_cli.core.evaluation.policies' layout: W1 (in x 8), b1, W2, b2, W3, b3
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

    return episode, num_params(obs_dim, n_act)


def _peer_run(algo: str, env: str, seeds: int, generations: int) -> dict:
    """evosax ``algo`` (SNES / Open_ES) on gymnax ``env``: every generation of every seed in one
    jitted function (lax.scan over generations, vmap over seeds and members, lax.scan over the
    200 steps of an episode, as gymnax is meant to be used). Returns wall/compile seconds,
    env steps (steps before each episode's end) and the final population mean return."""
    import jax
    import jax.numpy as jnp
    import optax
    from evosax.algorithms import SNES, Open_ES

    episode, dim = gymnax_episode(env)
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


def _imix_overrides(env: str, eim: bool, seeds: int, generations: int, results_dir: str, extra: tuple = ()) -> list[str]:
    return ["algo=snes", f"env={env}", f"eim={str(eim).lower()}", f"seeds={seeds}", f"generations={generations}",
            "progress=false", f"results_dir={results_dir}", "experiment=peers", *extra]  # fmt: skip


def _worker_server_ready() -> None:
    """Start the seed workers' fork server in this process and wait until it has imported what it preloads (a child forked
    from it has run). Why: the first in-process row started the server inside its timing, ~1 s of start-up that nothing
    overlapped, so the run "itself" took longer than the whole process (5.1 s against 4.2 s, the row after it 4.3 s);
    the whole process's row has that start-up, beside its own imports."""
    from imix_cli.core.processes import seed_worker_context
    from imix_cli.running.pool import SEED_WORKER_MODULES

    child = seed_worker_context(SEED_WORKER_MODULES).Process(target=int)
    child.start()
    child.join()


def _imix_run(env: str, eim: bool, seeds: int, generations: int, extra: tuple = (), label: str | None = None) -> dict:
    """``imix run algo=snes env=<env> eim=<eim> [extra]`` in this process (its worker pool, all cores).
    ``label``: the row's name in the ratios, for the runs compared with the others (imix SNES + EIM)."""
    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.runner import run

    with tempfile.TemporaryDirectory(prefix="imix-bench-peers-") as tmp:
        (spec,) = validate_overrides(_imix_overrides(env, eim, seeds, generations, tmp, extra))
        _worker_server_ready()
        started = time.perf_counter()
        summary = run(spec, echo=lambda *_: None)
        wall = time.perf_counter() - started
    row = {"run": " ".join([f"imix run algo=snes eim={str(eim).lower()}", *extra]), "env": env, "eim": eim, "seeds": seeds,
           "generations": generations, "wall": wall, "compile": None, "env_steps": summary["env_steps"],
           "final": summary["final_mean_score"]}  # fmt: skip
    if label is not None:
        row["label"] = label
    return row


def _imix_process(env: str, seeds: int, generations: int, numba_cache: str | None) -> tuple[float, dict]:
    """``imix run algo=snes env=<env> eim=true`` as a user types it: a new process (``python -m imix_cli.commands.cli``),
    timed from its start to its exit; ``numba_cache``: a folder for ``NUMBA_CACHE_DIR`` (empty: every kernel compiled),
    or None (imix's own cache, warm after the runs before). Returns (wall seconds, the run's summary)."""
    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.summary import summarize

    with tempfile.TemporaryDirectory(prefix="imix-bench-peers-") as tmp:
        overrides = _imix_overrides(env, True, seeds, generations, os.path.join(tmp, "results"))
        environ = {**os.environ, **({"NUMBA_CACHE_DIR": os.path.join(tmp, numba_cache)} if numba_cache else {})}
        started = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "imix_cli.commands.cli", "run", *overrides], env=environ, capture_output=True, text=True)
        wall = time.perf_counter() - started
        if done.returncode != 0:
            raise RuntimeError(f"imix run (a new process) failed: {(done.stderr or done.stdout).strip().splitlines()[-1:]}")
        (spec,) = validate_overrides(overrides)
        return wall, summarize(spec)


def _imix_first_run(env: str, seeds: int, generations: int) -> dict:
    """``imix run algo=snes env=<env> eim=true`` as a user's first run: a new process with an empty numba cache, so
    every kernel it needs is compiled, in each worker, before it runs. Its ``compile`` is filled in by
    :func:`peer_rows`: this wall time minus the same run's in-process with the cache warm (start-up included)."""
    wall, summary = _imix_process(env, seeds, generations, "numba-cache")
    return {"run": "imix run algo=snes eim=true, first run (empty numba cache)", "env": env, "eim": True, "first_run": True,
            "label": "imix SNES + EIM, first run",
            "seeds": seeds, "generations": generations, "wall": wall, "compile": None, "env_steps": summary["env_steps"],
            "final": summary["final_mean_score"]}  # fmt: skip


#: Runs of the whole process, whose median the row gives: one run of a few seconds moved by 15 % between two
#: `imix bench peers` runs on the same VM (3.4 and 3.9 s), more than a change worth measuring.
WHOLE_PROCESS_RUNS = 3


def _imix_whole_process(env: str, seeds: int, generations: int) -> dict:
    """``imix run algo=snes env=<env> eim=true`` in a new process with the numba cache warm, start to exit: what a
    user waits for at the terminal (Python's start-up, imports, the cache's loading, the worker pool included); the
    median of :data:`WHOLE_PROCESS_RUNS` runs, each named in the row."""
    walls = []
    for _ in range(WHOLE_PROCESS_RUNS):
        wall, summary = _imix_process(env, seeds, generations, None)
        walls.append(wall)
    wall = statistics.median(walls)
    every = ", ".join(f"{w:.1f}" for w in walls)
    return {"run": f"imix run algo=snes eim=true, the whole process (cache warm), median of {every} s", "env": env, "eim": True,
            "label": "imix SNES + EIM, the whole process",
            "seeds": seeds, "generations": generations, "wall": wall, "compile": None, "env_steps": summary["env_steps"],
            "final": summary["final_mean_score"]}  # fmt: skip


def peer_rows(envs, seeds: int, generations: int, echo=None) -> list[dict]:
    """The peers and imix's SNES with and without EIM on each env, one after the other: on every
    env imix SNES + EIM in-process and as a whole new process (start to exit, cache warm); on the
    first env also as a first run (numba compiling), whose extra wall time over
    the warm run is its ``compile``, and with a checkpoint every ``checkpoint_every`` generations whatever
    the time (``checkpoint_seconds=0``, the default before checkpoint_seconds existed: 500 checkpoints)."""
    rows = []
    for number, env in enumerate(envs):
        runs = [partial(_peer_run, "snes", env), partial(_peer_run, "openes", env)]
        runs += [partial(_imix_first_run, env)] if number == 0 else []
        runs += [partial(_imix_run, env, True, label="imix SNES + EIM"), partial(_imix_whole_process, env)]
        # a checkpoint (and live CSV) every 50 generations, however short they are: what that costs of the wall time
        runs += (
            [partial(_imix_run, env, True, extra=("checkpoint_seconds=0",), label="imix SNES + EIM, checkpoints every 50 generations")] if number == 0 else []
        )
        runs += [partial(_imix_run, env, False)]
        for run in runs:
            row = run(seeds=seeds, generations=generations)
            rows.append(row)
            if echo:
                echo(f"  {row['run']}, {env}: {row['wall']:.1f} s, {row['env_steps']:,} env steps, final {row['final']:.1f}")
        first = [r for r in rows if r.get("first_run") and r["env"] == env]
        if first:
            warm = next(r for r in rows if r["env"] == env and r.get("label") == "imix SNES + EIM")
            first[0]["compile"] = first[0]["wall"] - warm["wall"]
    return rows


def format_peers(rows: list[dict]) -> str:
    body = [[r["run"], r["env"], r["seeds"], r["generations"], f"{r['wall']:.1f}",
             "" if r["compile"] is None else f"{r['compile']:.1f}", f"{r['env_steps']:,}", f"{r['final']:.1f}"]
            for r in rows]  # fmt: skip
    # compile: JAX's lower().compile() of the whole loop; for imix's first run, its wall time minus the
    # warm run's (numba compiling into an empty cache, and a new process's start-up)
    header = ["run", "env", "seeds", "generations", "wall (s)", "of which compile (s)", "env steps", "final mean score"]
    return table(header, body, "llrrrrrr")


def _ratio(x: float) -> str:
    return f"{x:.2f}" if x >= 0.1 else f"{x:.2g}"  # a tiny test run against a first run's compile: not 0.00


def format_peer_ratios(rows: list[dict]) -> str:
    """imix SNES + EIM (in-process with the cache warm, the whole process; where there are, a first run and checkpoints) against
    every other row of the same env: wall time and env steps ratios."""
    body = []
    for env in dict.fromkeys(r["env"] for r in rows):
        mine = [r for r in rows if r["env"] == env and "label" in r]
        for ours in mine:
            for other in (r for r in rows if r["env"] == env and r not in mine):
                body.append([env, f"{ours['label']} vs {other['run']}", _ratio(other["wall"] / ours["wall"]),
                             f"{other['env_steps'] / max(ours['env_steps'], 1):.1f}"])  # fmt: skip
    return table(["env", "comparison", "× faster (wall)", "× fewer env steps"], body, "llrr")
