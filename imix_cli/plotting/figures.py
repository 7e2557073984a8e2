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
* ``efficiency_<env>``    paper Figs 7-8: the same vs episodes evaluated, no mixing and mixing
  overlaid on one axis (log x when their episode counts differ by 4x or more);
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
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter

from imix_cli.core.registry import ALGORITHM_SPECS, MIXING_NAMES, OKABE_ITO, algo_label, env_label, mixing_suffix, mixing_title
from imix_cli.core.registry import NON_ES_NAMES as NON_ES
from imix_cli.running.files.writing import atomic_write_bytes, write_figure

from . import didactic
from .data import (
    HYPERPARAMS,
    MEASURES,
    Experiment,
    PlotOptions,
    align_by_generation,
    align_on_grid,
    column_for,
    final_value,
    headline,
    mean_ci,
    rank_sweep,
    select_main_groups,
    sort_groups,
    sweep_families,
)

# --------------------------------------------------------------------------- style

#: Okabe & Ito (2008) colour-blind-safe palette.
#: The colour of each algorithm in every figure (:data:`imix_cli.core.registry.ALGORITHM_SPECS`).
ALGO_COLORS = {name: spec.color for name, spec in ALGORITHM_SPECS.items()}
_SPARE_COLORS = (OKABE_ITO["orange"], OKABE_ITO["sky_blue"], "#7F7F7F")

PARAM_NAMES = {"popsize": "population size", "sigma": "initial σ", "lr": "learning rate"}

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


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", text).strip("_") or "x"


def group_label(group, with_mixing: bool = False, with_overrides: bool = True) -> str:
    label = algo_label(group.algo) + (mixing_suffix(group.mixing) if with_mixing else "")
    if with_overrides and group.overrides:
        label += f" ({group.overrides})"
    return label


def _short_number(value, _pos=None) -> str:
    if abs(value) >= 10_000:
        return f"{value / 1000:g}k"
    return f"{value:g}"


def new_figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), layout="constrained")


def fitted_suptitle(fig: Figure, text: str, margin: float = 0.02, **kwargs):
    """``fig.suptitle(text)`` with each line too wide for the figure wrapped at spaces, so that none is cut.

    Constrained layout makes room above the axes for a title's lines but never narrows them: a title wider than
    its figure (a one-panel figure: the main job's convergence figure of a single run) lost both ends. Widths are
    measured with the Agg renderer at the figure's dpi, in the title's own font; ``margin``: the fraction of the
    width kept free on each side. A line that fits is kept as it is (the figures of several panels are unchanged).
    """
    from matplotlib.backends.backend_agg import RendererAgg

    title = fig.suptitle(text, **kwargs)
    dpi = fig.dpi
    renderer = RendererAgg(max(1, int(fig.bbox.width)), max(1, int(fig.bbox.height)), dpi)
    prop = title.get_fontproperties()
    room = fig.bbox.width * (1.0 - 2.0 * margin)

    def fits(line: str) -> bool:
        return renderer.get_text_width_height_descent(line, prop, ismath=False)[0] <= room

    lines = []
    for line in text.split("\n"):
        words, current = line.split(" "), ""
        for word in words:
            candidate = f"{current} {word}" if current else word
            if current and not fits(candidate):
                lines.append(current)
                candidate = word
            current = candidate
        lines.append(current)
    title.set_text("\n".join(lines))
    return title


def save_figure(fig: Figure, out_dir: Path, stem: str, formats=("png", "pdf"), dpi: int = 150, root=None) -> list:
    """Write ``<out_dir>/<stem>.<fmt>`` for each format (no timestamps, so reruns give identical files) through the
    one writer (:mod:`imix_cli.running.files.writing`; ``root``: the results folder, below which no link is followed)."""
    out_dir = Path(out_dir)
    paths = []
    for fmt in formats:
        path = out_dir / f"{stem}.{fmt}"
        if fmt == "png":
            atomic_write_bytes(path, _png_bytes(fig, dpi), root=root)
        else:
            metadata = {"pdf": {"CreationDate": None}, "svg": {"Date": None}}.get(fmt)
            write_figure(fig, path, root=root, format=fmt, dpi=dpi, metadata=metadata)
        paths.append(path)
    return paths


