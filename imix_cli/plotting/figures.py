"""Figures drawn from run CSVs, the shared style, and the registry of every figure.

REGISTRY -- to add a figure, write ``def my_figures(exp, opts)`` yielding
``(file_stem, matplotlib.figure.Figure)`` pairs and append a :class:`FigureSpec`
to :data:`FIGURES` at the bottom of this file; ``imix plot`` saves every figure
as ``<results_dir>/<experiment>/figures/<stem>.{png,pdf}`` and ``only=<name>``
selects it. Tables have the same kind of registry in :mod:`.tables`.

Data figures (mean over seeds, shaded 68 % Student-t CI of the mean; see
:mod:`.data` for the statistics and how seeds are aligned):

* ``convergence_<env>``   paper Figs 5-6: population mean return vs generation,
  one line per algorithm, one panel per mixing (without | with IM | with EIM);
* ``efficiency_<env>``    paper Figs 7-8: the same vs episodes evaluated;
* ``ddpg_<env>``          paper Figs 12-13: DDPG against the ES runs of the same
  env vs environment steps, log x-axis, mean (solid, shaded CI) and median (dotted);
* ``gridsearch_<algo>_<env>_<mixing>_<param>``  paper Figs 9-11: one line per
  value of popsize, sigma or lr (the other two fixed) vs episodes evaluated.

Colours: Okabe-Ito (colour-blind safe), one fixed colour per algorithm in every
figure (:func:`algo_color`); grid-search lines use the ordered ``viridis`` map.
Matplotlib is used without pyplot (``matplotlib.figure.Figure``), so no display
or backend state is involved.
"""

from __future__ import annotations

import contextlib
import io
import re
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter

from . import didactic
from .data import (
    HYPERPARAMS,
    Experiment,
    PlotOptions,
    align_by_generation,
    align_on_grid,
    mean_ci,
    rank_sweep,
    select_main_groups,
    sort_groups,
    sweep_families,
)

# --------------------------------------------------------------------------- style

#: Okabe & Ito (2008) colour-blind-safe palette.
OKABE_ITO = {
    "black": "#000000",
    "orange": "#E69F00",
    "sky_blue": "#56B4E9",
    "bluish_green": "#009E73",
    "yellow": "#F0E442",
    "blue": "#0072B2",
    "vermillion": "#D55E00",
    "reddish_purple": "#CC79A7",
}

#: The colour of each algorithm in every figure.
ALGO_COLORS = {
    "openes": OKABE_ITO["blue"],
    "snes": OKABE_ITO["vermillion"],
    "cem": OKABE_ITO["bluish_green"],
    "cmaes": OKABE_ITO["reddish_purple"],
    "ddpg": OKABE_ITO["black"],
}
_SPARE_COLORS = (OKABE_ITO["orange"], OKABE_ITO["sky_blue"], "#7F7F7F")

ALGO_NAMES = {"openes": "OpenES", "snes": "SNES", "cem": "CEM", "cmaes": "CMA-ES", "ddpg": "DDPG"}
ENV_NAMES = {
    "cartpole": "CartPole",
    "acrobot": "Acrobot",
    "continuous_cartpole": "ContinuousCartPole",
    "continuous_cartpole_hard": "ContinuousCartPoleHard",
}
MIXING_NAMES = {"none": "without mixing", "im": "with IM", "eim": "with EIM"}
MIXING_SHORT = {"none": "", "im": " + IM", "eim": " + EIM"}
PARAM_NAMES = {"popsize": "population size", "sigma": "initial σ", "lr": "learning rate"}

#: Algorithms that are not evolution strategies (no generations, no mixing): only in the DDPG figure.
NON_ES = {"ddpg"}

STYLE = {
    "font.size": 9,
    "axes.titlesize": 9.5,
    "axes.labelsize": 9,
    "legend.fontsize": 8.5,
    "figure.titlesize": 10.5,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "lines.linewidth": 1.5,
    "legend.frameon": False,
    "pdf.fonttype": 42,  # embed TrueType: text stays text in the PDF
    "savefig.dpi": 150,
}

BAND_ALPHA = 0.2


@contextlib.contextmanager
def style():
    """The rc settings of every imix figure."""
    with matplotlib.rc_context(STYLE):
        yield


def algo_color(algo: str) -> str:
    """Fixed colour per algorithm (unknown names get a spare colour chosen by a stable hash)."""
    if algo in ALGO_COLORS:
        return ALGO_COLORS[algo]
    return _SPARE_COLORS[zlib.crc32(algo.encode()) % len(_SPARE_COLORS)]


