"""``imix run | plot | bench | eval | render | status``: a thin dispatcher, nothing else.

Hydra has no subcommands, so ``main`` takes the subcommand off the command line and hands the
rest to the right entry point: ``run`` to a ``@hydra.main`` function (so ``-m``, sweepers,
launchers, ``--cfg`` and ``--help`` keep working), ``plot`` to :mod:`imix_cli.plotting`,
``bench`` to :mod:`imix_cli.bench`. Before Hydra starts, every point of the command line is
composed and validated, so bad input gives one line and exit status 2 before anything runs.
"""

from __future__ import annotations

import atexit
import os
import signal
import sys
import threading
from concurrent.futures.process import BrokenProcessPool

from imix_cli.commands.boundary import Terminated, guard, report, take_debug_flag  # Terminated: SIGTERM as a Ctrl-C
from imix_cli.messages import bounded_line

USAGE = """\
usage: imix <command> [arguments]

Evolution strategies with importance mixing (Pourchot, Perrin & Sigaud 2018).

commands:
  run     run an experiment: 25 seeds of one config in parallel, one CSV per seed
            imix run algo=snes env=cartpole eim=true
            imix run algo=cmaes env=acrobot im=true seeds=5 generations=100 experiment=try
            imix run -m algo=openes,snes,cem,cmaes env=cartpole,acrobot eim=false,true experiment=paper
          `imix run --help` lists every key.
  plot    draw the paper's figures and tables from the CSVs of an experiment
            imix plot experiment=try
          `imix plot --help` lists its keys (experiment=paper after `make reproduce`).
  bench   print the speed benchmarks (batched rollouts, mixing, a grid)
            imix bench
            imix bench loop seeds=5
          `imix bench --help` lists its sections and keys.
  eval    evaluate the saved policies of every seed on fresh episodes; writes eval.csv per run
            imix eval experiment=try episodes=100 which=mean
  render  write a GIF (or .mp4 with ffmpeg) of one saved policy acting in its env
            imix render experiment=try run=cmaes-acrobot-im seed=0 out=policy.gif
  status  seeds done / running / stopped / not started of each run, last generation, scores (read-only)
            imix status experiment=try

Results go to results/<experiment>/<algo>-<env>-<mixing>[-<overrides>]/seed_<k>.csv.
`imix --version` prints the version.
"""

COMMANDS = ("run", "plot", "bench", "eval", "render", "status")
# Flags that ask Hydra for information only: no validation, no run.
_HYDRA_INFO_FLAGS = ("--help", "-h", "--hydra-help", "--cfg", "-c", "--info", "-i", "--resolve", "--package", "-p", "--version", "--shell-completion", "-sc")

# Hydra's other long flags; any other `--x` is a key given the argparse way.
_HYDRA_RUN_FLAGS = ("--multirun", "--run", "--config-path", "--config-name", "--config-dir", "--experimental-rerun")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(USAGE, end="")
        return 0
    if argv[0] in ("--version", "-V", "version"):
        from imix_cli import __version__

        print(f"imix {__version__}")
        return 0
    command, rest = argv[0], take_debug_flag(argv[1:])
    if command == "run":
        try:
            return run_command(rest)
        except KeyboardInterrupt as stop:  # during validation or Hydra's start-up (the run itself reports its own)
            print(TERMINATED if isinstance(stop, Terminated) else INTERRUPTED, file=sys.stderr)
            return 143 if isinstance(stop, Terminated) else 130
        except BaseException as err:  # noqa: BLE001 - the one boundary (imix_cli.commands.boundary): one line
            if isinstance(err, SystemExit):
                raise
            return report("run", err)
    if command in COMMANDS:  # imix_cli's early Ctrl-C/SIGTERM handler (see imix_cli/__init__.py) is for `imix run` only
        return guard(command, lambda: _dispatch(command, rest))
    print(f"imix: unknown command {command!r}; valid commands: {', '.join(COMMANDS)} (see imix --help)", file=sys.stderr)
    return 2


def entry() -> None:
    """The ``imix`` command (its console script): :func:`main`, then the process ends as Python ends it -- threads
    finished, ``atexit`` hooks run (a tracker's, logging's, multiprocessing's), streams flushed -- but for the teardown
    of every module, which the exit status does not depend on. Why: tearing down numba, scipy, Hydra and the rest took
    the main job's process ~0.2 s after its summary was printed (4 % of it), as it took each worker
    (:func:`imix_cli.running.pool._exit_without_teardown`). A thread still running (none after a run) gets the
    interpreter's own exit, which waits for it. :func:`main` itself returns, for callers in a Python of their own."""
    try:
        code = main()
    except SystemExit as stop:
        code = stop.code
    if any(t is not threading.main_thread() and not t.daemon and t.is_alive() for t in threading.enumerate()):
        sys.exit(code)
    atexit._run_exitfuncs()
    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:  # as Python's exit: SystemExit("message") prints the message, status 1
        print(code, file=sys.stderr)
        status = 1
    from imix_cli.core.processes import exit_without_teardown  # loaded already: the imix script loads it first

    exit_without_teardown(status)