def _png_bytes(fig: Figure, dpi: int) -> bytes:
    """PNG reduced to a 256-colour palette (no dithering): about 3x smaller, no visible change for line art."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, metadata={"Software": None})
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - Pillow is a matplotlib dependency
        return buffer.getvalue()
    buffer.seek(0)
    out = io.BytesIO()
    with Image.open(buffer) as image:
        palette = image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        palette.save(out, format="png", optimize=True)
    return out.getvalue()


#: The returns an env can give (per episode), for clipping CI bands; other envs use the data's range.
RETURN_RANGES = {
    "cartpole": (0.0, 200.0),
    "acrobot": (-200.0, 0.0),
    "continuous_cartpole": (0.0, 200.0),
    "continuous_cartpole_hard": (0.0, 200.0),
}


def achievable_range(env: str, matrix) -> tuple:
    """The env's return range (:data:`RETURN_RANGES`), widened to the data's if they exceed it (an
    env.max_steps override); the data's own range for other envs. A mean cannot leave it."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        lo, hi = float(np.nanmin(matrix)), float(np.nanmax(matrix))
    if env in RETURN_RANGES:
        lo, hi = min(lo, RETURN_RANGES[env][0]), max(hi, RETURN_RANGES[env][1])
    return lo, hi


def _draw_band(ax, x, matrix, color, label, level, linestyle="-", median=False, clip=None):
    """Mean over seeds (solid where every seed has a value, dotted where fewer do) and its CI band,
    clipped to ``clip`` = (low, high) (the achievable range) if given."""
    mean, half, n = mean_ci(matrix, level, axis=0)
    full = np.where(n == matrix.shape[0], mean, np.nan)
    (line,) = ax.plot(x, full, color=color, label=label, linestyle=linestyle)
    if np.any((n > 0) & (n < matrix.shape[0])):
        fewer = np.where(n > 0, mean, np.nan)
        ax.plot(x, fewer, color=color, linestyle=":", linewidth=1.1, zorder=line.get_zorder() - 0.1)
    if np.any(np.isfinite(half)):
        low, high = mean - half, mean + half
        if clip is not None:
            low, high = np.clip(low, *clip), np.clip(high, *clip)
        ax.fill_between(x, low, high, color=color, alpha=BAND_ALPHA, linewidth=0)
    if median:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns (no seed there) give NaN: fine
            med = np.nanmedian(matrix, axis=0)
        ax.plot(x, med, color=color, linestyle=":", linewidth=1.3)
    return line


#: Fewer seeds than this: the group's CI is flagged as unreliable in captions and tables.
MIN_SEEDS = 5


def _seeds_note(groups) -> str:
    counts = {g.n_seeds for g in groups}
    flag = ", <5: weak CI" if min(counts) < MIN_SEEDS else ""
    running = sum(len(g.partial) for g in groups)
    flag += f", {running} running" if running else ""
    if len(counts) == 1:
        n = counts.pop()
        return f"{n} seed{'s' if n != 1 else ''}{flag}"
    most = max(counts)
    fewer = ", ".join(f"{algo_label(g.algo)} {g.n_seeds}" for g in groups if g.n_seeds < most)
    return f"{most} seeds; {fewer}{flag}"


def common_settings(groups) -> dict:
    """Non-default settings (the run folders' overrides) shared by every group: said once, in the title."""
    from .data import parse_overrides

    parsed = [parse_overrides(g.overrides) for g in groups]
    if not parsed:
        return {}
    return {k: v for k, v in parsed[0].items() if all(p.get(k) == v for p in parsed[1:])}


def settings_text(settings: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in sorted(settings.items()))