def algo_name(algo: str) -> str:
    return ALGO_NAMES.get(algo, algo)


def env_name(env: str) -> str:
    return ENV_NAMES.get(env, env)


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", text).strip("_") or "x"


def group_label(group, with_mixing: bool = False, with_overrides: bool = True) -> str:
    label = algo_name(group.algo) + (MIXING_SHORT.get(group.mixing, f" + {group.mixing}") if with_mixing else "")
    if with_overrides and group.overrides:
        label += f" ({group.overrides})"
    return label


def _short_number(value, _pos=None) -> str:
    if abs(value) >= 10_000:
        return f"{value / 1000:g}k"
    return f"{value:g}"


def new_figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), layout="constrained")


def save_figure(fig: Figure, out_dir: Path, stem: str, formats=("png", "pdf"), dpi: int = 150) -> list:
    """Write ``<out_dir>/<stem>.<fmt>`` for each format (no timestamps, so reruns give identical files)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for fmt in formats:
        path = out_dir / f"{stem}.{fmt}"
        if fmt == "png":
            _save_png(fig, path, dpi)
        else:
            metadata = {"pdf": {"CreationDate": None}, "svg": {"Date": None}}.get(fmt)
            fig.savefig(path, format=fmt, dpi=dpi, metadata=metadata)
        paths.append(path)
    return paths


def _save_png(fig: Figure, path: Path, dpi: int) -> None:
    """PNG reduced to a 256-colour palette (no dithering): about 3x smaller, no visible change for line art."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, metadata={"Software": None})
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - Pillow is a matplotlib dependency
        path.write_bytes(buffer.getvalue())
        return
    buffer.seek(0)
    with Image.open(buffer) as image:
        palette = image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        palette.save(path, format="png", optimize=True)


def _draw_band(ax, x, matrix, color, label, level, linestyle="-", median=False):
    mean, half, _ = mean_ci(matrix, level, axis=0)
    (line,) = ax.plot(x, mean, color=color, label=label, linestyle=linestyle)
    if np.any(np.isfinite(half)):
        ax.fill_between(x, mean - half, mean + half, color=color, alpha=BAND_ALPHA, linewidth=0)
    if median:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns (no seed there) give NaN: fine
            med = np.nanmedian(matrix, axis=0)
        ax.plot(x, med, color=color, linestyle=":", linewidth=1.3)
    return line


def _seeds_note(groups) -> str:
    counts = {g.n_seeds for g in groups}
    if len(counts) == 1:
        n = counts.pop()
        return f"{n} seed{'s' if n != 1 else ''}"
    most = max(counts)
    fewer = ", ".join(f"{algo_name(g.algo)} {g.n_seeds}" for g in groups if g.n_seeds < most)
    return f"{most} seeds; {fewer}"


_THRESHOLD_STYLE = dict(color="0.35", linestyle=(0, (4, 3)), linewidth=0.9)


def _threshold_line(ax, threshold):
    if threshold is not None:
        ax.axhline(threshold, zorder=1, **_THRESHOLD_STYLE)


def _add_threshold_entry(handles, labels, threshold):
    if threshold is not None:
        handles.append(Line2D([], [], **_THRESHOLD_STYLE))
        labels.append(f"threshold {threshold:g}")


# --------------------------------------------------------------------------- paper Figs 5-8


def _es_main_groups(exp: Experiment) -> list:
    return [g for g in select_main_groups(exp.groups) if g.algo not in NON_ES]


