"""`imix plot`: figures and tables of the paper from the run CSVs of one experiment.

Reads ``<results_dir>/<experiment>/<run>/seed_<k>.csv`` through the CSV
contract (:mod:`imix_cli.running.files.results`; the runner is never imported) and writes
``<results_dir>/<experiment>/figures/``. What is drawn is listed in two
registries: :data:`.figures.FIGURES` and :data:`.tables.TABLES`.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

from imix_cli.keyvalue import UsageError, experiment_name, finite_number, flag, help_requested, parse_key_values, results_dir_value

HELP = """\
usage: imix plot [key=value ...]
       imix plot mujoco [key=value ...]   (the MuJoCo study: imix plot mujoco --help)

Draw the paper's figures and tables from the runs of one experiment into
<results_dir>/<experiment>/figures/ (each figure as PNG and PDF, each table
as CSV, Markdown and LaTeX).

keys:
  results_dir=PATH        folder holding the experiments (default: results)
  experiment=NAME         experiment to plot (default: default)
  measure=theta|population
                          what the efficiency figures, the threshold, iqm and
                          improvement tables and the profiles measure a run by
                          (default: theta, the distribution mean on fresh
                          episodes, free of reused returns; population: the last
                          generation's mean return with reused members' stored
                          returns, the paper's measure, drawn beside θ anyway)
  threshold.<env>=RETURN  return that counts as solved, for the
                          evaluations-to-threshold table (defaults: cartpole=195,
                          acrobot=-100, continuous_cartpole=195,
                          continuous_cartpole_hard=195; other envs are left out
                          unless given; threshold.<env>=none removes one)
  ci=LEVEL                confidence level of the shaded interval of the mean,
                          in (0, 1) (default: 0.68, as in the paper; Student t)
  only=NAME[,NAME...]     draw only these outputs, among:
                          {names}
  formats=FMT[,FMT...]    figure formats among png, pdf, svg (default: png,pdf)
  dpi=N                   resolution of PNG figures, 50-600 (default: 150)
  didactic=true|false     also draw the paper's three didactic figures (Figs 1-3,
                          no data needed; default: false). only=didactic draws
                          just those.

Figures show the mean over seeds with a shaded confidence interval of the mean
(Student t), clipped to the env's achievable returns. Against episodes
evaluated, each seed is put on a common grid by holding the score of its last
generation whose cumulative evaluations do not exceed the grid point; curves run
to the longest seed, dotted where fewer seeds remain. Every run folder is its own
curve, labelled with its non-default settings (grid-search points: gridsearch
figures). Seeds still running (seed_<k>.partial.csv) are included with their
rows so far (written every few seconds), with a warning. Groups with fewer than 5 seeds are flagged.

