"""The CSV contract between running and plotting -- the only module that touches result files.

Layout::

    <results_dir>/<experiment>/<algo>-<env>-<mixing>[-<overrides>]/seed_<k>.csv
    <results_dir>/<experiment>/<algo>-<env>-<mixing>[-<overrides>]/config.yaml

One row per generation (for DDPG: per finished episode), with exactly the columns
of :data:`COLUMNS`. Files are written by the one writer (:mod:`imix_cli.running.files.writing`): the data
goes to a temporary file in the same folder, is flushed to disk, then renamed over the final
name, so a reader (or a resumed run) never sees a half-written CSV, and no link in the run
folder is followed.
"""

from __future__ import annotations

import operator
import os
import re
import stat
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from imix_cli.running.files.writing import atomic_write_bytes, atomic_write_text  # noqa: F401 - the one writer (imix_cli.writing), used here and re-exported

if TYPE_CHECKING:
    import pandas as pd  # imported where used: a worker process writing plain rows never needs it (~0.25 s)

#: Column names and order of every run CSV (plots and outside tools rely on them).
COLUMNS = (
    "algo",  # algorithm name: openes | snes | cem | cmaes | ars | ddpg
    "env",  # environment config name (cartpole, acrobot, ...) or gymnasium id
    "mixing",  # none | im | eim
    "seed",  # seed index k of seed_<k>.csv
    "generation",  # 0-based generation (DDPG: episode index)
    "evaluations",  # cumulative episodes actually run
    "env_steps",  # cumulative environment steps actually run
    "mean_score",  # mean raw episode return over the generation (reused members with their stored return)
    "best_score",  # best raw episode return in the generation
    "reused",  # members taken from earlier generations
    "reused_im",  # ... of which from the previous generation
    "reused_eim",  # ... of which from older generations
    "reevaluated",  # reused members whose return was measured again this generation (reeval_age / reeval_prob)
    "popsize",  # members in the generation
    "sigma_mean",  # mean standard deviation of the search distribution
    "nonfinite",  # episodes of the generation whose return was NaN or inf (ranked last by the ES)
    "wall_time",  # seconds since the seed started
    "mean_policy_score",  # mean return of the distribution mean theta on fresh episodes (eval_mean_every; NaN on other rows)
    "mean_policy_episodes",  # cumulative episodes spent measuring theta (not counted in evaluations / env_steps)
    "diverged",  # 1 on the last row of a seed whose search distribution became non-finite (the seed ends there), else 0
)

#: Columns a row may leave out (:func:`rows_to_frame` fills them in): ``lockstep.generation_row`` leaves the distribution
#: mean's columns to whoever measures it, and ``diverged`` is set only on a diverged seed's last row.
_ROW_DEFAULTS = {"reevaluated": 0, "mean_policy_score": float("nan"), "mean_policy_episodes": 0, "diverged": 0}


_INT_COLUMNS = (
    "seed", "generation", "evaluations", "env_steps", "reused", "reused_im", "reused_eim", "reevaluated", "popsize", "nonfinite",
    "mean_policy_episodes", "diverged",
)  # fmt: skip
_FLOAT_COLUMNS = ("mean_score", "best_score", "sigma_mean", "wall_time", "mean_policy_score")


class CorruptResultError(ValueError):
    """A result file exists but does not follow the CSV contract."""


class ResultMismatchError(CorruptResultError):
    """A seed CSV follows the contract but contradicts the config of its run (:func:`imix_cli.running.seed_checks.check_seed_csv`)."""


#: The file that marks a run folder as an Optuna search's pruned trial (:mod:`imix_cli.commands.search`): its seeds stopped
#: early, at a stage of their generations; ``imix plot`` leaves the folder out. A later trial with the same parameters
#: continues the seeds and removes it.
PRUNED_FILE = "PRUNED"


def seed_csv_path(run_dir, seed: int) -> Path:
    return Path(run_dir) / f"seed_{seed}.csv"


def partial_csv_path(run_dir, seed: int) -> Path:
    """``seed_<k>.partial.csv``: the rows of an unfinished seed so far, its live view (same columns).

    Written atomically at each checkpoint and every few seconds between (not flushed: a live view, not a result;
    :mod:`imix_cli.running.files.run_writer`) and removed once ``seed_<k>.csv`` exists, so that
    ``imix plot`` and ``imix status`` can show a running experiment without touching the run.
    """
    return Path(run_dir) / f"seed_{seed}.partial.csv"