def _mixing_panels(exp, opts, env, groups, by_evaluations: bool) -> Figure:
    mixings = sorted({g.mixing for g in groups}, key=lambda m: ("none", "im", "eim").index(m) if m in ("none", "im", "eim") else 9)
    n = len(mixings)
    fig = new_figure(max(0.6 + 3.5 * n, 5.0), 3.4 if n > 1 else 3.7)
    axes = fig.subplots(1, n, sharey=True, squeeze=False)[0]
    handles = {}
    threshold = opts.thresholds.get(env) if by_evaluations else None
    for letter, ax, mixing in zip("abcdefgh", axes, mixings):
        panel = [g for g in groups if g.mixing == mixing]
        for group in panel:
            if by_evaluations:
                x, matrix = align_on_grid(group, "evaluations", "mean_score")
            else:
                x, matrix = align_by_generation(group, "mean_score")
            line = _draw_band(ax, x, matrix, algo_color(group.algo), algo_name(group.algo), opts.ci_level)
            handles.setdefault(group.algo, line)
        _threshold_line(ax, threshold)
        title = MIXING_NAMES.get(mixing, f"with {mixing}")
        ax.set_title(f"({letter}) {title}  [{_seeds_note(panel)}]", loc="left")
        ax.set_xlabel("episodes evaluated" if by_evaluations else "generation")
        ax.xaxis.set_major_formatter(FuncFormatter(_short_number))
        ax.set_xlim(left=0)
    axes[0].set_ylabel("population mean return")
    order = sorted(handles, key=lambda a: [g.algo for g in groups].index(a))
    legend_handles = [handles[a] for a in order]
    legend_labels = [algo_name(a) for a in order]
    _add_threshold_entry(legend_handles, legend_labels, threshold)
    fig.legend(legend_handles, legend_labels, loc="outside lower center", ncols=len(legend_handles))
    what = "episodes evaluated" if by_evaluations else "generation"
    title = f"{env_name(env)}: population mean return vs {what}"
    note = f"(mean ± {opts.ci_level:.0%} CI over seeds)"
    fig.suptitle(f"{title} {note}" if n > 1 else f"{title}\n{note}")
    return fig


def convergence_figures(exp: Experiment, opts: PlotOptions) -> Iterator:
    """Paper Figs 5-6: population mean return per generation, without and with mixing side by side."""
    groups = _es_main_groups(exp)
    for env in sorted({g.env for g in groups}):
        yield f"convergence_{slug(env)}", _mixing_panels(exp, opts, env, [g for g in groups if g.env == env], False)


def efficiency_figures(exp: Experiment, opts: PlotOptions) -> Iterator:
    """Paper Figs 7-8: population mean return vs cumulative episodes evaluated (step-aligned over seeds)."""
    groups = _es_main_groups(exp)
    for env in sorted({g.env for g in groups}):
        yield f"efficiency_{slug(env)}", _mixing_panels(exp, opts, env, [g for g in groups if g.env == env], True)


# --------------------------------------------------------------------------- paper Figs 12-13


def _best_es_group(exp, opts, algo, env):
    """The ES run of ``algo`` on ``env`` to set against DDPG: with mixing if any, the best sweep point if several."""
    candidates = [g for g in exp.groups if g.algo == algo and g.env == env]
    for mixing in ("eim", "im", "none"):
        pool = [g for g in candidates if g.mixing == mixing]
        if len(pool) == 1:
            return pool[0]
        if pool:
            return rank_sweep(pool, opts.thresholds.get(env), opts.ci_level)[0][0]
    return candidates[0] if candidates else None


def ddpg_figures(exp: Experiment, opts: PlotOptions) -> Iterator:
    """Paper Figs 12-13: DDPG vs the ES runs of the same env, return vs environment steps (log x).

    Solid line and band: mean ± CI over seeds; dotted line: median. DDPG rows are
    episodes, so its ``mean_score`` is an episode return. Each ES algorithm
    contributes one run (with EIM/IM if available, the best sweep point if
    several; see :func:`_best_es_group`).
    """
    for env in sorted({g.env for g in exp.groups if g.algo in NON_ES}):
        groups = [g for g in sort_groups(exp.groups) if g.env == env and g.algo in NON_ES]
        for algo in sorted({g.algo for g in exp.groups if g.env == env and g.algo not in NON_ES}, key=lambda a: [*ALGO_COLORS, a].index(a)):
            best = _best_es_group(exp, opts, algo, env)
            if best is not None:
                groups.append(best)
        fig = new_figure(6.4, 3.8)
        ax = fig.subplots()
        handles = []
        for group in groups:
            x, matrix = align_on_grid(group, "env_steps", "mean_score", log=True)
            label = group_label(group, with_mixing=group.algo not in NON_ES)
            if group.algo in NON_ES and len([g for g in groups if g.algo == group.algo]) == 1:
                label = group_label(group, with_overrides=False)
            handles.append(_draw_band(ax, x, matrix, algo_color(group.algo), f"{label} [{group.n_seeds} seeds]", opts.ci_level, median=True))
        _threshold_line(ax, opts.thresholds.get(env))
        ax.set_xscale("log")
        ax.set_xlabel("environment steps (log scale)")
        ax.set_ylabel("mean return (ES: population; DDPG: episode)")
        labels = [h.get_label() for h in handles]
        _add_threshold_entry(handles, labels, opts.thresholds.get(env))
        fig.legend(handles, labels, loc="outside lower center", ncols=min(len(handles), 2))
        fig.suptitle(
            f"{env_name(env)}: DDPG vs evolution strategies\n"
            f"(solid: mean ± {opts.ci_level:.0%} CI over seeds; dotted: median)"
        )
        yield f"ddpg_{slug(env)}", fig


