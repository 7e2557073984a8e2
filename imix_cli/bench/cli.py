"""``imix bench [section ...] [key=value ...]``: the command line of the benchmarks (see :mod:`imix_cli.bench`).

Sections are words, settings ``key=value`` (lists comma-separated), as every imix command takes them
(:mod:`imix_cli.keyvalue`); a bad one is one line naming it, exit status 2.
"""

from __future__ import annotations

import os
import sys
import time
from types import SimpleNamespace

import numpy as np

from imix_cli.bench.breakdown import breakdown_rows, format_breakdown
from imix_cli.bench.common import ROLLOUT_ENVS
from imix_cli.bench.grid import PAPER_GRID, format_grid, grid_rows
from imix_cli.bench.loop import LOOP_CONFIGS, format_loop, loop_rows
from imix_cli.bench.memory import format_memory, memory_row
from imix_cli.bench.mixing import format_mixing, mixing_rows
from imix_cli.bench.mujoco import MUJOCO_BENCH_ENVS, format_mujoco, mujoco_rows
from imix_cli.bench.peers import QUICK_PEERS, format_peer_ratios, format_peers, peer_rows, peers_available
from imix_cli.bench.rollouts import format_rollouts, rollout_rows
from imix_cli.core.registry import ALGORITHM_SPECS, ES_NAMES, MAIN_GRID_ENVS, MUJOCO_ENVS, PAPER_ES_NAMES
from imix_cli.keyvalue import UsageError, at_least, flag, help_requested, parse_key_values

#: The body of ``imix bench --help``: the sections and what each measures.
HELP = """``imix bench``: speed benchmarks, each next to its baseline measured in the same run.

Sections (give any of them; default ``rollouts mixing memory``; ``all`` runs every one)::

    rollouts   env-steps/s of imix's evaluator (imix_cli.core.evaluation.make_evaluator: compiled
               episodes, policy included) for CartPole and Acrobot at several batch sizes (2: what
               importance mixing leaves fresh per seed; 50: one population), next to a naive loop
               (gymnasium.make + numpy MLP per step, one episode at a time) and gymnasium's
               SyncVectorEnv stepping the same batched numpy policy; ratios of the three.
    mixing     one importance-mixing step (paper, exact, sun2009) against plain sampling of the
               same population (N = 50, K = 3), d = 130 (the paper's CartPole) to 10^6.
    memory     wall time, CPU time and peak RSS (VmHWM) of `imix run algo=snes env=cartpole
               eim=true seeds=25` in a subprocess: its main process and its worker processes.
    breakdown  where a run's time goes: evaluation, mixing (or plain sampling) and ES update
               of a lockstep run in this process (seeds of one worker, paper dimensions).
    loop       the compiled generation loop (imix_cli.running.loop.compiled_loop) against the Python loop it
               reproduces: the same seeds of SNES + EIM, OpenES + EIM, SNES without mixing and
               ARS + EIM on CartPole, in this process; time per seed-generation, ratio, and whether the rows
               are the same (13 seeds x 300 generations unless seeds=/generations=).
    grid       wall time and total env steps of the paper's main grid (4 ES x CartPole,
               Acrobot x 25 seeds at the paper's generation counts), with EIM and without
               mixing, through imix_cli.running.runner.run into a temporary folder. Takes minutes.
    peers      the same task in a peer library, in this run: evosax SNES and OpenES + gymnax
               CartPole-v1 / Acrobot-v1 (both capped at 200 steps), the same 8-8 tanh MLP, pop 50,
               no mixing, the whole loop jitted with the seeds vmapped (JAX on CPU); next to
               `imix run algo=snes env=<env> eim=true` and `eim=false` (in this process, all
               cores, a temporary results folder), and on the first env `imix run ... eim=true`
               as a user's first run (a new process with an empty numba cache: every kernel is
               compiled). Wall times (compile included: JAX's shown, and imix's first run's
               extra over the warm run), env steps, final scores and ratios. Default 25 seeds x
               1000 generations (minutes); quick=true: 3 x 100. Needs the `peers` extra
               (pip install ".[peers]" from the imix clone); without it the section says so and exits 0.
    mujoco     imix's cost per env step on HalfCheetah-v5 and Hopper-v5 (linear policy, no mixing,
               pool evaluator with one worker: the evaluator on fixed policies, and a short
               `imix run`) against a plain gymnasium loop over the same policies and seeds, and
               the share of that loop spent in MuJoCo's mj_step (the floor of any path that
               reproduces gymnasium's episodes). Pairwise ratios. Needs the `mujoco` extra.

Policies of the rollout benchmark (fixed, so episodes have realistic lengths): CartPole, a
hand-built balancing controller written as an MLP (action = sign of 2 theta + 0.5 theta_dot
+ 0.3 x_dot + 0.1 x through one tanh unit per layer) plus N(0, 0.1^2) noise on every parameter
(numpy seed 0): a late-training population, mean episode ~190 steps. Acrobot, random
N(0, 0.5^2) parameters (seed 0): an early-training population, mean episode ~195 steps of
the 200-step cap. Episode seeds 0..B-1.

Timings are medians of repeats; the machine may be shared, so compare the ratios (measured
in the same run) rather than absolute numbers across runs. Exit status 2 on bad arguments.
"""