def own_settings_label(group, common: dict, with_mixing: bool = False) -> str:
    """Algorithm (+ mixing) and the group's non-default settings that are not common to the figure."""
    from .data import parse_overrides

    label = algo_label(group.algo) + (mixing_suffix(group.mixing) if with_mixing else "")
    own = {k: v for k, v in parse_overrides(group.overrides).items() if common.get(k) != v}
    if not own and group.overrides and "=" not in group.overrides:
        return f"{label} ({group.overrides})"  # a folder name of another form: keep it distinct
    return f"{label} ({settings_text(own)})" if own else label


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
    mixings = sorted({g.mixing for g in groups}, key=lambda m: MIXING_NAMES.index(m) if m in MIXING_NAMES else 9)
    n = len(mixings)
    # One panel (a single run, the main job): as wide as the efficiency figure, and taller for its wrapped title.
    fig = new_figure(max(0.6 + 3.5 * n, 6.6), 3.4 if n > 1 else 4.4)
    # A shared x-axis: with and without mixing on one scale, so the episodes saved show as distance.
    axes = fig.subplots(1, n, sharey=True, sharex=True, squeeze=False)[0]
    handles = {}
    threshold = opts.thresholds.get(env) if by_evaluations else None
    common = common_settings(groups)
    variants = {}  # runs of one algorithm with different settings: one line style each
    for group in groups:
        variants.setdefault(group.algo, {}).setdefault(own_settings_label(group, common), len(variants.get(group.algo, {})))
    styles = ("-", "--", "-.", (0, (5, 1, 1, 1)))
    for letter, ax, mixing in zip("abcdefgh", axes, mixings):
        panel = [g for g in groups if g.mixing == mixing]
        for group in panel:
            if by_evaluations:
                x, matrix = align_on_grid(group, "evaluations", "mean_score")
            else:
                x, matrix = align_by_generation(group, "mean_score")
            label = own_settings_label(group, common)
            style_ = styles[variants[group.algo][label] % len(styles)]
            line = _draw_band(ax, x, matrix, algo_color(group.algo), label, opts.ci_level, linestyle=style_, clip=achievable_range(env, matrix))
            handles.setdefault(label, line)
            if not by_evaluations:  # the distribution mean's own return, where it was measured
                gens, theta = align_by_generation(group, "mean_policy_score")
                measured = np.flatnonzero(np.isfinite(theta).any(axis=0))
                if measured.size:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", RuntimeWarning)
                        dots = np.nanmean(theta[:, measured], axis=0)
                    ax.plot(gens[measured], dots, color=algo_color(group.algo), linestyle="none", marker="o", markersize=2.2, alpha=0.8)
                    handles.setdefault(THETA_LABEL, Line2D([], [], color="0.35", linestyle="none", marker="o", markersize=3))
        _threshold_line(ax, threshold)
        title = mixing_title(mixing)
        ax.set_title(f"({letter}) {title}  [{_seeds_note(panel)}]", loc="left")
        ax.set_xlabel("episodes evaluated" if by_evaluations else "generation")
        ax.xaxis.set_major_formatter(FuncFormatter(_short_number))
        ax.set_xlim(left=0)
    axes[0].set_ylabel("population mean return")
    legend_labels = list(handles)
    legend_handles = [handles[label] for label in legend_labels]
    _add_threshold_entry(legend_handles, legend_labels, threshold)
    fig.legend(legend_handles, legend_labels, loc="outside lower center", ncols=min(len(legend_handles), 5))
    what = "episodes evaluated" if by_evaluations else "generation"
    title = f"{env_label(env)}: population mean return vs {what}"
    note = f"(mean ± {opts.ci_level:.0%} Student-t CI over seeds, clipped to the achievable returns; dotted: fewer seeds"
    note += ")" if by_evaluations else ";\ndots: return of the distribution mean θ on fresh episodes, mean over seeds)"
    if common:
        title += f"; {settings_text(common)}"
    fitted_suptitle(fig, f"{title}\n{note}{_left_out_note(exp, env)}")
    return fig


#: Legend entry of the distribution mean's measured return (CSV column mean_policy_score).
THETA_LABEL = "distribution mean θ (dots)"


def convergence_figures(exp: Experiment, opts: PlotOptions) -> Iterator:
    """Paper Figs 5-6: population mean return per generation, without and with mixing side by side."""
    groups = _es_main_groups(exp)
    for env in sorted({g.env for g in groups}):
        yield f"convergence_{slug(env)}", _mixing_panels(exp, opts, env, [g for g in groups if g.env == env], False)


