"""Load run CSVs into groups, and the statistics every figure and table shares.

Only :mod:`imix_cli.running.files.results` touches result files; this module goes through
:func:`~imix_cli.running.files.results.read_run_csv` and never imports the runner (the CSV
contract is the seam between running and plotting).

Grouping
    One group per run folder ``<algo>-<env>-<mixing>[-<overrides>]``: the
    algorithm, environment and mixing come from the CSV columns, the overrides
    suffix (a sweep point such as ``popsize=10,sigma=0.1``) from the folder name,
    and the hyper-parameters from ``config.yaml`` (then from the suffix).

Robustness
    A missing, unreadable or corrupt ``seed_<k>.csv`` is skipped with a warning
    naming the file; a group with fewer seeds than the others, or whose seeds
    stop at different generations, is flagged with a warning. Nothing here raises
    on bad data.

Statistics
    :func:`mean_ci` -- mean over seeds and the half-width of a two-sided
    confidence interval *of the mean* (default 68 %, as in the paper) from the
    Student t distribution with n - 1 degrees of freedom:
    ``t_{(1+level)/2, n-1} * s / sqrt(n)`` with ``s`` the sample standard
    deviation (ddof = 1). With 25 seeds this is 1.02 SEM; with 3 seeds 1.19 SEM.
    One seed gives no interval (NaN, no band drawn).

    :func:`align_by_generation` -- seeds share the generation axis; the matrix runs
    to the longest seed, NaN where a seed has no row (an in-progress seed, a seed of
    another length). Means and CIs at a point use the seeds present there; figures
    draw the part where every seed is present solid and the rest dotted, so curves
    never stop silently at the shortest seed nor hide that fewer seeds remain.

    :func:`align_on_grid` -- seeds have different evaluation counts per generation
    (reused members cost nothing), so each seed's curve is put on a common grid
    of evaluations by a *step (zero-order hold)* rule: at budget x the seed's
    value is that of its last generation whose cumulative evaluations are <= x,
    i.e. the population the algorithm had once it had spent x episodes.
    Generations that cost no episode (full reuse) share an evaluation count with
    the one before; the later generation wins. The grid runs from the largest
    first-generation count to the largest final count over the seeds; beyond a
    seed's last generation its value is NaN (fewer seeds, drawn dotted).

Running experiments
    A seed without ``seed_<k>.csv`` but with ``seed_<k>.partial.csv`` (written by
    the runner at each checkpoint and every few seconds between) is read as in progress: its rows so
    far join the group, and a warning names the run and those seeds.

    :func:`first_crossing` / :func:`threshold_stats` -- evaluations needed for a
    score (θ on fresh episodes, ``mean_policy_score``, by default: :func:`headline`; or the
    population mean, ``mean_score``) to first reach a threshold: the cumulative
    ``evaluations`` of the first generation whose score ``>= threshold``.
    Seeds that never reach it are counted (``reached`` of ``n_seeds``) and left
    out of the mean, CI and median, which are therefore conditional on success.
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from imix_cli.core.registry import ALGO_NAMES, MIXING_NAMES, NON_ES_NAMES, plot_thresholds
from imix_cli.core.stats import mean_ci  # noqa: F401  (re-exported: figures and tables use it)
from imix_cli.running.files.results import PRUNED_FILE, CorruptResultError, ResultMismatchError, read_run_csv, run_dir_name, seed_csv_path
from imix_cli.running.files.safe_yaml import BadYamlError, load_yaml_file
from imix_cli.running.seed_checks import check_seed_csv

__all__ = [
    "PlotOptions",
    "RunGroup",
    "Experiment",
    "load_experiment",
    "select_main_groups",
    "mean_ci",
    "align_by_generation",
    "align_on_grid",
    "first_crossing",
    "final_value",
    "column_for",
    "headline",
    "MEASURES",
    "THETA",
    "threshold_stats",
    "reuse_stats",
    "HYPERPARAMS",
]

#: Default thresholds on the population mean return (``threshold.<env>=`` overrides, ``=none`` removes):
#: the presets' of :data:`imix_cli.core.registry.ENV_SPECS` (:func:`~imix_cli.core.registry.plot_thresholds`).
DEFAULT_THRESHOLDS = plot_thresholds()

#: Algorithms whose rows are episodes (one per finished episode within an env-step budget): their
#: seeds have different row counts by design, so that is not flagged. The non-ES algorithms.
EPISODE_ROW_ALGOS = NON_ES_NAMES

#: Hyper-parameters a grid search varies (read from config.yaml, then the folder's overrides suffix).
HYPERPARAMS = ("popsize", "sigma", "lr")

_SEED_FILE = re.compile(r"^seed_(\d+)(\.partial)?\.csv$")
#: Sub-folders of an experiment that are not runs.
_NOT_RUNS = {"figures"}


def _stderr_warn(message: str) -> None:
    print(f"imix plot: warning: {message}", file=sys.stderr)


#: CSV column of the distribution mean θ's return on fresh episodes (every ``eval_mean_every`` generations, NaN between).
THETA = "mean_policy_score"

#: What a headline figure or table measures a run by (``imix plot measure=``): CSV column and its name in the outputs.
#: ``theta`` (the default): θ on fresh episodes, free of reused returns. ``population``: the last generation's mean
#: return, reused members counted with the returns they were stored with -- the paper's measure, which on noisy tasks
#: flatters mixing (selection keeps the reused members whose stored episodes were lucky).
MEASURES = {"theta": (THETA, "θ on fresh episodes"), "population": ("mean_score", "population mean return")}


@dataclass
class PlotOptions:
    """Everything the figure and table builders need besides the data."""

    thresholds: dict = field(default_factory=lambda: dict(DEFAULT_THRESHOLDS))
    ci_level: float = 0.68
    dpi: int = 150
    formats: tuple = ("png", "pdf")
    warn: Callable[[str], None] = _stderr_warn
    measure: str = "theta"  # a key of MEASURES: what the efficiency figures, threshold, iqm, improvement tables and profiles use


def has_theta(group) -> bool:
    """Whether every seed of ``group`` measured θ at least once (``eval_mean_every`` > 0)."""
    return all(np.isfinite(f[THETA].to_numpy(dtype=float)).any() for f in group.frames())


def headline(groups, opts: PlotOptions, output: str) -> tuple[str, str]:
    """``(column, name)`` of the measure ``output`` ranks ``groups`` by: ``opts.measure``'s, or, for θ when a run never
    measured it (``eval_mean_every=0``), the population mean for the whole output, with one warning naming the runs
    (one output never mixes two measures)."""
    if opts.measure == "theta":
        missing = [g.name for g in groups if g.algo not in NON_ES_NAMES and not has_theta(g)]
        if not missing:
            return MEASURES["theta"]
        opts.warn(f"{output}: no θ measured in {', '.join(missing)} (eval_mean_every=0): the population mean (stored returns) is used instead")
    return MEASURES["population"]


def column_for(group, column: str) -> str:
    """The column that holds ``column``'s measure for ``group``: a learner that is not an ES (DDPG) has no θ column, and
    its rows' returns are its own fresh episodes (nothing reused), so its ``mean_score`` stands for both measures."""
    return "mean_score" if group.algo in NON_ES_NAMES else column