def run_dir_name(algo: str, env: str, mixing: str, overrides: str = "") -> str:
    """``<algo>-<env>-<mixing>[-<overrides>]`` (env ids such as ``imix/Foo-v0`` get their '/' replaced)."""
    name = f"{algo}-{env.replace('/', '_')}-{mixing}"
    return f"{name}-{overrides}" if overrides else name


def rows_to_frame(rows) -> pd.DataFrame:
    """Build a contract-conforming DataFrame from a list of dicts (one per generation)."""
    import pandas as pd

    frame = pd.DataFrame(list(rows))
    for column, value in _ROW_DEFAULTS.items():
        if column not in frame.columns:
            frame[column] = value
        frame[column] = frame[column].fillna(value).astype(type(value))
    missing = [c for c in COLUMNS if c not in frame.columns]
    if missing:
        raise ValueError(f"result rows lack columns {missing}")
    return frame.loc[:, list(COLUMNS)]


# ----------------------------------------------------------------------------- rows and their summary
def episode_row(*, algo: str, env: str, mixing: str, seed: int, index: int, env_steps: int, ret: float,
                sigma_mean: float, wall_time: float) -> dict:  # fmt: skip
    """The row of one finished training episode of a one-member learner (DDPG): generation = episode
    index, evaluations = episodes so far, mean_score = best_score = the return (NaN if not finite,
    then counted in ``nonfinite``), nothing reused, popsize 1."""
    finite = bool(np.isfinite(ret))
    score = float(ret) if finite else float("nan")
    return {
        "algo": algo, "env": env, "mixing": mixing, "seed": seed, "generation": index, "evaluations": index + 1,
        "env_steps": env_steps, "mean_score": score, "best_score": score, "reused": 0, "reused_im": 0,
        "reused_eim": 0, "reevaluated": 0, "mean_policy_score": float("nan"), "mean_policy_episodes": 0,
        "popsize": 1, "sigma_mean": sigma_mean, "nonfinite": 0 if finite else 1, "wall_time": wall_time,
    }  # fmt: skip


def seed_summary(frame) -> dict:
    """What a run's summary needs of one seed's rows: a contract-conforming frame (read or just
    written), or any mapping of column name to its values (:func:`write_run_csv`'s plain rows).

    ``theta``: the distribution mean's return on fresh episodes where it was last measured (NaN if never).
    ``stalled``: generations in which no member was evaluated (every one reused: ``reused == popsize``),
    what ``min_fresh`` >= 1 rules out (imix_cli/core/mixing/__init__.py, "A minimal refresh")."""

    def column(name):
        return np.asarray(frame[name])

    measured = column("mean_policy_score").astype(float)
    measured = measured[np.isfinite(measured)]
    return {
        "final": float(column("mean_score")[-1]),
        "theta": float(measured[-1]) if measured.size else float("nan"),
        "evaluations": int(column("evaluations")[-1]),
        "env_steps": int(column("env_steps")[-1]),
        "reused": int(column("reused").sum()),
        "members": int(column("popsize").sum()),
        "stalled": int(np.count_nonzero(column("reused") == column("popsize"))),
        "nonfinite": int(column("nonfinite").sum()),
        "mixing": str(column("mixing")[0]),
        "diverged": int(column("diverged")[-1] == 1),
    }


def es_seed_finished(frame, generations: int) -> bool:
    """Whether an ES seed whose CSV holds ``frame`` is finished in a run of ``generations``: it has them all, or
    fewer ending in a diverged row (a diverged seed stops there for good).

    The one notion of "finished" of every reader: ``imix run`` skips such a seed and continues (or refuses) any
    other (:func:`imix_cli.running.loop.es_seeds.needs_running`), ``imix status`` counts it done; a 1-of-30-row CSV is
    neither's finished seed."""
    return len(frame) >= generations or (len(frame) > 0 and int(frame["diverged"].iloc[-1]) == 1)


