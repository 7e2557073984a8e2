"""``imix bench [section ...] [key=value ...]``: the command line of the benchmarks (see :mod:`imix_cli.bench`).

Sections are words, settings ``key=value`` (lists comma-separated), as every imix command takes them
(:mod:`imix_cli.commands.keyvalue`); a bad one is one line naming it, exit status 2.
"""

from __future__ import annotations

import os
import sys
import time
from types import SimpleNamespace

import numpy as np

import imix_cli.bench as _package
from imix_cli.bench.breakdown import breakdown_rows, format_breakdown
from imix_cli.bench.common import ROLLOUT_ENVS
from imix_cli.bench.grid import PAPER_GRID, format_grid, grid_rows
from imix_cli.bench.loop import LOOP_CONFIGS, format_loop, loop_rows
from imix_cli.bench.memory import format_memory, memory_row
from imix_cli.bench.mixing import format_mixing, mixing_rows
from imix_cli.bench.mujoco import MUJOCO_BENCH_ENVS, format_mujoco, mujoco_rows
from imix_cli.bench.peers import QUICK_PEERS, format_peer_ratios, format_peers, peer_rows, peers_available
from imix_cli.bench.rollouts import format_rollouts, rollout_rows
from imix_cli.commands.keyvalue import UsageError, at_least, flag, help_requested, parse_key_values
from imix_cli.registry import ALGORITHM_SPECS, ES_NAMES, MAIN_GRID_ENVS, MUJOCO_ENVS, PAPER_ES_NAMES

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
        f"usage: imix bench [section ...] [key=value ...]\n\n{_package.__doc__.replace('``', '`')}\n"
        f"sections: {', '.join(SECTIONS)}, all (default: {' '.join(DEFAULT_SECTIONS)})\n\n"
        f"keys (lists comma-separated; the defaults shown):\n{keys}\n\n"
        "examples:\n  imix bench\n  imix bench rollouts sizes=50,250,1250\n  imix bench grid\n"
        "  imix bench all seeds=5 generations=50\n  imix bench peers envs=cartpole quick=true\n  imix bench loop seeds=5\n"
    )


def parse_args(argv: list[str]) -> SimpleNamespace:
    """Section words and ``key=value`` settings -> the settings (``sections``: the sections to run, in order).
    :class:`~imix_cli.commands.keyvalue.UsageError` naming the bad argument."""
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
                from imix_cli.evaluation import MUJOCO_EXTRA_HINT

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