def final_value(frame, column: str) -> float:
    """A seed's final value of ``column``: its last row's, or for θ (measured every few generations) the last measured one."""
    values = frame[column].to_numpy(dtype=float)
    if column == THETA:
        values = values[np.isfinite(values)]
        return float(values[-1]) if values.size else math.nan
    return float(values[-1])


@dataclass
class RunGroup:
    """All seeds of one run folder."""

    algo: str
    env: str
    mixing: str
    overrides: str
    path: Path
    config: dict
    seeds: dict  # seed index -> DataFrame (contract columns)
    partial: frozenset = frozenset()  # seeds read from seed_<k>.partial.csv (still running)

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def n_seeds(self) -> int:
        return len(self.seeds)

    @property
    def key(self) -> tuple:
        return (self.algo, self.env, self.mixing, self.overrides)

    def frames(self) -> list:
        return [self.seeds[k] for k in sorted(self.seeds)]

    def hyperparams(self) -> dict:
        """popsize, sigma and lr of the run: config.yaml's values, then the overrides suffix's."""
        found = {}
        for key in HYPERPARAMS:
            value = self.config.get(key)
            if value is None and isinstance(self.config.get("algo"), dict):
                value = self.config["algo"].get(key)
            found[key] = _as_number(value)
        for key, value in parse_overrides(self.overrides).items():
            short = key.rsplit(".", 1)[-1].lstrip("+")
            if short in HYPERPARAMS:
                found[short] = _as_number(value)
        return found


