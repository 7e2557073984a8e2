"""``imix eval``: the saved policies of every seed, evaluated on fresh episodes.

Why: training scores are the population's on the episodes it was trained on; the number to
report for a learned policy is its return on episodes it never saw. This reads the policy files
of each run (:mod:`imix_cli.policy_files`), runs ``episodes`` episodes per seed with the batched
evaluator the run trained with, prints mean ± 95 % CI over seeds per run and writes
``<run>/eval.csv`` (one row per seed and ``which``).

Fresh episode seeds: seed ``k``'s evaluation episodes take their seeds from
``SeedSequence(k, spawn_key=(EVAL_STREAM,))``. Training draws from ``SeedSequence(k).spawn(2)``
(spawn keys (0,) and (1,)) and DDPG from seed ``k`` itself, so the evaluation stream is a
different, independent stream; its 63-bit episode seeds coincide with a training episode's with
probability below 1e-12 per run. Same files and arguments, same numbers (deterministic by seed).
"""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path

import numpy as np

from imix_cli.keyvalue import UsageError, at_least, folder_name, help_requested, one_of, parse_key_values

HELP = """\
usage: imix eval [key=value ...]

Evaluate the saved policies (policy_<k>_<which>.npz) of every seed of every run of an
experiment on fresh episodes (seeds disjoint from training), print mean ± 95 % CI over
seeds per run, and write <run>/eval.csv.

keys:
  results_dir=PATH   folder holding the experiments (default: results)
  experiment=NAME    experiment to evaluate (default: default)
  run=NAME           only this run folder (default: every run with policy files)
  episodes=N         episodes per seed, >= 1 (default: 100)
  which=mean|best    mean: the final search-distribution mean; best: the best-ever member
                     (default: mean)
"""

#: Spawn key of the evaluation episode stream (ASCII "eval"); training uses spawn keys 0 and 1.
EVAL_STREAM = 0x6576616C

EVAL_COLUMNS = (
    "run", "seed", "which", "episodes", "mean_return", "std_return", "min_return", "max_return",
    "mean_steps", "train_generation", "train_return", "config_hash",
)  # fmt: skip

_POLICY_FILE = re.compile(r"^policy_(\d+)_(mean|best)\.npz$")
_NOT_RUNS = {"figures"}


#: The keys that choose policy files, shared by ``imix eval`` and ``imix render``: defaults and checks.
POLICY_KEYS = {"results_dir": "results", "experiment": "default", "run": None, "which": "mean"}
POLICY_KEY_CHECKS = {"experiment": folder_name, "run": folder_name, "which": one_of("mean", "best")}


def run_folders(results_dir, experiment: str, run: str | None = None) -> list[Path]:
    """The run folders of an experiment (or just ``run``); UsageError (status 1) if there are none."""
    exp_dir = Path(results_dir) / experiment
    if not exp_dir.is_dir():
        raise UsageError(f"no experiment at {exp_dir} (check results_dir= and experiment=)", 1)
    folders = sorted(p for p in exp_dir.iterdir() if p.is_dir() and p.name not in _NOT_RUNS and not p.name.startswith((".", "_")))
    if run is not None:
        if not (exp_dir / run).is_dir():
            names = ", ".join(p.name for p in folders) or "none"
            raise UsageError(f"bad value for run: {run!r} is not a run folder of {exp_dir} (runs: {names})", 1)
        folders = [exp_dir / run]
    return folders


def policy_files(run_dir: Path, which: str) -> dict:
    """seed -> path of ``policy_<seed>_<which>.npz`` in ``run_dir``."""
    found = {}
    for path in Path(run_dir).iterdir():
        match = _POLICY_FILE.match(path.name)
        if match and match.group(2) == which:
            found[int(match.group(1))] = path
    return dict(sorted(found.items()))


def eval_episode_seeds(seed: int, episodes: int) -> np.ndarray:
    """The episode seeds of seed ``seed``'s evaluation: the first ``episodes`` draws of its eval stream."""
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(EVAL_STREAM,)))
    return rng.integers(0, np.iinfo(np.int64).max, size=int(episodes), dtype=np.int64)


def evaluator_for(header: dict, cache: dict | None = None):
    """The batched evaluator a policy was trained with (from its header)."""
    from imix_cli.evaluation import make_evaluator
    from imix_cli.registry import BUILTIN_ENVS

    if header.get("obs_normalizer") is not None:
        raise UsageError(
            f"policy of run {header.get('run')!r} seed {header.get('seed')} normalises observations; "
            "this imix eval cannot apply a normaliser yet", 1
        )  # fmt: skip
    name = header["env_name"] if header["env_name"] in BUILTIN_ENVS else header["env_id"]
    hidden = tuple(int(h) for h in header["hidden"])  # policy.hidden of the run
    key = (name, header["max_steps"], hidden)
    cache = {} if cache is None else cache
    if key not in cache:
        cache[key] = make_evaluator(name, header["max_steps"], hidden=hidden)
    return cache[key]


