"""Figures and table of the MuJoCo study (``make reproduce-mujoco``).

Usage::

    imix plot mujoco [results_dir=results] [experiment=mujoco]
                     [threshold.<env id>=RETURN ...] [resamples=2000]

Reads ``<results_dir>/<experiment>/<run>/seed_<k>.csv`` through :mod:`imix_cli.running.files.results`
and writes into ``<results_dir>/<experiment>/figures/``:

* ``mujoco_<env>.png`` / ``.pdf``: the population's mean return (``mean_score``) against
  episodes run, environment steps run and wall time, one curve per run folder (algorithm x
  mixing), the mean over seeds with a 95 % bootstrap confidence interval of that mean;
* ``mujoco_table.csv`` / ``.md``: per env and run, the final return (mean and 95 % CI), the
  distribution mean's last return on fresh episodes (``mean_policy_score``), the return when
  the run had spent the smallest episode budget of any seed of the env (an equal-episodes
  comparison), the
  reuse rate, the episodes and env steps spent, the wall time, and the episodes and wall time
  needed to first reach the env's return threshold (mean over the seeds that reached it, and
  how many did).

Why a bootstrap interval: with 5 seeds and returns that are far from normal (a seed that
learns to hop against one that falls), a Student t interval is symmetric where the data are
not; the percentile bootstrap of the mean (``resamples`` resamplings of the seeds, fixed
generator) follows the data. Curves are put on a common x grid by holding each seed's value
of its last generation at or before the grid point, and stop where the shortest seed stops,
so every point averages all seeds (as ``imix plot`` does). Wall time is the ``wall_time``
column: seconds since the seed started, in a process that advances its seeds in lockstep --
so it is the run's time, not one seed's alone.

The thresholds default to :data:`DEFAULT_THRESHOLDS` (modest returns that separate learning
from not learning within the study's budget); override them with ``threshold.Hopper-v5=800``.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from imix_cli.core.registry import mujoco_thresholds
from imix_cli.keyvalue import UsageError, at_least, experiment_name, finite_number, help_requested, parse_key_values, results_dir_value
from imix_cli.running.files.writing import atomic_write_text, csv_text, one_line, write_figure

#: Return thresholds of the to-threshold columns: a clear sign of learning in the study's budget.
#: Keyed by gymnasium id (MuJoCo runs are named by it), from :data:`imix_cli.core.registry.ENV_SPECS`.
DEFAULT_THRESHOLDS = mujoco_thresholds()
AXES = (("evaluations", "episodes"), ("env_steps", "environment steps"), ("wall_time", "wall time (s)"))
GRID_POINTS = 200


def bootstrap_ci(values: np.ndarray, resamples: int = 2000, level: float = 0.95, seed: int = 0):
    """Mean over axis 0 and the percentile-bootstrap interval of that mean: ``(mean, low, high)``.

    ``values`` is (n_seeds, ...); resampling draws seeds with replacement (the same draws for
    every column, so a curve's band is one coherent resampling). One seed: low = high = mean.
    """
    values = np.asarray(values, dtype=np.float64)
    mean = values.mean(axis=0)
    n = values.shape[0]
    if n < 2:
        return mean, mean.copy(), mean.copy()
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, n, size=(resamples, n))
    means = values[idx].mean(axis=1)
    alpha = (1.0 - level) / 2.0
    return mean, np.quantile(means, alpha, axis=0), np.quantile(means, 1.0 - alpha, axis=0)


def hold_on_grid(x: np.ndarray, y: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """y of the last point with x <= grid point (zero-order hold); x non-decreasing."""
    pos = np.searchsorted(x, grid, side="right") - 1
    return y[np.clip(pos, 0, None)]


def load_runs(exp_dir: Path) -> dict:
    """``{env: {run name: [frames of its seeds]}}`` for every run folder holding seed CSVs."""
    from imix_cli.running.files.results import CorruptResultError, read_run_csv

    runs: dict = {}
    for run_dir in sorted(p for p in exp_dir.iterdir() if p.is_dir() and not p.name.startswith(".") and p.name != "figures"):
        frames = []
        for path in sorted(run_dir.glob("seed_*.csv")):
            try:
                frames.append(read_run_csv(path))
            except CorruptResultError as err:
                print(f"imix plot mujoco: warning: skipped {path} ({err})", file=sys.stderr)
        frames = [f for f in frames if len(f)]
        if frames:
            env = str(frames[0]["env"].iloc[0])
            runs.setdefault(env, {})[run_dir.name] = frames
    return runs


def labels(runs_of_env: dict) -> tuple[dict, str]:
    """Short run labels (``"<algo> <mixing>"`` plus the settings not shared by all runs of the
    env) and the shared settings, e.g. ``"hidden=linear,popsize=20"``."""
    suffixes = {}
    for name, frames in runs_of_env.items():
        algo, env, mixing = (str(frames[0][c].iloc[0]) for c in ("algo", "env", "mixing"))
        rest = name[len(f"{algo}-{env}-{mixing}") :].lstrip("-")
        suffixes[name] = (f"{algo} {mixing}", set(rest.split(",")) - {""})
    common = set.intersection(*(tokens for _, tokens in suffixes.values())) if suffixes else set()
    short = {name: " ".join([head, ",".join(sorted(tokens - common))]).strip() for name, (head, tokens) in suffixes.items()}
    return short, ",".join(sorted(common))


def curve(frames: list, column: str, resamples: int):
    """The grid, mean and 95 % bootstrap band of ``mean_score`` against ``column`` over seeds."""
    start = max(float(f[column].iloc[0]) for f in frames)
    stop = min(float(f[column].iloc[-1]) for f in frames)
    grid = np.linspace(start, stop, GRID_POINTS) if stop > start else np.array([stop])
    ys = np.array([hold_on_grid(f[column].to_numpy(float), f["mean_score"].to_numpy(float), grid) for f in frames])
    return (grid, *bootstrap_ci(ys, resamples))


def first_reach(frame, threshold: float):
    """(episodes, wall time) at the first generation whose mean_score >= threshold, or None."""
    hit = np.flatnonzero(frame["mean_score"].to_numpy(float) >= threshold)
    if not hit.size:
        return None
    row = frame.iloc[int(hit[0])]
    return float(row["evaluations"]), float(row["wall_time"])


def table_rows(runs: dict, thresholds: dict, resamples: int) -> list[dict]:
    rows = []
    for env in sorted(runs):
        threshold = thresholds.get(env)
        short, _ = labels(runs[env])
        # The smallest budget any seed of the env spent: every run is also compared at it.
        budget = min(int(f["evaluations"].iloc[-1]) for frames in runs[env].values() for f in frames)
        for name, frames in sorted(runs[env].items()):
            finals = np.array([float(f["mean_score"].iloc[-1]) for f in frames])
            at_budget = [float(f["mean_score"][f["evaluations"] <= budget].iloc[-1]) for f in frames if (f["evaluations"] <= budget).any()]
            # The distribution mean's return on fresh episodes (eval_mean_every), last measurement per seed
            # (NaN on the rows where it was not measured).
            theta = [float(f["mean_policy_score"].dropna().iloc[-1]) for f in frames if f["mean_policy_score"].notna().any()]
            mean, low, high = bootstrap_ci(finals[:, None], resamples)
            reached = [r for r in (first_reach(f, threshold) for f in frames) if r is not None] if threshold is not None else []
            rows.append({
                "env": env, "run": short[name], "folder": name, "seeds": len(frames), "generations": int(min(len(f) for f in frames)),
                "final_return": float(mean[0]), "ci95_low": float(low[0]), "ci95_high": float(high[0]),
                "mean_policy_return": float(np.mean(theta)) if theta else math.nan,
                "budget_episodes": budget, "return_at_budget": float(np.mean(at_budget)) if at_budget else math.nan,
                "reuse_percent": 100.0 * sum(int(f["reused"].sum()) for f in frames) / max(1, sum(int(f["popsize"].sum()) for f in frames)),
                "episodes": float(np.mean([f["evaluations"].iloc[-1] for f in frames])),
                "env_steps": float(np.mean([f["env_steps"].iloc[-1] for f in frames])),
                "wall_time_s": float(np.mean([f["wall_time"].iloc[-1] for f in frames])),
                "threshold": threshold if threshold is not None else math.nan,
                "reached": f"{len(reached)}/{len(frames)}" if threshold is not None else "",
                "episodes_to_threshold": float(np.mean([r[0] for r in reached])) if reached else math.nan,
                "wall_time_to_threshold_s": float(np.mean([r[1] for r in reached])) if reached else math.nan,
            })  # fmt: skip
    return rows


def _fmt(value, spec: str) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


def _markdown(rows: list[dict]) -> str:
    head = (
        "| env | run | seeds | final return (95 % CI) | θ on fresh episodes | return at the smallest budget (episodes) | reuse "
        "| episodes | env steps | wall time | threshold | reached | episodes to threshold | wall time to threshold |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        lines.append(
            f"| {one_line(r['env'])} | {one_line(r['run'])} | {r['seeds']} | {r['final_return']:.1f} [{r['ci95_low']:.1f}, {r['ci95_high']:.1f}] | "
            f"{_fmt(r['mean_policy_return'], '.1f')} | {_fmt(r['return_at_budget'], '.1f')} ({r['budget_episodes']:,}) | "
            f"{r['reuse_percent']:.1f} % | {r['episodes']:,.0f} | {r['env_steps']:,.0f} | {r['wall_time_s']:.0f} s | "
            f"{_fmt(r['threshold'], '.0f')} | {r['reached'] or '-'} | {_fmt(r['episodes_to_threshold'], ',.0f')} | "
            f"{_fmt(r['wall_time_to_threshold_s'], '.0f')} |"
        )
    return "\n".join(lines) + "\n"


def draw_env(env: str, runs_of_env: dict, resamples: int):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(AXES), figsize=(5.0 * len(AXES), 3.8), constrained_layout=True)
    short, common = labels(runs_of_env)
    for k, (name, frames) in enumerate(sorted(runs_of_env.items())):
        color = f"C{k % 10}"
        for ax, (column, label) in zip(axes, AXES):
            grid, mean, low, high = curve(frames, column, resamples)
            ax.plot(grid, mean, color=color, label=f"{short[name]} ({len(frames)} seeds)")
            ax.fill_between(grid, low, high, color=color, alpha=0.2, linewidth=0)
            ax.set_xlabel(label)
    axes[0].set_ylabel("population mean return")
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle(f"{env}: population mean return, mean over seeds, 95 % bootstrap CI ({common or 'paper settings'})", fontsize=9)
    return fig


def parse_args(argv: list) -> dict:
    """``key=value`` arguments (:mod:`imix_cli.keyvalue`, as every ``imix plot`` key) -> settings."""
    thresholds = dict(DEFAULT_THRESHOLDS)

    def threshold(key: str, value: str) -> None:
        if len(key) == len("threshold."):
            raise UsageError(f"unknown key {key!r} (expected threshold.<env id>)")
        thresholds[key[len("threshold.") :]] = finite_number(key, value)

    settings = parse_key_values(
        argv, "plot mujoco", {"results_dir": "results", "experiment": "mujoco", "resamples": 2000},
        convert={"results_dir": results_dir_value, "experiment": experiment_name, "resamples": at_least(100)},
        prefixed={"threshold.": threshold}, known="results_dir, experiment, threshold.<env id>, resamples",
    )  # fmt: skip
    return {**settings, "thresholds": thresholds}


HELP = """\
usage: imix plot mujoco [key=value ...]
       (or python -m imix_cli.plotting.mujoco [key=value ...], as make reproduce-mujoco runs it)

Draw the MuJoCo study's figures and table (make reproduce-mujoco, docs/research/mujoco.md)
from the seed CSVs of <results_dir>/<experiment>/<run>/ into <results_dir>/<experiment>/figures/:
mujoco_<env>.png/.pdf (the population's mean return against episodes, env steps and wall
time, one curve per run folder: the mean over seeds with a 95 % bootstrap CI) and
mujoco_table.csv/.md (per env and run: final return, the mean policy's return on fresh
episodes, the return at an equal episode budget, reuse rate, episodes, env steps, wall time,
and the episodes and time to the env's return threshold).

keys:
  results_dir=PATH              folder holding the experiments (default: results)
  experiment=NAME               experiment to plot (default: mujoco)
  threshold.<env id>=RETURN     return counted as reaching the threshold, by gymnasium id
                                (defaults: {thresholds})
  resamples=N                   bootstrap resamplings of the seeds, at least 100 (default: 2000)

example:
  imix plot mujoco experiment=mujoco threshold.Hopper-v5=800
"""


def _help_text() -> str:
    return HELP.format(thresholds=", ".join(f"{env}={value:g}" for env, value in DEFAULT_THRESHOLDS.items()))


def main(argv: list | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if help_requested(argv, _help_text):
        return 0
    try:
        settings = parse_args(argv)
    except UsageError as err:
        print(f"imix plot mujoco: {err}", file=sys.stderr)
        return 2
    exp_dir = Path(settings["results_dir"]) / settings["experiment"]
    runs = load_runs(exp_dir) if exp_dir.is_dir() else {}
    if not runs:
        print(f"imix plot mujoco: no run CSVs under {exp_dir}", file=sys.stderr)
        return 1
    out, root = exp_dir / "figures", settings["results_dir"]
    import matplotlib.pyplot as plt

    for env, runs_of_env in sorted(runs.items()):
        fig = draw_env(env, runs_of_env, settings["resamples"])
        for ext in ("png", "pdf"):
            path = out / f"mujoco_{env}.{ext}"
            write_figure(fig, path, root=root, dpi=150)
            print(f"wrote {path}")
        plt.close(fig)
    rows = table_rows(runs, settings["thresholds"], settings["resamples"])
    import pandas as pd

    atomic_write_text(out / "mujoco_table.csv", csv_text(pd.DataFrame(rows)), root=root)
    atomic_write_text(out / "mujoco_table.md", _markdown(rows), root=root)
    print(f"wrote {out / 'mujoco_table.csv'}\nwrote {out / 'mujoco_table.md'}")
    print(_markdown(rows), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