@dataclass
class Experiment:
    results_dir: Path
    name: str
    groups: list

    @property
    def path(self) -> Path:
        return Path(self.results_dir) / self.name

    def envs(self) -> list:
        return sorted({g.env for g in self.groups})


def _as_number(value):
    if value is None or isinstance(value, bool):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return int(number) if number.is_integer() and not isinstance(value, float) else number


def parse_overrides(text: str) -> dict:
    """``"popsize=10,sigma=0.1"`` -> ``{"popsize": "10", "sigma": "0.1"}`` (pieces without '=' are ignored)."""
    out = {}
    for piece in text.split(","):
        if "=" in piece:
            key, value = piece.split("=", 1)
            out[key.strip()] = value.strip()
    return out


def read_run_config(path: Path, warn, fallback: str = "hyper-parameters taken from the folder name") -> dict:
    """A run's ``config.yaml`` as a dict: ``{}`` if it is absent, or unreadable (``warn`` then says so
    and what the caller does instead, ``fallback``). Read through imix's one bounded YAML loader
    (:func:`imix_cli.running.files.safe_yaml.load_yaml_file`): data only, size, nesting and expanded aliases bounded."""
    if not path.exists():
        return {}
    try:
        data = load_yaml_file(path)  # a huge file (or /dev/zero), an alias bomb, a Python tag: refused unbuilt
    except BadYamlError as err:  # names the file and why, in a bounded line
        warn(f"{err}; {fallback}")
        return {}
    except Exception as err:  # noqa: BLE001 - any other error: keep going without the config
        warn(f"{path}: unreadable config.yaml ({type(err).__name__}); {fallback}")
        return {}
    return data if isinstance(data, dict) else {}


def _load_group(run_dir: Path, warn) -> RunGroup | None:
    found = {}
    for path in run_dir.iterdir():
        match = _SEED_FILE.match(path.name)
        if match:  # a finished seed's CSV wins over its partial one (removed right after)
            seed, partial = int(match.group(1)), bool(match.group(2))
            if seed not in found or (found[seed][1] and not partial):
                found[seed] = (path, partial)
    csvs = [(seed, path) for seed, (path, _) in found.items()]
    partial_seeds = frozenset(seed for seed, (_, partial) in found.items() if partial)
    if not csvs:
        warn(f"{run_dir}: no seed_<k>.csv files; skipped")
        return None
    seeds, fingerprints = {}, {}
    identity = None
    config = read_run_config(run_dir / "config.yaml", warn)
    for seed, path in sorted(csvs):
        try:
            frame = read_run_csv(path)
            check_seed_csv(frame, path, config)  # a CSV that contradicts its run's config.yaml is not one of its seeds
        except ResultMismatchError as err:
            warn(f"skipped {err}")
            continue
        except CorruptResultError as err:
            warn(f"skipped corrupt result {err}")
            continue
        except OSError as err:
            if seed in partial_seeds and seed_csv_path(run_dir, seed).exists():  # finished while we listed
                try:
                    frame, partial_seeds = read_run_csv(seed_csv_path(run_dir, seed)), partial_seeds - {seed}
                    check_seed_csv(frame, seed_csv_path(run_dir, seed), config)
                except (CorruptResultError, OSError):
                    continue
            else:
                warn(f"skipped unreadable result {path}: {err}")
                continue
        ident = tuple(frame[c].astype(str).unique().tolist() for c in ("algo", "env", "mixing"))
        if any(len(values) != 1 for values in ident):
            warn(f"skipped corrupt result {path}: algo/env/mixing change between rows")
            continue
        ident = tuple(values[0] for values in ident)
        decreasing = [c for c in ("evaluations", "env_steps") if np.any(np.diff(frame[c].to_numpy()) < 0)]
        if decreasing:
            warn(f"skipped corrupt result {path}: cumulative column(s) {', '.join(decreasing)} decrease")
            continue
        if identity is None:
            identity = ident
        elif ident != identity:
            warn(f"skipped {path}: it is a {'-'.join(ident)} run, the rest of {run_dir.name} is {'-'.join(identity)}")
            continue
        # A seed's rows are its own: identical scores, episodes and wall times are a copy of another seed's CSV.
        fingerprint = tuple(frame[c].to_numpy(dtype=float).tobytes() for c in ("evaluations", "env_steps", "mean_score", "best_score", "wall_time"))
        twin = next((other for other, fp in fingerprints.items() if fp == fingerprint), None)
        if twin is not None:
            warn(f"skipped {path}: the same rows as seed_{twin}'s CSV (a copy?); counted once")
            continue
        fingerprints[seed] = fingerprint
        frame = frame.copy()
        for column in ("mean_score", "best_score"):
            values = frame[column].to_numpy(dtype=float)
            frame[column] = np.where(np.isfinite(values), values, np.nan)
        seeds[seed] = frame
    if identity is None:
        warn(f"{run_dir}: no readable seed CSV; group skipped")
        return None
    algo, env, mixing = identity
    prefix = run_dir_name(algo, env, mixing)
    if run_dir.name == prefix:
        overrides = ""
    elif run_dir.name.startswith(prefix + "-"):
        overrides = run_dir.name[len(prefix) + 1 :]
    else:
        overrides = run_dir.name  # unexpected folder name: keep it distinct from the standard group
    running = sorted(partial_seeds & set(seeds))
    if running:
        warn(f"{run_dir.name}: seed(s) {', '.join(map(str, running))} still running; their rows so far (the live view) are included")
    return RunGroup(algo, env, mixing, overrides, run_dir, config, seeds, frozenset(running))