def evaluate_policy(policy, episodes: int, cache: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(returns, steps)`` of ``episodes`` fresh episodes of a :class:`~imix_cli.policy_files.PolicyFile`."""
    evaluator = evaluator_for(policy.header, cache)
    seeds = eval_episode_seeds(policy.header["seed"], episodes)
    return evaluator.evaluate(np.repeat(policy.params[None, :], episodes, axis=0), seeds)


def evaluate_run(run_dir: Path, which: str, episodes: int, cache: dict | None = None):
    """Rows (dicts with :data:`EVAL_COLUMNS`) of every seed of one run folder, or [] without policy files."""
    from imix_cli.policy_files import read_policy

    rows = []
    for seed, path in policy_files(run_dir, which).items():
        policy = read_policy(path)
        returns, steps = evaluate_policy(policy, episodes, cache)
        h = policy.header
        rows.append(
            {
                "run": Path(run_dir).name, "seed": seed, "which": which, "episodes": episodes,
                "mean_return": float(np.mean(returns)), "std_return": float(np.std(returns, ddof=1)) if episodes > 1 else math.nan,
                "min_return": float(np.min(returns)), "max_return": float(np.max(returns)),
                "mean_steps": float(np.mean(steps)), "train_generation": h.get("generation"),
                "train_return": h.get("train_return"), "config_hash": h.get("config_hash"),
            }
        )  # fmt: skip
    return rows


def write_eval_csv(run_dir: Path, rows: list) -> Path:
    """Write ``<run_dir>/eval.csv`` atomically, keeping the rows of the other ``which`` already there."""
    import pandas as pd

    from imix_cli.results import atomic_write_text

    path = Path(run_dir) / "eval.csv"
    frame = pd.DataFrame(rows, columns=list(EVAL_COLUMNS))
    if path.exists():
        try:
            old = pd.read_csv(path)
            old = old[old["which"] != rows[0]["which"]] if "which" in old.columns else old.iloc[0:0]
            frame = pd.concat([old.reindex(columns=list(EVAL_COLUMNS)), frame], ignore_index=True)
        except Exception:  # an unreadable old eval.csv is replaced, not merged
            pass
    frame = frame.sort_values(["which", "seed"], kind="stable")
    atomic_write_text(path, frame.to_csv(index=False, float_format="%.10g", lineterminator="\n"))
    return path


def format_estimate(values, level: float = 0.95) -> str:
    """``mean ± half-width`` over seeds (Student t), or the bare value with one seed."""
    from imix_cli.stats import mean_ci

    mean, half, n = mean_ci(values, level)
    return f"{mean:.2f}" if n < 2 or not math.isfinite(half) else f"{mean:.2f} ± {half:.2f}"


def main(argv: list | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if help_requested(argv, HELP):
        return 0
    try:
        s = parse_key_values(argv, "eval", {**POLICY_KEYS, "episodes": 100}, convert={**POLICY_KEY_CHECKS, "episodes": at_least(1)})
        folders = run_folders(s["results_dir"], s["experiment"], s["run"])
        from imix_cli.policy_files import PolicyFileError

        cache, results = {}, []
        for run_dir in folders:
            rows = evaluate_run(run_dir, s["which"], s["episodes"], cache)
            if not rows:
                why = "unfinished, algo=ddpg, or run before policy files existed"
                print(f"imix eval: {run_dir.name}: no policy_<k>_{s['which']}.npz ({why}); skipped", file=sys.stderr)
                continue
            results.append((run_dir, rows, write_eval_csv(run_dir, rows)))
    except UsageError as err:
        print(f"imix eval: {err}", file=sys.stderr)
        return err.status
    except PolicyFileError as err:
        print(f"imix eval: {err}", file=sys.stderr)
        return 1
    if not results:
        print(f"imix eval: no policy files to evaluate under {Path(s['results_dir']) / s['experiment']}", file=sys.stderr)
        return 1
    width = max(32, *(len(r[0].name) for r in results))
    print(f"{'run':<{width}} {'seeds':>5} {'return on fresh episodes (mean ± 95% CI over seeds)':>52}")
    for run_dir, rows, _path in results:
        estimate = format_estimate([r["mean_return"] for r in rows])
        flag = "  (<5 seeds: CI unreliable)" if len(rows) < 5 else ""
        print(f"{run_dir.name:<{width}} {len(rows):>5} {estimate:>52}{flag}")
    print(f"({s['episodes']} episodes per seed, policy={s['which']}; per seed: <run>/eval.csv)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
