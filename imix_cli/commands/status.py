"""``imix status``: where the runs of an experiment stand, read-only and safe while they write.

Why: MuJoCo-scale runs last hours; one wants to know which seeds are done, which are running
and how well they score without stopping or disturbing them. Nothing here writes, locks or
deletes; every file read is one the runner replaces atomically (CSV, partial CSV, checkpoint), so
a read sees either the old or the new version, and a file that vanishes between listing and
reading (a partial CSV removed as its seed finishes) is read again as finished or ignored.

Per seed ``k`` of a run folder (``seeds`` from its config.yaml, else the files found):

* done: ``seed_<k>.csv`` is finished -- the same notion as ``imix run``'s, in one place
  (:func:`imix_cli.running.files.results.es_seed_finished`: all the config's generations, or fewer ending
  diverged) -- and no partial CSV goes beyond it;
* running: not done, and a live ``imix run`` holds the run folder's lock
  (:func:`imix_cli.running.run_folder.lock_holder`: the pid in ``.lock``, holding a lock on it): that run
  runs every unfinished seed of the folder at once, those with nothing on disk yet included;
* stopped: not done, no live run, and started -- ``seed_<k>.partial.csv`` (its rows so far: its live view),
  a checkpoint ``.checkpoints/seed_<k>.*``, or a CSV short of the config's generations with its final state
  to continue from. A run stopped by Ctrl-C or SIGTERM checkpointed every seed's current generation; one
  killed (kill -9) keeps its last periodic checkpoint. Re-running the same command resumes them;
* corrupt: ``seed_<k>.csv`` (or its partial CSV) does not follow the CSV contract, or is short of the
  config's generations with no final state to continue from; listed by name and reason, and counted
  neither done nor running nor stopped (``imix run`` refuses the folder until it is moved);
* not started: none of these.

Last gen: per seed, the most advanced of its CSV/partial rows and its checkpoint's header (``generation``,
if the checkpoint is an ``.npz`` holding a ``header`` entry or has a ``seed_<k>.json`` beside it; anything
else is tolerated and ignored); shown as the range over the seeds (``370-375/1000``). A running seed's is
that of its live view (``seed_<k>.partial.csv``, rewritten with every checkpoint and every few seconds between:
:data:`imix_cli.running.files.run_writer.LIVE_VIEW_SECONDS`), so it shows from a run's first seconds on; the
run itself is a little ahead. A stopped seed's is where a re-run resumes: its checkpoint's, when a kill -9 left
its live view beyond it. Best score: the highest ``best_score`` of any
generation read; current: the population ``mean_score`` of the last generation read, averaged over the
seeds that have rows.
"""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path

from imix_cli.commands.eval_command import run_folders
from imix_cli.keyvalue import UsageError, folder_name, help_requested, parse_key_values
from imix_cli.running.files.results import MAX_CONFIG_BYTES, PRUNED_FILE, ResultMismatchError, read_small_text, regular_file_size
from imix_cli.running.files.run_lock import lock_holder
from imix_cli.running.files.safe_yaml import load_yaml_file
from imix_cli.running.seed_checks import check_seed_csv, check_seed_scores
from imix_cli.running.trainers import trainer_named

HELP = """\
usage: imix status [key=value ...]

For each run folder: seeds done / running (a live imix run holds the folder) / stopped (started,
no live run: re-run the same command to resume) / not started, the generations each seed has on
disk (range over the seeds), the best member score ever and the current population mean score.
Read-only; safe while runs write. Rows of running seeds are those of their live view, written
every few seconds and with each checkpoint (checkpoint_every=, checkpoint_seconds=); Ctrl-C or
SIGTERM saves each seed's current generation, where a re-run resumes.

keys:
  results_dir=PATH   folder holding the experiments (default: results)
  experiment=NAME    one experiment (default: every experiment under results_dir)
"""

_SEED_FILE = re.compile(r"^seed_(\d+)(\.partial)?\.csv$")


def _read_rows(path: Path, corrupt: dict | None = None):
    """The rows of a seed's CSV, or None (absent, being replaced); a file that does not follow the
    CSV contract is noted in ``corrupt`` (name -> reason) when given."""
    from imix_cli.running.files.results import CorruptResultError, read_run_csv

    try:
        return read_run_csv(path)
    except (FileNotFoundError, CorruptResultError, OSError) as err:
        if corrupt is not None and isinstance(err, CorruptResultError) and path.exists():
            corrupt[path.name] = str(err).replace(f"{path}: ", "", 1)
        return None