def load_experiment(results_dir, experiment: str, warn: Callable[[str], None] = _stderr_warn) -> Experiment:
    """Read every run folder of ``<results_dir>/<experiment>``; bad files are skipped with a warning."""
    exp_dir = Path(results_dir) / experiment
    groups, pruned = [], []
    if exp_dir.is_dir():
        for run_dir in sorted(p for p in exp_dir.iterdir() if p.is_dir()):
            if run_dir.name in _NOT_RUNS or run_dir.name.startswith((".", "_")):
                continue
            if (run_dir / PRUNED_FILE).is_file():  # an Optuna search's trial stopped early: partial results, not a run's
                pruned.append(run_dir.name)
                continue
            group = _load_group(run_dir, warn)
            if group is not None:
                groups.append(group)
    if pruned:
        warn(f"{len(pruned)} run folder(s) of trials an Optuna search pruned are left out (their seeds stopped early; file {PRUNED_FILE}): {', '.join(pruned)}")
    _flag_uneven(groups, warn)
    return Experiment(Path(results_dir), experiment, groups)


def _flag_uneven(groups: list, warn) -> None:
    if not groups:
        return
    most = max(g.n_seeds for g in groups)
    for group in groups:
        expected = group.config.get("seeds")
        if isinstance(expected, (list, tuple)):
            expected = len(expected)
        expected = expected if isinstance(expected, int) and not isinstance(expected, bool) else 0
        target = max(most, expected)
        if group.n_seeds < target:
            source = "config.yaml asks for" if expected >= most and expected > group.n_seeds else "other groups have"
            warn(
                f"{group.name} has only {group.n_seeds} seed(s) ({', '.join(map(str, sorted(group.seeds)))}) "
                f"while {source} {target}; its mean and CI rest on fewer runs"
            )
        lengths = {len(f) for f in group.seeds.values()}
        if len(lengths) > 1 and group.algo not in EPISODE_ROW_ALGOS:
            warn(
                f"{group.name}: seeds stop at different generations ({min(lengths)} to {max(lengths)} rows); "
                f"curves continue to the longest, dotted where fewer seeds remain"
            )


def _algo_rank(algo: str) -> tuple:
    order = ALGO_NAMES
    return (order.index(algo), algo) if algo in order else (len(order), algo)