def efficiency_figures(exp: Experiment, opts: PlotOptions) -> Iterator:
    """Paper Figs 7-8, on one axis: return vs cumulative episodes evaluated, no mixing (dashed) and mixing
    (solid) of each algorithm overlaid, so the episodes mixing saves show as the horizontal distance between
    two lines of one colour. The bands are the headline measure (:func:`headline`: θ on fresh episodes by
    default), thin lines the other one (the paper plotted the population mean). Log x when the runs' episode
    counts differ by :data:`LOG_X_RATIO` or more (mixing's curves would otherwise sit in the leftmost few per cent)."""
    groups = _es_main_groups(exp)
    for env in sorted({g.env for g in groups}):
        yield f"efficiency_{slug(env)}", _efficiency_overlay(exp, opts, env, efficiency_groups(exp, env))


#: Episode counts of the runs differing by this factor or more: the efficiency figure's x axis is logarithmic.
LOG_X_RATIO = 4.0

#: Line style of each mixing setting in the overlaid efficiency figure.
MIXING_LINESTYLES = {"none": (0, (4, 2)), "im": "-.", "eim": "-"}


def efficiency_curves(groups, column: str = "mean_score") -> tuple[bool, list]:
    """The data an efficiency figure draws: whether its x axis is logarithmic, and per group ``(group, x,
    matrix)``, each seed's ``column`` (population mean return, or θ held between its measurements) on the
    common grid ``x`` of episodes evaluated (a row per seed). ``python -m imix_cli.commands.docs_numbers``
    writes it next to the README's figure."""
    finals = [max(f["evaluations"].iloc[-1] for f in g.frames()) for g in groups]
    firsts = [min(f["evaluations"].iloc[0] for f in g.frames()) for g in groups]
    log = min(finals) > 0 and min(firsts) > 0 and max(finals) / min(finals) >= LOG_X_RATIO
    return log, [(group, *align_on_grid(group, "evaluations", column_for(group, column), log=log)) for group in groups]


def efficiency_groups(exp: Experiment, env: str) -> list:
    """The runs the efficiency figure of ``env`` overlays (the main groups: no grid-search points)."""
    return [g for g in _es_main_groups(exp) if g.env == env]


def _efficiency_overlay(exp, opts, env, groups) -> Figure:
    column, measure = headline(groups, opts, f"efficiency_{slug(env)}")
    other_column, other = next(m for m in MEASURES.values() if m[0] != column)
    log, curves = efficiency_curves(groups, column)
    _, beside = efficiency_curves(groups, other_column)
    fig = new_figure(6.6, 4.4)
    ax = fig.subplots()
    common = common_settings(groups)
    threshold = opts.thresholds.get(env)
    handles = []
    for (group, x, matrix), (_, x2, matrix2) in zip(curves, beside):
        label = own_settings_label(group, common, with_mixing=True)
        style_ = MIXING_LINESTYLES.get(group.mixing, ":")
        handles.append(_draw_band(ax, x, matrix, algo_color(group.algo), label, opts.ci_level, linestyle=style_, clip=achievable_range(env, matrix)))
        if group.algo not in NON_ES and np.isfinite(matrix2).any():  # the other measure, thin, without a band
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                ax.plot(x2, np.nanmean(matrix2, axis=0), color=algo_color(group.algo), linestyle=style_, linewidth=0.7, alpha=0.45)
    _threshold_line(ax, threshold)
    labels = [h.get_label() for h in handles]
    handles.append(Line2D([], [], color="0.35", linewidth=0.7, alpha=0.6))
    labels.append(f"thin: {other}")
    _add_threshold_entry(handles, labels, threshold)
    if log:
        ax.set_xscale("log")
        ax.set_xlabel("episodes evaluated (log scale)")
    else:
        ax.set_xlabel("episodes evaluated")
        ax.set_xlim(left=0)
    ax.xaxis.set_major_formatter(FuncFormatter(_short_number))
    ax.set_ylabel(measure)
    fig.legend(handles, labels, loc="outside lower center", ncols=min(len(handles), 3))
    title = f"{env_label(env)}: {measure} vs episodes evaluated"
    if common:
        title += f"; {settings_text(common)}"
    note = f"(dashed: no mixing, solid: mixing; mean ± {opts.ci_level:.0%} Student-t CI over seeds;\n{_seeds_note(groups)}; dotted: fewer seeds)"
    fitted_suptitle(fig, f"{title}\n{note}{_left_out_note(exp, env)}")
    return fig