SECTIONS = ("rollouts", "mixing", "memory", "breakdown", "loop", "grid", "peers", "mujoco")
DEFAULT_SECTIONS = ("rollouts", "mixing", "memory")


def _positive_ints(key: str, value: str) -> list[int]:
    return [at_least(1)(key, part) for part in value.split(",")]


def _some_of(*choices: str):
    def check(key: str, value: str) -> list[str]:
        names = value.split(",")
        bad = [name for name in names if name not in choices]
        if bad:
            raise UsageError(f"bad value for {key}: {bad[0]!r} (expected a comma-separated list of {', '.join(choices)})")
        return list(dict.fromkeys(names))

    return check


def _seconds(key: str, value: str) -> float:
    try:
        number = float(value)
    except ValueError:
        number = float("nan")
    if not 0.0 <= number < float("inf"):
        raise UsageError(f"bad value for {key}: {value!r} (expected a number >= 0)")
    return number


#: Every key: its default, its check (what it converts to) and its line in ``--help``.
KEYS = {
    "sizes": ([2, 50, 1250], _positive_ints, "rollouts: batch sizes"),
    "envs": (list(MAIN_GRID_ENVS), _some_of(*sorted(ROLLOUT_ENVS)), "rollouts, grid, breakdown, peers: environments"),
    "repeats": (3, at_least(1), "timed repeats per measurement"),
    "min_seconds": (1.0, _seconds, "rollouts: minimum time per batched measurement"),
    "naive_members": (20, at_least(1), "rollouts: episodes of the naive loop"),
    "dims": ([130, 1_000, 10_000, 100_000, 1_000_000], _positive_ints, "mixing: dimensions"),
    "seeds": (None, at_least(1), "seeds per run (default: 25; breakdown and loop: 13, one worker's share)"),
    "generations": (None, at_least(1), "generations per run (default: the paper's, per algorithm; loop: 300)"),
    "workers": (None, at_least(1), "memory: the run's worker processes (default: all cores)"),
    "quick": (False, flag, f"peers: {QUICK_PEERS[0]} seeds x {QUICK_PEERS[1]} generations unless seeds=/generations= say otherwise"),
    "algos": (list(PAPER_ES_NAMES), _some_of(*ES_NAMES), f"grid and breakdown: algorithms, any of {', '.join(ES_NAMES)}"),
    "mujoco_envs": (list(MUJOCO_BENCH_ENVS), _some_of(*sorted(MUJOCO_ENVS)), f"mujoco: environments, any of {', '.join(sorted(MUJOCO_ENVS))}"),
    "popsize": (50, at_least(1), "mujoco: policies per measurement and the run's popsize"),
}


def _shown(value) -> str:
    if isinstance(value, list):
        return ",".join(map(str, value))
    return "N" if value is None else str(value).lower() if isinstance(value, bool) else str(value)