MIXING_ORDER = MIXING_NAMES


def _mixing_rank(mixing: str) -> int:
    return MIXING_ORDER.index(mixing) if mixing in MIXING_ORDER else len(MIXING_ORDER)


def sort_groups(groups) -> list:
    return sorted(groups, key=lambda g: (g.env, _algo_rank(g.algo), _mixing_rank(g.mixing), g.overrides))


def select_main_groups(groups, warn: Callable[[str], None] | None = None) -> list:
    """The groups of the paper's main figures and tables: every run folder, but grid searches.

    Every run folder is its own curve / row (labelled with its non-default settings), except the
    points of a grid search (:func:`sweep_families`: runs of one algorithm, env and mixing at two
    or more popsize / sigma / lr points), which the grid-search figures and ranking show; of those,
    only the folder without overrides (if any) is kept, and ``warn`` names the ones left out.
    """
    swept = {id(g) for members in sweep_families(groups).values() for g in members}
    chosen = [g for g in groups if id(g) not in swept or not g.overrides]
    left_out = sorted(g.name for g in groups if id(g) in swept and g.overrides)
    if warn is not None and left_out:
        warn(f"{len(left_out)} grid-search run(s) left out of the main figures and tables (shown by the gridsearch figures and ranking): {', '.join(left_out)}")
    return sort_groups(chosen)


# --------------------------------------------------------------------------- statistics


def align_by_generation(group: RunGroup, column: str = "mean_score"):
    """``(generations, Y)`` with ``Y[s, g]`` the value of seed s at generation g, up to the longest
    seed (NaN after a seed's last row)."""
    frames = group.frames()
    length = max(len(f) for f in frames)
    matrix = np.full((len(frames), length), np.nan)
    for row, frame in zip(matrix, frames):
        row[: len(frame)] = frame[column].to_numpy(dtype=float)
    return np.arange(length), matrix