def _left_out_note(exp, env) -> str:
    """What the main figures of ``env`` leave out (grid-search points), said in the figure itself."""
    shown = {id(g) for g in select_main_groups(exp.groups)}
    left_out = [g for g in exp.groups if g.env == env and g.algo not in NON_ES and id(g) not in shown]
    if not left_out:
        return ""
    return f"\nnot shown: {len(left_out)} grid-search run(s) with settings of their own (gridsearch figures)"


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
            if group.algo not in NON_ES:  # the settings the run used (its config.yaml), not only the non-default ones
                label = f"{group_label(group, with_mixing=True, with_overrides=False)} ({es_settings_text(group)})"
            flag = ", <5: CI unreliable" if group.n_seeds < MIN_SEEDS else ""
            handles.append(
                _draw_band(
                    ax,
                    x,
                    matrix,
                    algo_color(group.algo),
                    f"{label} [{group.n_seeds} seeds{flag}]",
                    opts.ci_level,
                    median=True,
                    clip=achievable_range(env, matrix),
                )
            )
        _threshold_line(ax, opts.thresholds.get(env))
        ax.set_xscale("log")
        ax.set_xlabel("environment steps (log scale)")
        ax.set_ylabel("mean return (ES: population; DDPG: episode)")
        labels = [h.get_label() for h in handles]
        _add_threshold_entry(handles, labels, opts.thresholds.get(env))
        fig.legend(handles, labels, loc="outside lower center", ncols=min(len(handles), 2))
        fitted_suptitle(fig, f"{env_label(env)}: DDPG vs evolution strategies\n(solid: mean ± {opts.ci_level:.0%} CI over seeds; dotted: median)")
        yield f"ddpg_{slug(env)}", fig


def _uses_lr(algo: str) -> bool:
    spec = ALGORITHM_SPECS.get(algo)
    return spec is not None and spec.uses_lr


def es_settings_text(group) -> str:
    """``popsize 10, σ 0.1, lr 0.1, 1500 generations, weight_decay_form=estool``: from the run's config.yaml
    (then its folder name), so that a legend states what the run actually used."""
    hp = group.hyperparams()
    parts = [f"popsize {hp['popsize']:g}" if hp.get("popsize") is not None else None,
             f"σ {hp['sigma']:g}" if hp.get("sigma") is not None else None,
             f"lr {hp['lr']:g}" if hp.get("lr") is not None and _uses_lr(group.algo) else None]  # fmt: skip
    generations = group.config.get("generations")
    if isinstance(generations, int) and not isinstance(generations, bool):
        parts.append(f"{generations} generations")
    form = group.config.get("weight_decay_form")
    if form and form != "paper":
        parts.append(f"weight_decay_form={form}")
    return ", ".join(p for p in parts if p) or group.overrides or "paper settings"


# --------------------------------------------------------------------------- performance profiles