def write_run_csv(path, rows) -> dict:
    """Write one seed's rows (dicts, or a frame) atomically to ``path`` (``seed_<k>.csv``); return
    their :func:`seed_summary`.

    Rows of plain values (what generation rows hold) are formatted and summed up without pandas --
    the same text (:func:`rows_csv_text`) and the same numbers: a worker process that runs seeds
    then never imports pandas (~0.25 s of its start) and writes a seed's CSV in ~1 ms rather than ~13."""
    text = _plain_csv_text(rows, header=True) if isinstance(rows, list) and rows else None
    if text is None:
        frame = rows if not isinstance(rows, list) else rows_to_frame(rows)
        atomic_write_text(path, csv_text(frame))
        return seed_summary(frame)
    atomic_write_text(path, text)
    return seed_summary(_PlainColumns(rows))


class _PlainColumns:
    """Plain rows (:func:`_plain_csv_text` formats them) read by column, defaults filled in as
    :func:`rows_to_frame` fills them."""

    def __init__(self, rows: list):
        self.rows = rows

    def __getitem__(self, name: str) -> list:
        default = _ROW_DEFAULTS.get(name)
        return [row.get(name, default) for row in self.rows]


def rows_csv_text(rows: list, header: bool = True) -> str:
    """``csv_text(rows_to_frame(rows), header)`` -- the same text -- formatted directly when the rows
    hold what generation rows hold (ints, floats, plain strings), through pandas otherwise.

    Why: pandas costs ~4 ms a call whatever the number of rows, and a seed's live CSV gets its
    new rows at every checkpoint (``tests/test_compiled_loop.py`` checks the texts agree)."""
    text = _plain_csv_text(rows, header)
    return csv_text(rows_to_frame(rows), header) if text is None else text


#: How a seed CSV writes a float: 10 significant digits.
FLOAT_FORMAT = "%.10g"


def as_written(value: float) -> float:
    """``value`` as the seed CSV holds it (:data:`FLOAT_FORMAT`): what a reader of the CSV gets back."""
    return float(FLOAT_FORMAT % value)


def _plain_csv_text(rows: list, header: bool) -> str | None:
    """:func:`rows_csv_text`'s text of rows of plain values; None where a value needs pandas to decide.

    A row is formatted by one ``%`` of :data:`_PLAIN_ROW` (each column its ``%s``, ``%d`` or ``%.10g``), in C, and a
    NaN float's ``nan`` then made empty, as pandas writes it: 1000 rows in 3.8 ms instead of 6.1 (the same text;
    ``/tmp`` script), ~30 ms less for a worker's 13 seeds of the main job."""
    lines = [",".join(COLUMNS)] if header else []
    for row in rows:
        try:
            cells = _ROW_CELLS(row)
        except KeyError:  # a column the row leaves to its default
            cells = tuple(row.get(column, default) for column, default in _PLAIN_DEFAULTS)
        if tuple(map(type, cells)) != _PLAIN_TYPES:  # a missing column, NaN in an int column, a bool ...
            return None
        if not all(map(_QUOTED.isdisjoint, (cells[i] for i in _PLAIN_STRINGS))):  # a string pandas quotes
            return None
        line = _PLAIN_ROW % cells
        if "nan" in line:  # a NaN float (or a string holding "nan", left as it is): split at commas, which no cell holds
            parts = line.split(",")
            for i in _PLAIN_FLOATS:
                if parts[i] == "nan":
                    parts[i] = ""
            line = ",".join(parts)
        lines.append(line)
    return "".join(line + "\n" for line in lines)


#: What :func:`_plain_csv_text` formats itself: each column's value type, its default (where a row has
#: none: the class ``dict``, never of a column's type), where its floats and strings are, the
#: characters that make pandas quote a string, a row's cells and its format.
_PLAIN_TYPES = tuple(float if c in _FLOAT_COLUMNS else int if c in _INT_COLUMNS else str for c in COLUMNS)
_PLAIN_DEFAULTS = tuple((c, _ROW_DEFAULTS.get(c, dict)) for c in COLUMNS)
_PLAIN_FLOATS = tuple(i for i, kind in enumerate(_PLAIN_TYPES) if kind is float)
_PLAIN_STRINGS = tuple(i for i, kind in enumerate(_PLAIN_TYPES) if kind is str)
_QUOTED = frozenset(',"\r\n')
_ROW_CELLS = operator.itemgetter(*COLUMNS)
_PLAIN_ROW = ",".join(FLOAT_FORMAT if kind is float else "%d" if kind is int else "%s" for kind in _PLAIN_TYPES)