def _checkpoint_generation(run_dir: Path, seed: int):
    """The generation in a checkpoint's JSON header, or None (absent, other format, unreadable)."""
    ckpt_dir = run_dir / ".checkpoints"
    sidecar = ckpt_dir / f"seed_{seed}.json"
    try:
        if sidecar.exists():
            return int(json.loads(read_small_text(sidecar))["generation"])
        npz = ckpt_dir / f"seed_{seed}.npz"
        if npz.exists():
            import zipfile

            import numpy as np

            regular_file_size(npz)  # a regular file, or nothing is opened
            with zipfile.ZipFile(npz) as archive:  # the header's declared size is checked before it is inflated
                if archive.getinfo("header.npy").file_size > MAX_CONFIG_BYTES:
                    return None
            with np.load(npz, allow_pickle=False) as data:
                header = data["header"]
                # imix's checkpoints: the JSON's UTF-8 bytes as a uint8 array (imix_cli.running.files.checkpoints); else a string
                text = header.tobytes().decode() if header.dtype == np.uint8 else str(header[()])
                return int(json.loads(text)["generation"])
    except Exception:  # noqa: BLE001 - another helper's format, a write in progress: not our business
        return None
    return None


def _has_checkpoint(run_dir: Path, seed: int) -> bool:
    ckpt_dir = run_dir / ".checkpoints"
    return ckpt_dir.is_dir() and any(p.name.startswith(f"seed_{seed}.") and not p.name.endswith(".tmp") for p in ckpt_dir.iterdir())


def run_status(run_dir: Path) -> dict:
    """Status of one run folder (see the module docstring); ``generations``: seed -> its last generation on disk."""
    try:
        config = load_yaml_file(run_dir / "config.yaml") or {}  # bounded (safe_yaml); a refused one is as a missing one
    except Exception:  # noqa: BLE001 - missing or being written: fall back on the files found
        config = {}
    config = config if isinstance(config, dict) else {}
    found = set()
    for path in run_dir.iterdir():
        match = _SEED_FILE.match(path.name)
        if match:
            found.add(int(match.group(1)))
    if (run_dir / ".checkpoints").is_dir():
        found |= {int(m.group(1)) for p in (run_dir / ".checkpoints").iterdir() if (m := re.match(r"^seed_(\d+)\.", p.name))}
    n_seeds = config.get("seeds") if isinstance(config.get("seeds"), int) else (max(found) + 1 if found else 0)
    algo = config.get("algo") if isinstance(config.get("algo"), dict) else {}
    trainer = trainer_named(algo.get("name"))
    target = config.get(trainer.budget_key)  # generations, or DDPG's total_steps
    target = target if isinstance(target, int) and not isinstance(target, bool) else None
    holder = lock_holder(run_dir)
    done, unfinished, not_started, corrupt = [], [], [], {}
    generations, best, current = {}, -math.inf, []
    for seed in range(max(n_seeds, max(found) + 1 if found else 0)):
        final = _read_rows(run_dir / f"seed_{seed}.csv", corrupt)
        if final is None and f"seed_{seed}.csv" not in corrupt and (run_dir / f"seed_{seed}.csv").exists():
            final = _read_rows(run_dir / f"seed_{seed}.csv", corrupt)  # replaced between listing and reading: once more
        partial = _read_rows(run_dir / f"seed_{seed}.partial.csv", corrupt)
        if partial is not None and config:
            try:  # a stopped seed's rows are read by status alone: their scores checked as a finished seed's
                check_seed_scores(partial, run_dir / f"seed_{seed}.partial.csv", config)
            except ResultMismatchError as err:
                corrupt[f"seed_{seed}.partial.csv"] = str(err).replace(f"{run_dir / f'seed_{seed}.partial.csv'}: ", "", 1)
                partial = None
        if final is not None and config:
            try:  # a CSV that contradicts its run's config is one imix run refuses: not done (the readers' one check)
                check_seed_csv(final, run_dir / f"seed_{seed}.csv", config)
            except ResultMismatchError as err:
                corrupt[f"seed_{seed}.csv"] = str(err).replace(f"{run_dir / f'seed_{seed}.csv'}: ", "", 1)
                continue
        finished = final is not None and (target is None or trainer.finished(final, target))
        if finished and (partial is None or len(partial) <= len(final)):
            done.append(seed)
            frame = final
        elif f"seed_{seed}.csv" in corrupt:  # neither done nor running: a file to move away (imix run refuses it)
            continue
        elif final is not None and not finished and holder is None and not _has_checkpoint(run_dir, seed):
            # short of the config's generations with no final state to continue from: what imix run refuses
            corrupt[f"seed_{seed}.csv"] = f"{len(final)} of {target} generations and no final state to continue from"
            continue
        else:
            # Not finished: a seed under way, stopped, or a continuation to more generations whose partial rows go
            # beyond its CSV. Its rows are the most advanced on disk.
            frame = partial if partial is not None and (final is None or len(partial) > len(final)) else final
            ckpt_gen = _checkpoint_generation(run_dir, seed)
            if holder is None and frame is partial and frame is not None and ckpt_gen is not None and len(frame) > ckpt_gen:
                # stopped by a kill -9 after its live view had moved past its checkpoint: a re-run resumes from the checkpoint
                frame = frame.iloc[:ckpt_gen] if ckpt_gen > 0 else None
            if holder is not None or frame is not None or ckpt_gen is not None or _has_checkpoint(run_dir, seed):
                unfinished.append(seed)
                if ckpt_gen is not None and (frame is None or ckpt_gen > len(frame)):
                    generations[seed] = ckpt_gen
            else:
                not_started.append(seed)
        if frame is not None:
            generations[seed] = max(len(frame), generations.get(seed, 0))
            best = max(best, float(frame["best_score"].max()))
            current.append(float(frame["mean_score"].iloc[-1]))
    return {
        "run": run_dir.name, "seeds": n_seeds, "done": done, "running": unfinished if holder is not None else [],
        "stopped": [] if holder is not None else unfinished, "not_started": not_started, "corrupt": corrupt, "pid": holder,
        "generations": generations, "last_generation": max(generations.values()) if generations else None,
        "first_generation": min(generations.values()) if generations else None, "target": target,
        "best_score": best if math.isfinite(best) else None,
        "current_score": sum(current) / len(current) if current else None,
        "pruned": (run_dir / PRUNED_FILE).is_file(),  # an Optuna search's trial stopped early (imix_cli.commands.search)
    }  # fmt: skip


