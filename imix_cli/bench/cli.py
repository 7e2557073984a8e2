"""``imix bench [section ...] [--options]``: the command line of the benchmarks (see :mod:`imix_cli.bench`)."""

from __future__ import annotations

import argparse
import os
import sys
import time

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
from imix_cli.registry import ALGORITHM_SPECS, ES_NAMES, MAIN_GRID_ENVS, MUJOCO_ENVS, PAPER_ES_NAMES

SECTIONS = ("rollouts", "mixing", "memory", "breakdown", "loop", "grid", "peers", "mujoco")
DEFAULT_SECTIONS = ("rollouts", "mixing", "memory")


class BenchError(ValueError):
    """Bad arguments: one line, exit status 2."""


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
        description=_package.__doc__.replace("``", "`"),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples (key=value, as every imix command, or --key value):\n  imix bench\n  imix bench rollouts sizes=50,250,1250\n"
        "  imix bench grid\n  imix bench all seeds=5 generations=50\n  imix bench peers quick=true\n  imix bench loop --seeds 5",
    )
    p.add_argument("sections", nargs="*", metavar="section", help=f"any of {', '.join(SECTIONS)}, all (default: {' '.join(DEFAULT_SECTIONS)})")
    p.add_argument("--grid", action="store_true", help="also run the grid section")
    g = p.add_argument_group("rollouts")
    g.add_argument("--sizes", type=_positive_int, nargs="+", default=[2, 50, 1250], metavar="B", help="batch sizes (default: 2 50 1250)")
    g.add_argument("--envs", nargs="+", choices=sorted(ROLLOUT_ENVS), default=list(MAIN_GRID_ENVS), help="environments (rollouts, grid, breakdown, peers)")
    g.add_argument("--repeats", type=_positive_int, default=3, help="timed repeats per measurement (default: 3)")
    g.add_argument("--min-seconds", type=_positive_float, default=1.0, help="minimum time per batched measurement (default: 1)")
    g.add_argument("--naive-members", type=_positive_int, default=20, help="episodes of the naive loop (default: 20)")
    g = p.add_argument_group("mixing")
    g.add_argument(
        "--dims",
        type=_positive_int,
        nargs="+",
        default=[130, 1_000, 10_000, 100_000, 1_000_000],
        metavar="D",
        help="dimensions (default: 130 1000 100000 1000000)",
    )
    g = p.add_argument_group("memory, breakdown, grid, peers")
    g.add_argument("--seeds", type=_positive_int, default=None, help="seeds per run (default: 25; breakdown and loop: 13, one worker's share)")
    g.add_argument("--generations", type=_positive_int, default=None, help="generations per run (default: the paper's, per algorithm)")
    g.add_argument("--workers", type=_positive_int, default=None, help="memory run's worker processes (default: all cores)")
    g.add_argument(
        "--quick", action="store_true", help=f"peers: {QUICK_PEERS[0]} seeds x {QUICK_PEERS[1]} generations unless --seeds/--generations say otherwise"
    )
    g.add_argument("--algos", nargs="+", choices=ES_NAMES, default=list(PAPER_ES_NAMES), help="grid and breakdown algorithms")
    g = p.add_argument_group("mujoco")
    g.add_argument("--mujoco-envs", nargs="+", choices=sorted(MUJOCO_ENVS), default=list(MUJOCO_BENCH_ENVS), help="environments (default: halfcheetah hopper)")
    g.add_argument("--popsize", type=_positive_int, default=50, help="mujoco: policies per measurement and the run's popsize (default: 50)")
    return p


def _options_from_key_values(parser: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """``key=value`` arguments (every imix command's style) as the options they name: ``seeds=5`` is
    ``--seeds 5``, ``envs=cartpole,acrobot`` is ``--envs cartpole acrobot``, ``quick=true`` is
    ``--quick``; other arguments (sections, ``--options``) are kept. BenchError for an unknown key."""
    actions = {a.dest: a for a in parser._actions if a.option_strings and a.dest != "help"}
    out = []
    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            out.append(arg)
            continue
        key, value = arg.split("=", 1)
        action = actions.get(key.replace("-", "_"))
        if action is None:
            raise BenchError(f"unknown key {key!r}; valid keys: {', '.join(sorted(actions))}")
        option = action.option_strings[-1]
        if action.nargs == 0:  # a flag
            if value.lower() not in ("true", "false"):
                raise BenchError(f"{key}={value}: must be true or false")
            out += [option] if value.lower() == "true" else []
        elif action.nargs == "+":
            out += [option, *[v for v in value.split(",") if v]]
        else:
            out += [option, value]
    return out


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = build_parser()
    args = parser.parse_args(_options_from_key_values(parser, argv))
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