def csv_text(frame: pd.DataFrame, header: bool = True) -> str:
    """The text of a seed CSV of ``frame`` (:func:`rows_to_frame`'s); without ``header``, its rows only.
    Each value is formatted on its own (its column's type), so the text of consecutive frames
    concatenated is the text of the frame of all their rows."""
    return frame.to_csv(index=False, header=header, float_format=FLOAT_FORMAT, lineterminator="\n")


#: The largest seed CSV read back (a row is ~300 bytes: ~1 million generations or episodes). pandas
#: holds a CSV in memory, so this bounds what a results folder can make a reader allocate.
MAX_CSV_BYTES = 256 << 20
_SEED_NAME = re.compile(r"^seed_(\d+)(?:\.partial)?\.csv$")
#: Columns that count from the start of the seed: they never decrease from one row to the next.
_CUMULATIVE = ("evaluations", "env_steps", "mean_policy_episodes")


def regular_file_size(path) -> int:
    """The size of ``path`` if it is a regular file (after symlinks); OSError otherwise.

    Why: a results folder may hold anything under a result's name -- a symlink to ``/dev/zero``
    (endless: a reader would fill the memory), a FIFO (a reader would block forever). Every reader
    of imix's files asks this first and never opens anything but a regular file.
    """
    info = os.stat(path)
    if not stat.S_ISREG(info.st_mode):
        raise OSError(f"not a regular file ({_kind(info.st_mode)})")
    return info.st_size


#: The largest config.yaml (or checkpoint sidecar) imix reads back: a real one is a few kB.
MAX_CONFIG_BYTES = 1 << 20


def read_small_text(path, limit: int = MAX_CONFIG_BYTES) -> str:
    """The text of ``path`` if it is a regular file of at most ``limit`` bytes; OSError or ValueError otherwise.

    Why: a config.yaml is read back by run, plot, status and the summary; bounding it here keeps a
    huge file, ``/dev/zero`` or a FIFO under that name from filling the memory or blocking any of them."""
    size = regular_file_size(path)
    if size > limit:
        raise ValueError(f"{path}: {size:,} bytes, more than {limit:,}")
    return Path(path).read_text()


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "special"