def _step_values(x, y, grid):
    """Zero-order hold: value of the last point with x <= grid (NaN before the first / after the last)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    keep = np.append(x[1:] != x[:-1], True)  # last row of each run of equal x
    x, y = x[keep], y[keep]
    idx = np.searchsorted(x, grid, side="right") - 1
    out = y[np.clip(idx, 0, len(y) - 1)]
    return np.where((idx >= 0) & (grid <= x[-1]), out, np.nan)


def align_on_grid(group: RunGroup, x: str = "evaluations", y: str = "mean_score", points: int = 400, log: bool = False):
    """``(grid, Y)``: every seed's ``y`` on a common grid of ``x`` (see the module docstring).

    The grid spans [max of first x, max of last x] over seeds (from min of first x
    if the seeds do not overlap), NaN outside each seed's range; it is geometric
    when ``log`` is true (x must then be positive).
    """
    frames = group.frames()
    xs = [f[x].to_numpy(dtype=float) for f in frames]
    lo = max(v[0] for v in xs)
    hi = max(v[-1] for v in xs)
    if min(v[-1] for v in xs) < lo:
        lo = min(v[0] for v in xs)
    if log:
        lo = max(lo, 1.0)
        hi = max(hi, lo)
        grid = np.geomspace(lo, hi, points)
    else:
        grid = np.linspace(lo, hi, points)
    if grid.size:
        grid[0], grid[-1] = lo, hi  # exact end points despite rounding
    # θ is measured every few generations: held from one measurement to the next (NaN before the first)
    values = [f[y].ffill() if y == THETA else f[y] for f in frames]
    matrix = np.vstack([_step_values(xv, v.to_numpy(dtype=float), grid) for xv, v in zip(xs, values)])
    return grid, matrix


def first_crossing(frame: pd.DataFrame, threshold: float, score: str = "mean_score", cost: str = "evaluations"):
    """``cost`` at the first row whose ``score >= threshold``, or None if the seed never reaches it."""
    scores = frame[score].to_numpy(dtype=float)
    hits = np.flatnonzero(scores >= threshold)
    if hits.size == 0:
        return None
    return float(frame[cost].to_numpy()[hits[0]])


def threshold_stats(group: RunGroup, threshold: float, level: float = 0.68, cost: str = "evaluations", score: str = "mean_score") -> dict:
    """Evaluations to first reach ``threshold`` (by ``score``): mean, CI half-width and median over the seeds that reach it.

    ``reached`` counts those seeds out of ``n_seeds``; with none, the statistics are NaN.
    """
    values = [first_crossing(f, threshold, score=score, cost=cost) for f in group.frames()]
    hit = [v for v in values if v is not None]
    if hit:
        mean, half, _ = mean_ci(hit, level)
        median = float(np.median(hit))
    else:
        mean = half = median = math.nan
    return {"n_seeds": len(values), "reached": len(hit), "mean": mean, "ci": half, "median": median, "values": values}


def reuse_stats(group: RunGroup, level: float = 0.68) -> dict:
    """Reuse of one group, per seed then averaged over seeds (percentages).

    total = 100 * sum(reused) / sum(popsize) over all generations (generation 0,
    which has nothing to reuse, included); from_im / from_eim = 100 * sum(reused_im)
    / sum(reused) and 100 * sum(reused_eim) / sum(reused) (NaN for a seed that
    reused nothing).
    """
    total, from_im, from_eim = [], [], []
    for frame in group.frames():
        reused = float(frame["reused"].sum())
        total.append(100.0 * reused / max(float(frame["popsize"].sum()), 1.0))
        from_im.append(100.0 * float(frame["reused_im"].sum()) / reused if reused else math.nan)
        from_eim.append(100.0 * float(frame["reused_eim"].sum()) / reused if reused else math.nan)
    t_mean, t_ci, _ = mean_ci(total, level)
    im_mean, im_ci, _ = mean_ci(from_im, level)
    eim_mean, eim_ci, _ = mean_ci(from_eim, level)
    return {
        "n_seeds": group.n_seeds,
        "total": t_mean,
        "total_ci": t_ci,
        "from_im": im_mean,
        "from_im_ci": im_ci,
        "from_eim": eim_mean,
        "from_eim_ci": eim_ci,
    }


def final_score(group: RunGroup, level: float = 0.68):
    """Mean (and CI) over seeds of the population mean score at each seed's last generation."""
    return mean_ci([f["mean_score"].to_numpy(dtype=float)[-1] for f in group.frames()], level)


# --------------------------------------------------------------------------- grid searches


def sweep_families(groups) -> dict:
    """``(algo, env, mixing) -> [groups]`` for every combination run at two or more hyper-parameter points.

    These are the grid searches of the paper (Figs 9-11: SNES + EIM at several
    popsize / sigma / lr); points are told apart by :meth:`RunGroup.hyperparams`.
    """
    by_combo = {}
    for group in groups:
        by_combo.setdefault((group.algo, group.env, group.mixing), []).append(group)
    families = {}
    for combo, members in by_combo.items():
        points = {tuple(sorted(g.hyperparams().items(), key=lambda kv: kv[0])) for g in members}
        if len(members) >= 2 and len(points) >= 2:
            families[combo] = sort_groups(members)
    return families


def rank_sweep(members, threshold, level: float = 0.68) -> list:
    """Sweep points best first, as ``(group, stats)``.

    With a threshold: most seeds reaching it first (as a fraction), then fewest
    mean evaluations to reach it, then highest final score. Without one: highest
    final population mean return. ``stats`` holds the :func:`threshold_stats`
    fields (NaN without a threshold) plus ``final`` and ``final_ci``.
    """
    rows = []
    for group in members:
        if threshold is None:
            info = {"n_seeds": group.n_seeds, "reached": 0, "mean": math.nan, "ci": math.nan, "median": math.nan}
        else:
            info = threshold_stats(group, threshold, level)
        info["final"], info["final_ci"], _ = final_score(group, level)
        rows.append((group, info))

    def key(item):
        info = item[1]
        final = info["final"] if np.isfinite(info["final"]) else -np.inf
        if threshold is None:
            return (-final,)
        mean = info["mean"] if np.isfinite(info["mean"]) else np.inf
        return (-info["reached"] / max(info["n_seeds"], 1), mean, -final)

    return sorted(rows, key=key)
