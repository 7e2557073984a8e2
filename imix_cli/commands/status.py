"""``imix status``: where the runs of an experiment stand, read-only and safe while they write.

Why: MuJoCo-scale runs last hours; one wants to know which seeds are done, which are running
and how well they score without stopping or disturbing them. Nothing here writes, locks or
deletes; every file read is one the runner replaces atomically (CSV, partial CSV, checkpoint), so
a read sees either the old or the new version, and a file that vanishes between listing and
reading (a partial CSV removed as its seed finishes) is read again as finished or ignored.

Per seed ``k`` of a run folder (``seeds`` from its config.yaml, else the files found):

* done: ``seed_<k>.csv`` exists (and no partial CSV goes beyond it);
* running: ``seed_<k>.partial.csv`` (rows up to the last checkpoint) or a checkpoint
  ``.checkpoints/seed_<k>.*`` exists, and no final CSV -- or a partial CSV longer than the final
  one (a continuation to more generations). "Running" means "started and not finished": a killed
  run looks the same until it is resumed;
* corrupt: ``seed_<k>.csv`` (or its partial CSV) does not follow the CSV contract; listed by name
  and reason, and counted neither done nor running (``imix run`` refuses the folder until it is moved);
* not started: none of these.

Last generation: the most advanced of the CSV/partial rows and the checkpoint's JSON header
(``generation``, if the checkpoint is an ``.npz`` holding a ``header`` entry or has a
``seed_<k>.json`` beside it; anything else is tolerated and ignored). Best score: the highest
``best_score`` of any generation read; current: the population ``mean_score`` of the last
generation read, averaged over the seeds that have rows.
"""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path

from imix_cli.commands.eval_command import run_folders
from imix_cli.commands.keyvalue import UsageError, folder_name, help_requested, parse_key_values
from imix_cli.running.results import MAX_CONFIG_BYTES, read_small_text, regular_file_size
from imix_cli.running.trainers import trainer_named

HELP = """\
usage: imix status [key=value ...]

For each run folder: seeds done / running / not started, the last generation reached, the best
member score ever and the current population mean score. Read-only; safe while runs write.
Rows of running seeds are those of their last checkpoint (checkpoint_every=, checkpoint_seconds=).

keys:
  results_dir=PATH   folder holding the experiments (default: results)
  experiment=NAME    one experiment (default: every experiment under results_dir)
"""

_SEED_FILE = re.compile(r"^seed_(\d+)(\.partial)?\.csv$")


def _read_rows(path: Path, corrupt: dict | None = None):
    """The rows of a seed's CSV, or None (absent, being replaced); a file that does not follow the
    CSV contract is noted in ``corrupt`` (name -> reason) when given."""
    from imix_cli.running.results import CorruptResultError, read_run_csv

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
                return int(json.loads(str(data["header"][()]))["generation"])
    except Exception:  # noqa: BLE001 - another helper's format, a write in progress: not our business
        return None
    return None


def _has_checkpoint(run_dir: Path, seed: int) -> bool:
    ckpt_dir = run_dir / ".checkpoints"
    return ckpt_dir.is_dir() and any(p.name.startswith(f"seed_{seed}.") and not p.name.endswith(".tmp") for p in ckpt_dir.iterdir())


def run_status(run_dir: Path) -> dict:
    """Status of one run folder (see the module docstring)."""
    import yaml

    try:
        config = yaml.safe_load(read_small_text(run_dir / "config.yaml")) or {}
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
    target = config.get(trainer_named(algo.get("name")).budget_key)  # generations, or DDPG's total_steps
    done, running, not_started, corrupt = [], [], [], {}
    last_gen, best, current = [], -math.inf, []
    for seed in range(max(n_seeds, max(found) + 1 if found else 0)):
        final = _read_rows(run_dir / f"seed_{seed}.csv", corrupt)
        partial = _read_rows(run_dir / f"seed_{seed}.partial.csv", corrupt)
        if final is not None and (partial is None or len(partial) <= len(final)):
            done.append(seed)
            frame = final
        elif f"seed_{seed}.csv" in corrupt:  # neither done nor running: a file to move away (imix run refuses it)
            continue
        else:
            # No final CSV, or a continuation to more generations (started, killed or still running) whose
            # partial rows go beyond it: the seed is running, and its rows are the partial ones.
            frame = partial
            if frame is None and final is None and (run_dir / f"seed_{seed}.csv").exists():  # finished between the two reads
                frame = _read_rows(run_dir / f"seed_{seed}.csv")
                done.append(seed) if frame is not None else None
            if seed not in done:
                ckpt_gen = _checkpoint_generation(run_dir, seed)
                if frame is not None or ckpt_gen is not None or _has_checkpoint(run_dir, seed):
                    running.append(seed)
                    if ckpt_gen is not None and (frame is None or ckpt_gen > len(frame)):
                        last_gen.append(ckpt_gen)
                else:
                    not_started.append(seed)
        if frame is not None:
            last_gen.append(len(frame))
            best = max(best, float(frame["best_score"].max()))
            current.append(float(frame["mean_score"].iloc[-1]))
    return {
        "run": run_dir.name, "seeds": n_seeds, "done": done, "running": running, "not_started": not_started, "corrupt": corrupt,
        "last_generation": max(last_gen) if last_gen else None, "target": target,
        "best_score": best if math.isfinite(best) else None,
        "current_score": sum(current) / len(current) if current else None,
    }  # fmt: skip


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
    lines = [f"experiment {experiment}:", f"  {'run':<{width}} {'done':>5} {'running':>8} {'not started':>12} {'last gen':>12} {'best':>9} {'current':>9}"]
    for s in statuses:
        last = "-" if s["last_generation"] is None else f"{s['last_generation']}" + (f"/{s['target']}" if s["target"] else "")
        best = "-" if s["best_score"] is None else f"{s['best_score']:.2f}"
        current = "-" if s["current_score"] is None else f"{s['current_score']:.2f}"
        lines.append(f"  {s['run']:<{width}} {len(s['done']):>5} {len(s['running']):>8} {len(s['not_started']):>12} {last:>12} {best:>9} {current:>9}")
        if s["running"]:
            lines.append(f"  {'':<{width}}   running seeds: {_seed_list(s['running'])}")
        for name, reason in s.get("corrupt", {}).items():
            lines.append(f"  {'':<{width}}   corrupt: {name} ({reason}); imix run refuses it: move it away")
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
            statuses = [st for st in statuses if st["seeds"] or st["done"] or st["running"] or st["corrupt"]]
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