def read_run_csv(path) -> pd.DataFrame:
    """Read and validate one seed's CSV; raise :class:`CorruptResultError` naming the file if it is not valid.

    The one reader of seed CSVs (run, plot, status, summaries), so that all of them accept the
    same files: every column of :data:`COLUMNS`, integer counts >= 0 in the integer columns,
    generations 0, 1, 2, ..., one algo/env/mixing, the seed of the file's name on every row,
    cumulative columns that never decrease, member counts within the population, finite
    ``sigma_mean`` and ``wall_time``. A file above :data:`MAX_CSV_BYTES` is refused unread.
    """
    path = Path(path)
    try:
        size = regular_file_size(path)
    except FileNotFoundError:
        raise
    except OSError as err:
        raise CorruptResultError(f"{path}: unreadable ({err.strerror or err})") from None
    if size > MAX_CSV_BYTES:
        raise CorruptResultError(f"{path}: {size:,} bytes, more than a seed CSV can hold ({MAX_CSV_BYTES:,})")
    import pandas as pd

    try:
        frame = pd.read_csv(path)
    except Exception as err:  # pandas raises many types for malformed files
        raise CorruptResultError(f"{path}: unreadable CSV ({type(err).__name__}: {_first_line(err)})") from None
    missing = [c for c in COLUMNS if c not in frame.columns]
    if missing:
        raise CorruptResultError(f"{path}: missing columns {missing}")
    if frame.empty:
        raise CorruptResultError(f"{path}: no rows")
    for column in _INT_COLUMNS + _FLOAT_COLUMNS:
        if not pd.api.types.is_numeric_dtype(frame[column]) or pd.api.types.is_bool_dtype(frame[column]):
            raise CorruptResultError(f"{path}: column {column!r} is not numeric")
    if frame[list(_INT_COLUMNS)].isna().any().any():
        raise CorruptResultError(f"{path}: missing values in integer columns")
    ints = frame[list(_INT_COLUMNS)].to_numpy(dtype=np.float64)
    if not np.all(np.isfinite(ints)) or np.any(ints < 0) or np.any(ints != np.round(ints)) or np.any(ints > 2.0**53):
        bad = next(c for c in _INT_COLUMNS if not _counts(frame[c].to_numpy(dtype=np.float64)))
        raise CorruptResultError(f"{path}: column {bad!r} holds values that are not counts (integers >= 0)")
    gens = frame["generation"].to_numpy()
    if not np.array_equal(gens, np.arange(len(frame))):
        raise CorruptResultError(f"{path}: generations are not 0, 1, 2, ...")
    for column in ("algo", "env", "mixing"):
        if frame[column].isna().any() or frame[column].astype(str).nunique() != 1:
            raise CorruptResultError(f"{path}: column {column!r} is not one value on every row")
    match = _SEED_NAME.match(path.name)
    if match and np.any(frame["seed"].to_numpy() != int(match.group(1))):
        raise CorruptResultError(f"{path}: its rows are of seed {sorted(set(frame['seed'].tolist()))[:3]}, its name says seed {match.group(1)} (a copy?)")
    decreasing = [c for c in _CUMULATIVE if np.any(np.diff(frame[c].to_numpy()) < 0)]
    if decreasing:
        raise CorruptResultError(f"{path}: cumulative column(s) {', '.join(decreasing)} decrease")
    popsize = frame["popsize"].to_numpy()
    reused = frame["reused"].to_numpy()
    if (
        np.any(popsize != popsize[0]) or np.any(popsize < 1) or np.any(reused > popsize) or np.any(frame["nonfinite"].to_numpy() > popsize)
        or np.any(frame["reevaluated"].to_numpy() > reused) or np.any(frame["diverged"].to_numpy() > 1)
    ):  # fmt: skip
        raise CorruptResultError(f"{path}: member counts (popsize, reused, reevaluated, nonfinite, diverged) out of range or popsize changes")
    for column in ("sigma_mean", "wall_time"):
        values = frame[column].to_numpy(dtype=np.float64)
        if not np.all(np.isfinite(values)) or np.any(values < 0):
            raise CorruptResultError(f"{path}: column {column!r} holds negative or non-finite values")
    _check_scores(frame, path)
    header = tuple(map(str, frame.columns))
    frame = frame.loc[:, list(COLUMNS)]
    frame.attrs["header"] = header  # the file's own columns, for check_seed_csv's schema check
    return frame


def _check_scores(frame, path) -> None:
    """CorruptResultError unless the score columns hold what a run writes: a finite number, or NaN -- the population's
    ``mean_score`` and ``best_score`` only on a generation where every member's return was non-finite (``nonfinite ==
    popsize``), ``mean_policy_score`` where the distribution mean was not measured -- never an infinity, and a mean
    at most the best. The env's possible returns are checked against the run's config
    (:func:`imix_cli.running.seed_checks.check_seed_scores`)."""
    scores = {c: frame[c].to_numpy(dtype=np.float64) for c in ("mean_score", "best_score", "mean_policy_score")}
    for column, values in scores.items():
        infinite = np.isinf(values)
        if infinite.any():
            row = int(np.argmax(infinite))
            raise CorruptResultError(f"{path}: {column}={values[row]} at generation {row}; a score is a finite return (NaN where none was measured)")
    all_nonfinite = frame["nonfinite"].to_numpy() == frame["popsize"].to_numpy()
    for column in ("mean_score", "best_score"):
        wrong = np.isnan(scores[column]) != all_nonfinite
        if wrong.any():
            row = int(np.argmax(wrong))
            what = "NaN" if np.isnan(scores[column][row]) else "a number"
            raise CorruptResultError(f"{path}: {column} is {what} at generation {row}, where {int(frame['nonfinite'].iloc[row])} of "
                                     f"{int(frame['popsize'].iloc[row])} members' returns were non-finite (NaN exactly when all were)")  # fmt: skip
    mean, best = scores["mean_score"], scores["best_score"]
    above = mean > best + 1e-9 * np.maximum(1.0, np.abs(best))
    if above.any():
        row = int(np.argmax(above))
        raise CorruptResultError(f"{path}: mean_score {mean[row]:.6g} above best_score {best[row]:.6g} at generation {row}")


def _counts(values: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(values)) and np.all(values >= 0) and np.all(values == np.round(values)) and np.all(values <= 2.0**53))


def _first_line(err: Exception) -> str:
    text = str(err).strip()
    return text.splitlines()[0][:200] if text else type(err).__name__