# --------------------------------------------------------------------------- paper Figs 9-11


def sweep_slices(members, ranked) -> dict:
    """``param -> (fixed values, groups)``: for each hyper-parameter, the slice of the sweep that varies it.

    Groups are partitioned by the values of the other two hyper-parameters; the
    partition with the most distinct values of ``param`` is shown (ties: the one
    holding the best-ranked point, then the first). Works for one-at-a-time sweeps
    around a base point (as in the paper) and for full grids (slice through the best).
    """
    best = ranked[0][0] if ranked else None
    slices = {}
    for param in HYPERPARAMS:
        parts = {}
        for group in members:
            hp = group.hyperparams()
            fixed = tuple((k, hp[k]) for k in HYPERPARAMS if k != param)
            parts.setdefault(fixed, []).append(group)
        candidates = []
        for fixed, groups in parts.items():
            values = {g.hyperparams()[param] for g in groups}
            if len(values) >= 2 and None not in values:
                candidates.append((-len(values), best not in groups, fixed, groups))
        if candidates:
            candidates.sort(key=lambda c: (c[0], c[1]))
            _, _, fixed, groups = candidates[0]
            slices[param] = (fixed, sorted(groups, key=lambda g: g.hyperparams()[param]))
    return slices


def gridsearch_figures(exp: Experiment, opts: PlotOptions) -> Iterator:
    """Paper Figs 9-11: population mean return vs episodes evaluated, one line per popsize / σ / lr value."""
    for (algo, env, mixing), members in sweep_families([g for g in exp.groups if g.algo not in NON_ES]).items():
        threshold = opts.thresholds.get(env)
        ranked = rank_sweep(members, threshold, opts.ci_level)
        for param, (fixed, groups) in sweep_slices(members, ranked).items():
            fig = new_figure(6.0, 3.8)
            ax = fig.subplots()
            cmap = matplotlib.colormaps["viridis"]
            values = [g.hyperparams()[param] for g in groups]
            handles = []
            for i, (group, value) in enumerate(zip(groups, values)):
                color = cmap(0.85 * i / max(len(groups) - 1, 1))
                x, matrix = align_on_grid(group, "evaluations", "mean_score")
                label = f"{value:g}"
                if values.count(value) > 1:  # the same point run twice (e.g. base run and explicit override)
                    label += f" ({group.overrides or 'no overrides'})"
                handles.append(_draw_band(ax, x, matrix, color, f"{label}  [{group.n_seeds} seeds]", opts.ci_level))
            _threshold_line(ax, threshold)
            labels = [h.get_label() for h in handles]
            _add_threshold_entry(handles, labels, threshold)
            ax.set_xlabel("episodes evaluated")
            ax.set_ylabel("population mean return")
            ax.xaxis.set_major_formatter(FuncFormatter(_short_number))
            ax.set_xlim(left=0)
            ax.legend(handles, labels, title=PARAM_NAMES.get(param, param), loc="best")
            others = ", ".join(f"{PARAM_NAMES.get(k, k)} {v:g}" for k, v in fixed if v is not None)
            fig.suptitle(
                f"{algo_name(algo)}{MIXING_SHORT.get(mixing, '')} on {env_name(env)}: effect of the "
                f"{PARAM_NAMES.get(param, param)}\n({others}; mean ± {opts.ci_level:.0%} CI over seeds)"
            )
            yield f"gridsearch_{slug(algo)}_{slug(env)}_{slug(mixing)}_{param}", fig


# --------------------------------------------------------------------------- registry


@dataclass(frozen=True)
class FigureSpec:
    """One entry of the registry: ``draw(exp, opts)`` yields ``(file_stem, Figure)`` pairs."""

    name: str  # selector for `imix plot only=<name>`
    paper: str  # which figures of the paper it reproduces
    draw: Callable[[Experiment, PlotOptions], Iterator]
    needs_data: bool = True


#: Every figure `imix plot` draws, in order. Add new figures here.
FIGURES = [
    FigureSpec("didactic", "Figs 1-3", didactic.didactic_figures, needs_data=False),
    FigureSpec("convergence", "Figs 5-6", convergence_figures),
    FigureSpec("efficiency", "Figs 7-8", efficiency_figures),
    FigureSpec("gridsearch", "Figs 9-11", gridsearch_figures),
    FigureSpec("ddpg", "Figs 12-13", ddpg_figures),
]