def _score(value) -> str:
    """A score as the table prints it: two decimals, or three significant digits when large (never hundreds of digits)."""
    if value is None:
        return "-"
    return f"{value:.2f}" if abs(value) < 1e7 else f"{value:.3g}"


def _seed_list(seeds: list) -> str:
    if not seeds:
        return "-"
    ranges, start = [], seeds[0]
    for a, b in zip(seeds, [*seeds[1:], None]):
        if b != a + 1:
            ranges.append(f"{start}" if start == a else f"{start}-{a}")
            start = b
    return ",".join(ranges)


def format_status(experiment: str, statuses: list) -> str:
    width = max(32, *(len(s["run"]) for s in statuses)) if statuses else 32
    header = f"  {'run':<{width}} {'done':>5} {'running':>8} {'stopped':>8} {'not started':>12} {'last gen':>14} {'best':>9} {'current':>9}"
    lines = [f"experiment {experiment}:", header]
    for s in statuses:
        low, high = s.get("first_generation"), s["last_generation"]
        last = "-" if high is None else (f"{high}" if low in (None, high) else f"{low}-{high}") + (f"/{s['target']}" if s["target"] else "")
        best, current = _score(s["best_score"]), _score(s["current_score"])
        counts = f"{len(s['done']):>5} {len(s['running']):>8} {len(s['stopped']):>8} {len(s['not_started']):>12}"
        lines.append(f"  {s['run']:<{width}} {counts} {last:>14} {best:>9} {current:>9}")
        if s.get("pruned"):
            lines.append(f"  {'':<{width}}   pruned by an Optuna search: its seeds stopped early (file {PRUNED_FILE}); imix plot leaves it out")
        if s["running"]:
            lines.append(f"  {'':<{width}}   running seeds: {_seed_list(s['running'])} (imix run, pid {s['pid']})")
        if s["stopped"]:
            lines.append(f"  {'':<{width}}   stopped seeds: {_seed_list(s['stopped'])} (re-run the same command to resume them)")
        for name, reason in s.get("corrupt", {}).items():
            # imix run refuses a finished seed's CSV; a stopped seed's partial one it writes anew from the seed's checkpoint
            what = "its rows are left out here (imix run writes it anew)" if name.endswith(".partial.csv") else "imix run refuses it: move it away"
            lines.append(f"  {'':<{width}}   corrupt: {name} ({reason}); {what}")
    return "\n".join(lines)


def main(argv: list | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if help_requested(argv, HELP):
        return 0
    try:
        s = parse_key_values(argv, "status", {"results_dir": "results", "experiment": None}, convert={"experiment": folder_name})
        root = Path(s["results_dir"])
        if s["experiment"] is None:
            if not root.is_dir():
                raise UsageError(f"no results at {root} (check results_dir=)", 1)
            experiments = sorted(p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
        else:
            experiments = [s["experiment"]]
        blocks = []
        for experiment in experiments:
            statuses = [run_status(d) for d in run_folders(root, experiment)]
            statuses = [st for st in statuses if st["seeds"] or st["done"] or st["running"] or st["stopped"] or st["corrupt"]]
            if statuses:
                blocks.append(format_status(experiment, statuses))
    except UsageError as err:
        print(f"imix status: {err}", file=sys.stderr)
        return err.status
    if not blocks:
        print(f"imix status: no runs under {root}", file=sys.stderr)
        return 1
    print("\n\n".join(blocks))
    print("(best: highest member score of any generation; current: population mean score of the last generation, averaged over seeds)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