def _dispatch(command: str, rest: list) -> int:
    if command == "plot":
        from imix_cli.plotting import main as plot_main

        return plot_main(rest)
    if command == "bench":
        from imix_cli.bench import main as bench_main

        return bench_main(rest)
    if command == "eval":
        from imix_cli.commands.eval_command import main as eval_main

        return eval_main(rest)
    if command == "render":
        from imix_cli.commands.render import main as render_main

        return render_main(rest)
    if command == "status":
        from imix_cli.commands.status import main as status_main

        return status_main(rest)
    raise AssertionError(command)


INTERRUPTED = "imix run: interrupted; re-run the same command to resume (finished seeds and checkpoints are kept)"
TERMINATED = "imix run: terminated (SIGTERM); re-run the same command to resume (finished seeds and checkpoints are kept)"


def _raise_terminated(signum, frame) -> None:
    raise Terminated()


def _interrupted_before_anything_is_written(signum, frame) -> None:
    print(TERMINATED if signum == signal.SIGTERM else INTERRUPTED, file=sys.stderr, flush=True)
    os._exit(128 + signum)


def _run_handles_signals() -> None:
    """From here the run handles Ctrl-C (a KeyboardInterrupt) and SIGTERM (:class:`Terminated`) itself:
    it stops its worker pools and keeps finished seeds and checkpoints."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _raise_terminated)


#: Sweep points of this process's ``imix run -m`` refused by their run folder (in use by another run,
#: say): the others still run, and these are reported at the end, one line each, with exit status 1.
_SKIPPED_POINTS: list[str] = []
#: The RunSpecs that :func:`run_command` validated up front, by :func:`imix_cli.running.config.compose.point_key`: the Hydra task
#: takes its point's from here, so each point is validated once. A task run in another process (a launcher such
#: as joblib) finds none there and validates its point itself.
_VALIDATED: dict = {}
_SWEEPS_STARTED = 0
_POINTS_DONE = 0  # points of this process's sweep run so far (their one-line reports count them)


def _error(message: str, code: int) -> int:
    print(bounded_line(f"imix run: error: {message}"), file=sys.stderr)
    return code


def run_command(args: list[str]) -> int:
    """``imix run [hydra flags] [overrides]``."""
    info_only = any(a in _HYDRA_INFO_FLAGS or a.startswith("--cfg=") for a in args)
    # With Hydra's own launcher the seeds run in this process's workers: their fork server starts first of all, so that
    # its imports (numba, gymnasium, the loop: ~1 s) run on the other core beside this process's own imports and
    # validation, which need the same modules (~0.4 s of them before validation starts). Started after those imports,
    # it kept the main job's workers waiting ~0.4 s (a strace of the whole process).
    launcher = next((a.split("=", 1)[1] for a in reversed(args) if a.startswith("hydra/launcher=")), "basic")
    own_launcher = launcher == "basic"  # conf/config.yaml's default, also when named (_task: BasicLauncher)
    if not info_only:
        # Nothing is written before validation ends: a Ctrl-C then stops at once with one line, even
        # if it lands in a library that would swallow a KeyboardInterrupt (an import, a plugin scan).
        signal.signal(signal.SIGINT, _interrupted_before_anything_is_written)
        signal.signal(signal.SIGTERM, _interrupted_before_anything_is_written)
        # With Hydra's own launcher the points run in this process, and until the first one starts Hydra
        # is still loading its configs (omegaconf): a KeyboardInterrupt there left omegaconf half-updated
        # and came out as a traceback (measured: SIGINT 1.5 s into a 392-point sweep). So the handlers
        # above stay until a point's run starts (_task); another launcher runs the points elsewhere, and
        # this process hands Ctrl-C to it as a KeyboardInterrupt once validation is done.
        if own_launcher and "workers=1" not in args:
            from imix_cli.running.pool import start_worker_server

            start_worker_server()
    from imix_cli.messages import EXIT_MISSING_EXTRA, MissingExtraError
    from imix_cli.running.config.compose import ConfigError
    from imix_cli.running.run_folder import RunError

    searching = False
    if not info_only:
        specs = []
        searching = "hydra/sweeper=optuna" in args  # imix's Optuna search (imix_cli.commands.search)
        try:
            _VALIDATED.clear()
            specs = validate_run_args(args, _VALIDATED)
            if searching:  # the points validated are probes of the search space (imix_cli.running.config.search), not trials
                _VALIDATED.clear()
        except ConfigError as err:
            return _error(str(err), 2)
        except RunError as err:  # a missing extra: the same status whichever extra (MuJoCo's is a ConfigError: 2 too)
            return _error(str(err), EXIT_MISSING_EXTRA if isinstance(err, MissingExtraError) else 1)
        finally:
            if not own_launcher:
                _run_handles_signals()
        args = [*args, *_own_sweep_folder(args)]
    sys.argv = ["imix run", *args]
    _SKIPPED_POINTS.clear()
    global _POINTS_DONE
    _POINTS_DONE = 0
    try:
        if not info_only and _runs_without_hydra(args, specs):
            _run_point(specs[0], in_this_process=True)
        else:
            _hydra_run()
    except SystemExit as exit_:
        return exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 1)
    except Exception as err:  # Hydra's own argument errors (e.g. --cfg together with -m)
        return _error(str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__, 2)
    finally:
        _VALIDATED.clear()
    if not info_only and ("-m" in args or "--multirun" in args) and not searching:  # a sweep: every point in one table at the end
        from imix_cli.running.summary import format_sweep_table

        table = format_sweep_table(specs)
        if table:
            print(table)
    for message in _SKIPPED_POINTS:
        _error(f"sweep point skipped: {message}", 1)
    return 1 if _SKIPPED_POINTS else 0


def validate_run_args(args: list[str], validated: dict | None = None) -> list:
    """Everything ``imix run ARGS`` checks before anything runs or is written, and nothing else: the flags, every point's
    composed config (:func:`imix_cli.running.config.compose.validate_overrides`) and run folder (read only); returns the RunSpecs.

    ConfigError (exit status 2) or RunError (1; a missing extra's MissingExtraError 2), each a one-line message. ``imix run`` calls it first; the command-line
    fuzzer (tests/test_fuzz_readers.py) calls it alone, in-process: validation without an episode."""
    from imix_cli.running.config.compose import ConfigError, validate_overrides

    dashed = next((a for a in args if a.startswith("--") and a.split("=", 1)[0] not in _HYDRA_RUN_FLAGS), None)
    if dashed is not None:  # `--seeds 3` or `--seeds=3`: keys are Hydra overrides, key=value
        key = dashed[2:].split("=", 1)[0]
        value = dashed.split("=", 1)[1] if "=" in dashed else (args[args.index(dashed) + 1] if args.index(dashed) + 1 < len(args) else "...")
        raise ConfigError(f"unknown option {dashed!r}; keys are given as key=value, e.g. {key}={value} (see imix run --help)")
    hydra_args = _parse_hydra_args(args)
    if "hydra/sweeper=optuna" in hydra_args.overrides and not any(a in ("-m", "--multirun") for a in args):
        raise ConfigError("hydra/sweeper=optuna: a search runs with -m (imix run -m hydra/sweeper=optuna ...)")
    specs = validate_overrides(hydra_args.overrides, validated=validated, config_name=hydra_args.config_name, config_dirs=hydra_args.config_dirs)
    _check_run_folders(specs)
    return specs


class _HydraArgs:
    """What :func:`_parse_hydra_args` reads of ``imix run``'s command line: the overrides, the primary config's name and
    the folders Hydra composes it from (imix's conf/, or ``--config-path``; then ``--config-dir``)."""

    def __init__(self, overrides: list, config_name: str, config_dirs: tuple):
        self.overrides, self.config_name, self.config_dirs = overrides, config_name, config_dirs


def _parse_hydra_args(args: list[str]) -> _HydraArgs:
    """Read the command line with Hydra's own argument parser, so that what is validated is what Hydra will compose:
    ``--config-dir DIR`` and ``--config-dir=DIR`` (and ``-cd``, ``--config-name``/``-cn``, ``--config-path``/``-cp``) alike,
    the value of a flag never taken for an override. ConfigError (one line) for a flag without its value or a folder that
    is not there."""
    from hydra.main import get_args_parser

    from imix_cli.running.config.compose import ConfigError, config_dir

    parser = get_args_parser()

    def refuse(message: str):
        raise ConfigError(message)

    parser.error = refuse  # argparse would print its usage and exit
    parsed = parser.parse_args(args)
    primary = config_dir()
    if parsed.config_path is not None:
        # Hydra takes a relative --config-path relative to the file that calls hydra.main (imix_cli/commands/), not to where
        # the user stands: only an absolute one means what it says.
        if not os.path.isabs(parsed.config_path):
            raise ConfigError(f"--config-path {parsed.config_path!r}: give an absolute path (or add a folder of configs with --config-dir DIR)")
        primary = parsed.config_path
    dirs = [primary]
    if parsed.config_dir is not None:
        dirs.append(os.path.abspath(parsed.config_dir))
    for folder in dirs:
        if not os.path.isdir(folder):
            raise ConfigError(f"config folder {folder!r} not found (--config-path / --config-dir)")
    name = parsed.config_name or "config"

    def holds(folder: str) -> bool:
        try:
            return os.path.isfile(os.path.join(folder, name.removesuffix(".yaml") + ".yaml"))
        except (OSError, ValueError):  # a name too long for the file system, or holding NUL
            return False

    if not any(map(holds, dirs)):
        shown = name if len(name) <= 100 and name.isprintable() else repr(name[:100]) + "..."
        raise ConfigError(f"--config-name {shown}: no such config in {', '.join(dirs)} (--config-path / --config-dir)")
    return _HydraArgs(list(parsed.overrides), name, tuple(dirs))


def _check_run_folders(specs) -> None:
    """Every point's run folder, read only (:func:`imix_cli.running.run_folder.check_run_dir`), before any point runs:
    a folder holding another config, a corrupt CSV or a link stops the sweep before its first point."""
    from pathlib import Path

    from imix_cli.running.files.writing import LinkRefusedError
    from imix_cli.running.run_folder import RunError, check_run_dir

    for spec in specs:
        check_run_dir(spec)
        # Hydra writes a sweep's multirun.yaml and job folders below <experiment>/.multirun itself (not through
        # imix_cli.running.files.writing); the folder it makes there is new (named by the second and the pid), so refusing a
        # linked .multirun (the experiment folder: check_run_dir) keeps those writes inside results_dir.
        multirun = Path(spec.results_dir) / spec.experiment / ".multirun"
        if multirun.is_symlink():
            raise RunError(str(LinkRefusedError(multirun)))


def _own_sweep_folder(args: list[str]) -> list[str]:
    """For ``-m``: Hydra names a sweep's bookkeeping folder by the second it starts, so two sweeps started
    together shared one (and overwrote each other's ``multirun.yaml``); the process id (and a count, for
    several sweeps in one process) makes it theirs. A ``hydra.sweep.dir=`` of the user's is kept."""
    global _SWEEPS_STARTED
    if not any(a in ("-m", "--multirun") for a in args) or any(a.startswith("hydra.sweep.dir=") for a in args):
        return []
    _SWEEPS_STARTED += 1
    suffix = f"{os.getpid()}" + (f".{_SWEEPS_STARTED}" if _SWEEPS_STARTED > 1 else "")
    return [f"hydra.sweep.dir=${{results_dir}}/${{experiment}}/.multirun/${{now:%Y-%m-%d_%H-%M-%S}}_{suffix}"]


def _runs_without_hydra(args: list[str], specs: list) -> bool:
    """Whether ``imix run ARGS`` is one plain run -- no ``-m``, no flag, no ``hydra``/``hydra.*`` override -- which then
    runs the RunSpec its validation made (:func:`validate_run_args`) instead of Hydra composing the same config again.

    Why: for such a run Hydra's job adds nothing -- imix's config writes none of Hydra's files for a single run
    (``hydra.output_subdir: null``), sets no logging (``hydra/job_logging: none``) and stays in the working folder
    (``hydra.job.chdir: false``) -- but its second composition cost ~0.15 s of the main process (``/tmp`` script, the
    main job's command line). That is the whole path to the first episode where the main process runs the seeds itself
    (``workers=1``: a 2-seed run 0.89x as long, docs/research/performance.md); with seed workers, their fork server's own
    start-up (~1 s, beside it) decides when they start, and the main process's CPU is what is saved. A command that
    could make Hydra's job do something -- a sweep, ``--config-dir``, ``hydra.run.dir=``, ``hydra/launcher=``,
    ``hydra.job.env_set...`` -- is run by Hydra as before."""
    if len(specs) != 1:
        return False
    for arg in args:
        key = arg.split("=", 1)[0].lstrip("+~")
        if arg.startswith("-") or key == "hydra" or key.startswith(("hydra.", "hydra/")):
            return False
    return True


def _hydra_run() -> None:
    import hydra

    from imix_cli.running.config.compose import bounded_config_reads, config_dir

    with bounded_config_reads():  # Hydra composes each point again: every file read bounded, as validation read it
        hydra.main(version_base="1.3", config_path=config_dir(), config_name="config")(_task)()


def _point_done(spec):
    """A sweep point's line in place of its summary table: ``[3/16] snes-cartpole-eim done (3 seeds, 1.2 s)``."""
    global _POINTS_DONE
    _POINTS_DONE += 1
    count = f"[{_POINTS_DONE}/{len(_VALIDATED)}] " if len(_VALIDATED) >= _POINTS_DONE else ""

    def echo(_table: str) -> None:
        print(f"{count}{spec.run_name} done", flush=True)

    return echo


def _task(cfg) -> dict | None:
    """The Hydra task: one config (one sweep point) -> its RunSpec (validated by :func:`run_command`) -> runner. In an
    Optuna search (``hydra/sweeper=optuna``) it returns the trial's objective (:func:`imix_cli.commands.search.trial_result`)."""
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    from imix_cli.running.config.compose import ConfigError, point_key, spec_from_config

    try:
        launcher = OmegaConf.select(HydraConfig.get(), "launcher._target_")
        plain = OmegaConf.to_container(cfg, resolve=True)
        spec = _VALIDATED.get(point_key(plain, launcher)) or spec_from_config(plain, launcher)
    except ConfigError as err:
        sys.exit(_error(str(err), 2))
    from hydra.types import RunMode

    from imix_cli.commands.search import search_settings_of

    in_this_process = str(launcher or "").endswith("BasicLauncher")
    in_process_sweep = in_this_process and HydraConfig.get().mode == RunMode.MULTIRUN
    return _run_point(spec, in_this_process, in_process_sweep, search_settings_of(HydraConfig.get()))


def _run_point(spec, in_this_process: bool, in_process_sweep: bool = False, searching=None) -> dict | None:
    """Run one point, ``spec``, as the Hydra task (:func:`_task`) or a plain run (:func:`_runs_without_hydra`) does:
    every error one line and an exit status (``SystemExit``), the signal handlers of the run and, when it runs in
    ``imix run``'s own process (Hydra's own launcher), those of the time between points after it. ``searching``: an
    Optuna search's settings (the trial's objective is returned)."""
    from imix_cli.commands.boundary import broken_pipe
    from imix_cli.commands.search import trial_result
    from imix_cli.core.evaluation.parallel import EvaluatorError
    from imix_cli.running.runner import RunError, run

    _run_handles_signals()
    try:
        # a sweep in this process prints one table of every point at the end (run_command): each point says one line
        run(spec, echo=_point_done(spec) if in_process_sweep else print)
        if searching:
            return trial_result(spec, searching)
    except RunError as err:
        if in_process_sweep:  # the sweep's other points still run; this one is reported at the end
            _SKIPPED_POINTS.append(str(err))
            return
        sys.exit(_error(str(err), 1))
    except EvaluatorError as err:
        sys.exit(_error(str(err), 1))
    except BrokenProcessPool:
        sys.exit(_error("a worker process died (killed?); re-run the same command to resume from the checkpoints", 1))
    except BrokenPipeError:  # the reader of the output went away (`imix run ... | head`): the results are written
        sys.exit(broken_pipe())
    except OSError as err:
        where = f" {err.filename}" if getattr(err, "filename", None) else ""
        sys.exit(_error(f"cannot write{where}: {err.strerror or err}", 1))
    except Terminated:
        sys.exit(_error("terminated (SIGTERM); re-run the same command to resume (finished seeds and checkpoints are kept)", 143))
    except KeyboardInterrupt:
        sys.exit(_error("interrupted; re-run the same command to resume (finished seeds and checkpoints are kept)", 130))
    except Exception as err:  # noqa: BLE001 - a user env's exception, MemoryError...: Hydra would print a traceback
        sys.exit(report("run", err))
    finally:
        if in_this_process:  # between two points (Hydra preparing
            signal.signal(signal.SIGINT, _interrupted_before_anything_is_written)  # the next) and after the last,
            signal.signal(signal.SIGTERM, _interrupted_before_anything_is_written)  # nothing is half-written


if __name__ == "__main__":  # python -m imix_cli.commands.cli: imix's own process, as the `imix` script (imix_cli/__init__.py)
    from imix_cli.core.processes import set_one_blas_thread

    set_one_blas_thread()
    entry()  # as the `imix` script ends (imix bench peers times this process as the user's command)