def profile_figures(exp: Experiment, opts: PlotOptions) -> Iterator:
    """Performance profiles (Agarwal et al. 2021) of the final return (the headline measure, :func:`headline`), per env.

    For each return tau, the fraction of runs (seeds) whose final return exceeds
    tau, with a 95 % stratified-bootstrap band (:func:`imix_cli.core.stats.performance_profile_ci`).
    A curve further up and right is better everywhere, not only on average.
    """
    from imix_cli.core.stats import performance_profile_ci

    groups = select_main_groups(exp.groups)
    for env in sorted({g.env for g in groups}):
        members = [g for g in groups if g.env == env]
        column, measure = headline(members, opts, f"profile_{slug(env)}")
        finals = {g.name: np.array([final_value(f, column_for(g, column)) for f in g.frames()]) for g in members}
        values = np.concatenate(list(finals.values()))
        values = values[np.isfinite(values)]
        if values.size == 0:
            continue
        lo, hi = profile_range(values, opts.thresholds.get(env))
        taus = np.linspace(lo, hi, 201)
        fig = new_figure(6.4, 3.9)
        ax = fig.subplots()
        common = common_settings(members)
        for i, group in enumerate(members):
            scores = finals[group.name][np.isfinite(finals[group.name])]
            if scores.size == 0:
                continue
            point, low, high = performance_profile_ci(scores, taus, level=0.95, seed=i)
            color = algo_color(group.algo)
            style_ = "-" if group.mixing != "none" else "--"
            label = f"{own_settings_label(group, common, with_mixing=True)} [{group.n_seeds}]"
            ax.step(taus, point, where="post", color=color, linestyle=style_, label=label)
            ax.fill_between(taus, low, high, step="post", color=color, alpha=BAND_ALPHA, linewidth=0)
        threshold = opts.thresholds.get(env)
        if threshold is not None:
            ax.axvline(threshold, zorder=1, label=f"threshold {threshold:g}", **_THRESHOLD_STYLE)
        ax.set_xlim(lo, hi)
        ax.set_xlabel(f"final {measure} τ")
        ax.set_ylabel("fraction of runs with return > τ")
        ax.set_ylim(-0.02, 1.02)
        ax.legend(loc="best", fontsize=7.5)
        title = f"{env_label(env)}: performance profile of the final return"
        if common:
            title += f"; {settings_text(common)}"
        fitted_suptitle(fig, f"{title}\n(run-score distribution, 95 % stratified-bootstrap band; [seeds]; {_seeds_note(members)})")
        yield f"profile_{slug(env)}", fig


def profile_range(values, threshold=None) -> tuple:
    """The τ axis of a performance profile: the final returns' range (and the threshold), padded by 5 %.
    Not the env's achievable range: CartPole's runs end in 170-200 of 0-200, where the curves differ."""
    points = np.append(values, [] if threshold is None else [threshold])
    lo, hi = float(np.min(points)), float(np.max(points))
    pad = 0.05 * (hi - lo) if hi > lo else max(1.0, 0.05 * abs(hi))
    return lo - pad, hi + pad


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
                handles.append(_draw_band(ax, x, matrix, color, f"{label}  [{group.n_seeds} seeds]", opts.ci_level, clip=achievable_range(env, matrix)))
            _threshold_line(ax, threshold)
            labels = [h.get_label() for h in handles]
            _add_threshold_entry(handles, labels, threshold)
            ax.set_xlabel("episodes evaluated")
            ax.set_ylabel("population mean return")
            ax.xaxis.set_major_formatter(FuncFormatter(_short_number))
            ax.set_xlim(left=0)
            ax.legend(handles, labels, title=PARAM_NAMES.get(param, param), loc="best")
            others = ", ".join(f"{PARAM_NAMES.get(k, k)} {v:g}" for k, v in fixed if v is not None)
            fitted_suptitle(
                fig,
                f"{algo_label(algo)}{mixing_suffix(mixing, '')} on {env_label(env)}: effect of the "
                f"{PARAM_NAMES.get(param, param)}\n({others}; mean ± {opts.ci_level:.0%} CI over seeds)",
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
    on_request: bool = False  # drawn only when asked (only=<name> or <name>=true): not rewritten into every experiment


def _study_figures(exp: Experiment, opts: PlotOptions) -> Iterator:
    from .study import study_figures  # optuna is imported only where the experiment holds a study

    yield from study_figures(exp, opts)


#: Every figure `imix plot` draws, in order. Add new figures here.
FIGURES = [
    FigureSpec("didactic", "Figs 1-3", didactic.didactic_figures, needs_data=False, on_request=True),
    FigureSpec("convergence", "Figs 5-6", convergence_figures),
    FigureSpec("efficiency", "Figs 7-8", efficiency_figures),
    FigureSpec("gridsearch", "Figs 9-11", gridsearch_figures),
    FigureSpec("ddpg", "Figs 12-13", ddpg_figures),
    FigureSpec("profile", "Agarwal et al. 2021", profile_figures),
    FigureSpec("study", "an Optuna search (imix run -m hydra/sweeper=optuna)", _study_figures, needs_data=False),
]