def help_text() -> str:
    keys = "\n".join(f"  {f'{key}={_shown(default)}':<40} {text}" for key, (default, _, text) in KEYS.items())
    return (
        f"usage: imix bench [section ...] [key=value ...]\n\n{HELP.replace('``', '`')}\n"
        f"sections: {', '.join(SECTIONS)}, all (default: {' '.join(DEFAULT_SECTIONS)})\n\n"
        f"keys (lists comma-separated; the defaults shown):\n{keys}\n\n"
        "examples:\n  imix bench\n  imix bench rollouts sizes=50,250,1250\n  imix bench grid\n"
        "  imix bench all seeds=5 generations=50\n  imix bench peers envs=cartpole quick=true\n  imix bench loop seeds=5\n"
    )


def parse_args(argv: list[str]) -> SimpleNamespace:
    """Section words and ``key=value`` settings -> the settings (``sections``: the sections to run, in order).
    :class:`~imix_cli.keyvalue.UsageError` naming the bad argument."""
    sections, settings = [], []
    for arg in argv:
        if "=" in arg:
            settings.append(arg)
        elif arg.startswith("-"):
            key = arg.lstrip("-").replace("-", "_")
            hint = f", e.g. {key}=..." if key in KEYS else f"; sections are words, e.g. {key}" if key in SECTIONS else ""
            raise UsageError(f"unknown argument {arg!r}: settings are key=value{hint} (see imix bench --help)")
        elif arg == "all":
            sections.extend(SECTIONS)
        elif arg in SECTIONS:
            sections.append(arg)
        else:
            raise UsageError(f"unknown section {arg!r}; valid: {', '.join(SECTIONS)}, all")
    defaults = {key: default for key, (default, _, _) in KEYS.items()}
    args = parse_key_values(settings, "bench", defaults, convert={key: check for key, (_, check, _) in KEYS.items()})
    return SimpleNamespace(sections=list(dict.fromkeys(sections or DEFAULT_SECTIONS)), **args)  # unique, in order


def _machine() -> str:
    import platform

    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    load = " ".join(f"{x:.2f}" for x in os.getloadavg()) if hasattr(os, "getloadavg") else "n/a"
    return f"{platform.processor() or platform.machine()}, {cpus} cores, Python {platform.python_version()}, numpy {np.__version__}, load average {load}"


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if help_requested(argv, help_text):
        return 0
    try:
        args = parse_args(argv)
    except UsageError as err:
        print(f"imix bench: {err}", file=sys.stderr)
        return 2

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
        elif section == "loop":
            echo("## The compiled generation loop against the Python loop (the same seeds, in-process)")
            echo(format_loop(loop_rows(LOOP_CONFIGS, args.seeds or 13, args.generations or 300)))
        elif section == "peers":
            seeds = args.seeds or (QUICK_PEERS[0] if args.quick else 25)
            generations = args.generations or (QUICK_PEERS[1] if args.quick else ALGORITHM_SPECS["snes"].generations)
            echo(f"## Peers: evosax + gymnax (JAX, jitted, no mixing) vs imix, {seeds} seeds x {generations} generations, pop 50")
            if not peers_available(echo):
                echo(f"({section}: skipped)")
                continue
            rows = peer_rows(args.envs, seeds, generations, echo=echo)
            echo(format_peers(rows))
            echo()
            echo("## Ratios: imix SNES + EIM against each other run on the same env")
            echo(format_peer_ratios(rows))
        elif section == "mujoco":
            echo("## MuJoCo: imix's cost per env step against a plain gymnasium loop (linear policy, no mixing, pool evaluator, 1 worker)")
            import importlib.util

            if importlib.util.find_spec("mujoco") is None:
                from imix_cli.core.evaluation import MUJOCO_EXTRA_HINT

                echo(f"(mujoco: skipped, the mujoco package is not installed: {MUJOCO_EXTRA_HINT})")
                continue
            gens = max(args.generations or 5, 2)
            rows = mujoco_rows(args.mujoco_envs, args.popsize, args.repeats, gens, echo=echo)
            echo(format_mujoco(rows))
            echo(f"(ratios: medians over {args.repeats} pairs; imix run: {gens} generations of popsize {args.popsize})")
        elif section == "grid":
            echo("## The paper's main grid (as `make reproduce`), without mixing and with EIM")
            extra = [o for o in PAPER_GRID if not o.startswith(("algo=", "env="))]
            echo(format_grid(grid_rows(args.seeds, args.generations, args.algos, args.envs, extra, echo=echo)))
        echo(f"({section}: {time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