Robust statistics (Agarwal et al. 2021; 95 %, stratified bootstrap): the iqm table
(interquartile mean of final return and episodes to threshold), the improvement
table (probability that mixing needs fewer episodes than no mixing) and the
profile figures (performance profiles of the final return).
"""

_FORMATS = ("png", "pdf", "svg")
_ENV_NAME = re.compile(r"^[A-Za-z0-9_.:/-]+$")


def _registry_names() -> list:
    from .figures import FIGURES
    from .tables import TABLES

    return list(dict.fromkeys([f.name for f in FIGURES] + [t.name for t in TABLES]))


def _help_text() -> str:
    return HELP.format(names=", ".join(_registry_names()))


# ----------------------------------------------------------------------------- keys (imix_cli.keyvalue)
def _ci(key: str, value: str) -> float:
    level = finite_number(key, value)
    if not 0.0 < level < 1.0:
        raise UsageError(f"bad value for ci: {value!r} (expected a level in (0, 1), e.g. 0.68)")
    return level


def _only(key: str, value: str) -> tuple:
    names = [n.strip() for n in value.split(",") if n.strip()]
    known = _registry_names()
    bad = [n for n in names if n not in known]
    if not names or bad:
        raise UsageError(f"bad value for only: {value!r} (expected names among {', '.join(known)})")
    return tuple(names)


def _formats(key: str, value: str) -> tuple:
    fmts = [f.strip().lower().lstrip(".") for f in value.split(",") if f.strip()]
    if not fmts or any(f not in _FORMATS for f in fmts):
        raise UsageError(f"bad value for formats: {value!r} (expected some of {', '.join(_FORMATS)})")
    return tuple(dict.fromkeys(fmts))


def _measure(key: str, value: str) -> str:
    from .data import MEASURES

    if value not in MEASURES:
        raise UsageError(f"bad value for measure: {value!r} (expected {' or '.join(MEASURES)})")
    return value


def _dpi(key: str, value: str) -> int:
    try:
        dpi = int(value)
    except ValueError:
        raise UsageError(f"bad value for dpi: {value!r} (expected an integer)") from None
    if not 50 <= dpi <= 600:
        raise UsageError(f"bad value for dpi: {value!r} (expected 50 to 600)")
    return dpi


_DEFAULTS = {
    "results_dir": "results",
    "experiment": "default",
    "ci": 0.68,
    "only": None,
    "formats": ("png", "pdf"),
    "dpi": 150,
    "didactic": False,
    "measure": "theta",
}
_CONVERT = {
    "results_dir": results_dir_value,
    "experiment": experiment_name,
    "ci": _ci,
    "only": _only,
    "formats": _formats,
    "dpi": _dpi,
    "didactic": flag,
    "measure": _measure,
}
_KNOWN = "results_dir, experiment, measure, threshold.<env>, ci, only, formats, dpi, didactic"


def parse_args(argv: list) -> dict:
    """``key=value`` arguments -> settings dict; raises :class:`UsageError` naming the key."""
    from .data import DEFAULT_THRESHOLDS

    thresholds = dict(DEFAULT_THRESHOLDS)

    def threshold(key: str, value: str) -> None:
        env = key[len("threshold.") :]
        if not env or not _ENV_NAME.match(env):
            raise UsageError(f"bad key {key!r} (expected threshold.<env>, e.g. threshold.cartpole=195)")
        if value.lower() in ("none", "null", "off", ""):
            thresholds.pop(env, None)
        else:
            thresholds[env] = finite_number(key, value)

    settings = parse_key_values(argv, "plot", _DEFAULTS, convert=_CONVERT, prefixed={"threshold.": threshold}, known=_KNOWN)
    settings["thresholds"], settings["ci_level"] = thresholds, settings.pop("ci")
    return settings


def main(argv: list | None = None) -> int:
    """Entry point of ``imix plot``; ``argv`` excludes the ``plot`` word. Returns the exit status.

    0: everything selected was written; 1: no results to plot, or a figure/table
    failed (reported, the rest still written); 2: bad command line.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["mujoco"]:  # `imix plot mujoco ...`: the MuJoCo study's figures and table
        from .mujoco import main as mujoco_main

        return mujoco_main(argv[1:])
    if help_requested(argv, _help_text):
        return 0
    try:
        settings = parse_args(argv)
    except UsageError as err:
        print(f"imix plot: {err}", file=sys.stderr)
        return 2

    from .data import DEFAULT_THRESHOLDS, PlotOptions, load_experiment, select_main_groups
    from .figures import FIGURES, save_figure, style
    from .tables import TABLES, write_table

    only = settings["only"]
    asked = {"didactic"} if settings["didactic"] else set()
    figures = [f for f in FIGURES if (f.name in only if only is not None else not f.on_request or f.name in asked)]
    tables = [t for t in TABLES if only is None or t.name in only]
    needs_data = any(f.needs_data for f in figures) or bool(tables)

    exp_dir = Path(settings["results_dir"]) / settings["experiment"]
    if needs_data and not exp_dir.is_dir():
        print(
            f"imix plot: no results at {exp_dir} (check results_dir= and experiment=; only=didactic draws the figures that need no data)",
            file=sys.stderr,
        )
        return 1
    opts = PlotOptions(
        thresholds=settings["thresholds"],
        ci_level=settings["ci_level"],
        dpi=settings["dpi"],
        formats=settings["formats"],
        measure=settings["measure"],
    )
    exp = load_experiment(settings["results_dir"], settings["experiment"], warn=opts.warn)
    select_main_groups(exp.groups, warn=opts.warn)  # names the grid-search runs the main figures leave out
    if needs_data and not exp.groups:
        opts.warn(f"no readable runs under {exp_dir}; only figures that need no data are drawn")
    for env in sorted(set(settings["thresholds"]) - set(exp.envs()) - set(DEFAULT_THRESHOLDS)):
        opts.warn(f"threshold.{env} given but the experiment has no runs on env {env!r}")

    out_dir = exp_dir / "figures"
    status = 0
    written = 0
    with style():
        for spec in figures:
            if spec.needs_data and not exp.groups:
                continue
            try:
                for stem, fig in spec.draw(exp, opts):
                    for path in save_figure(fig, out_dir, stem, opts.formats, opts.dpi, root=settings["results_dir"]):
                        print(f"wrote {path}")
                        written += 1
            except (OSError, MemoryError) as err:  # a refused link, a full disk, no memory: the next file would fail the same way
                return _cannot_write(err)
            except Exception as err:  # noqa: BLE001 - one broken figure must not cost the others
                print(f"imix plot: error: figure {spec.name!r} failed: {type(err).__name__}: {err}", file=sys.stderr)
                status = 1
    if exp.groups:
        for spec in tables:
            try:
                for table in spec.build(exp, opts):
                    for path in write_table(table, out_dir, root=settings["results_dir"]):
                        print(f"wrote {path}")
                        written += 1
            except (OSError, MemoryError) as err:
                return _cannot_write(err)
            except Exception as err:  # noqa: BLE001
                print(f"imix plot: error: table {spec.name!r} failed: {type(err).__name__}: {err}", file=sys.stderr)
                status = 1
    if needs_data and not exp.groups:
        status = 1
    print(f"imix plot: {written} file(s) in {out_dir}")
    return status


def _cannot_write(err: OSError | MemoryError) -> int:
    """One line for a file that could not be written (a link refused by :mod:`imix_cli.running.files.writing`, a full disk); exit status 1.
    What was written before stays, and the file named keeps its old content. (A closed stdout is not a file: the
    command's boundary, imix_cli.commands.boundary, ends it silently; MemoryError too goes to it.)"""
    if isinstance(err, (BrokenPipeError, MemoryError)):
        raise err
    where = f" {err.filename}" if err.filename else ""
    print(f"imix plot: error: cannot write{where}: {err.strerror or err}", file=sys.stderr)
    return 1
