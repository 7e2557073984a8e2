"""Didactic figures of the paper drawn by the code itself (no result files): Figs 1, 2 and 3.

* ``didactic_rejection_sampling`` (Fig 1): points drawn uniformly in a box C1
  around a 1-D density f; those under the curve (accepted) are uniform under f
  and their abscissas are distributed as f (Theorems 1-2).
* ``didactic_importance_mixing`` (Fig 2): Algorithm 2 between two 1-D Gaussians.
  Old sample z ~ p_old is drawn at height rand1 * p_old(z): Rule 1 (accept with
  probability min(1, p_new/p_old)) accepts it exactly when that point lies in the
  overlap min(p_old, p_new) (shaded). New sample z' ~ p_new is drawn at height
  (1 - rand2) * p_new(z'): Rule 2 (accept with probability
  max(0, 1 - p_old/p_new)) accepts it exactly when that point lies above p_old,
  in the leftover part of the area under p_new.
* ``didactic_extended_importance_mixing`` (Fig 3): Algorithm 3 over three
  generations: the new generation is filled first from generation g-1 (pass
  k = 1), then, when still short, from generation g-2 (pass k = 2), each pass
  pairing Rule 1 on the archived generation with Rule 2 against its density.

The accept/reject rules are implemented here directly (this module does not
depend on :mod:`imix_cli.core.mixing`) with fixed seeds, so the figures are identical
on every run. For Fig 3 the seed is the first one, counting from 0, whose draw
actually needs the second pass and reuses a sample from it -- the case the
figure is meant to show (on average the first pass fills the generation about
half of the time, see the paper's section 4).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle

# Okabe-Ito colours (same palette as figures.py).
BLUE = "#0072B2"
VERMILLION = "#D55E00"
GREEN = "#009E73"
PURPLE = "#CC79A7"
ORANGE = "#E69F00"
GREY = "#7F7F7F"
OVERLAP_FILL = "#BFBFBF"


def gauss_pdf(z, mean: float, std: float):
    z = np.asarray(z, dtype=float)
    return np.exp(-0.5 * ((z - mean) / std) ** 2) / (std * np.sqrt(2.0 * np.pi))


@dataclass
class Gauss1D:
    mean: float
    std: float

    def pdf(self, z):
        return gauss_pdf(z, self.mean, self.std)

    def sample(self, n: int, rng) -> np.ndarray:
        return rng.normal(self.mean, self.std, size=n)


# --------------------------------------------------------------------------- Algorithms 2-3 in 1-D


@dataclass
class Trial:
    """One tried sample: where it is drawn in the (z, height) plane and what happened to it."""

    z: float
    height: float  # rand1 * p_old(z) for old samples, (1 - rand2) * p_new(z) for new ones
    source: str  # "old" (Rule 1) or "new" (Rule 2) or "fill" (drawn after the loop, accepted as is)
    accepted: bool
    passno: int = 1  # k of Algorithm 3 (1 = previous generation)
    removed: bool = False  # dropped because the generation overflowed to N + 1


@dataclass
class MixResult:
    trials: list = field(default_factory=list)
    untried: dict = field(default_factory=dict)  # pass -> abscissas of old samples never tried

    def members(self) -> list:
        return [t for t in self.trials if t.accepted and not t.removed]


def extended_importance_mixing(new: Gauss1D, archive: list, n: int, rng, fill: bool = True) -> MixResult:
    """Algorithm 3 (Algorithm 2 when ``archive`` has one entry) in 1-D.

    ``archive`` is ``[(density, samples), ...]``, most recent generation first.
    For each archived generation k and each i: draw rand1, rand2; accept old
    z_i with probability min(1, p_new/p_k) (Rule 1); draw z'_i ~ p_new and accept
    it with probability max(0, 1 - p_k/p_new) (Rule 2); stop once the generation
    holds N members. If it overflowed to N + 1, one random member is removed; if
    it is short after the last pass, it is filled with plain draws from p_new.
    """
    result = MixResult()
    size = 0
    for k, (old, samples) in enumerate(archive, start=1):
        for i, z in enumerate(samples):
            rand1, rand2 = rng.uniform(size=2)
            p_new_z, p_old_z = new.pdf(z), old.pdf(z)
            accept_old = min(1.0, p_new_z / p_old_z) > rand1
            result.trials.append(Trial(float(z), float(rand1 * p_old_z), "old", bool(accept_old), k))
            size += accept_old
            z_new = float(new.sample(1, rng)[0])
            p_new_n, p_old_n = new.pdf(z_new), old.pdf(z_new)
            accept_new = max(0.0, 1.0 - p_old_n / p_new_n) > rand2
            result.trials.append(Trial(z_new, float((1.0 - rand2) * p_new_n), "new", bool(accept_new), k))
            size += accept_new
            if size >= n:
                result.untried[k] = [float(v) for v in samples[i + 1 :]]
                break
        if size >= n:
            break
    if size > n:
        kept = [t for t in result.trials if t.accepted]
        kept[rng.integers(len(kept))].removed = True
    while fill and size < n:
        z = float(new.sample(1, rng)[0])
        result.trials.append(Trial(z, float(rng.uniform() * new.pdf(z)), "fill", True, 0))
        size += 1
    return result


# --------------------------------------------------------------------------- drawing helpers


def _figure(width, height) -> Figure:
    return Figure(figsize=(width, height), layout="constrained")


def _shade_regions(ax, grid, p_old, p_new, old_color, label_old="", label_new=""):
    low = np.minimum(p_old, p_new)
    ax.fill_between(grid, 0, low, color=OVERLAP_FILL, alpha=0.6, linewidth=0, label=label_old or None)
    ax.fill_between(grid, low, p_new, color=VERMILLION, alpha=0.13, linewidth=0, label=label_new or None)


def _draw_trials(ax, trials, old_color, new_color=VERMILLION):
    groups = {
        ("old", True): dict(marker="o", color=old_color, filled=True),
        ("old", False): dict(marker="o", color=old_color, filled=False),
        ("new", True): dict(marker="^", color=new_color, filled=True),
        ("new", False): dict(marker="^", color=new_color, filled=False),
        ("fill", True): dict(marker="s", color=ORANGE, filled=True),
    }
    for (source, accepted), spec in groups.items():
        pts = [t for t in trials if t.source == source and t.accepted == accepted]
        if not pts:
            continue
        ax.scatter(
            [t.z for t in pts],
            [t.height for t in pts],
            marker=spec["marker"],
            s=34,
            facecolors=spec["color"] if spec["filled"] else "white",
            edgecolors=spec["color"],
            linewidths=1.1,
            zorder=4,
        )
    removed = [t for t in trials if t.removed]
    if removed:
        ax.scatter([t.z for t in removed], [t.height for t in removed], marker="x", s=60, color="black", zorder=5)


def _trial_legend(trials, old_color, old_name="old", new_color=VERMILLION):
    def count(source, accepted):
        return sum(1 for t in trials if t.source == source and t.accepted == accepted)

    def marker(m, color, filled):
        return Line2D([], [], linestyle="", marker=m, markersize=6, markerfacecolor=color if filled else "white", markeredgecolor=color, markeredgewidth=1.1)

    handles = [
        (marker("o", old_color, True), f"{old_name} sample, accepted (Rule 1): {count('old', True)}"),
        (marker("o", old_color, False), f"{old_name} sample, rejected: {count('old', False)}"),
        (marker("^", new_color, True), f"new draw, accepted (Rule 2): {count('new', True)}"),
        (marker("^", new_color, False), f"new draw, rejected: {count('new', False)}"),
    ]
    if count("fill", True):
        handles.append((marker("s", ORANGE, True), f"fill draw from p_new: {count('fill', True)}"))
    if any(t.removed for t in trials):
        handles.append((Line2D([], [], linestyle="", marker="x", color="black"), "removed (overflow to N+1)"))
    return handles


# --------------------------------------------------------------------------- Fig 1


def rejection_sampling_figure(seed: int = 3, n_points: int = 220) -> Figure:
    """Fig 1: uniform points in a box; those under the density f are kept."""
    rng = np.random.default_rng(seed)
    lo, hi = -3.0, 3.0

    def f(z):
        return 0.6 * gauss_pdf(z, -1.0, 0.55) + 0.4 * gauss_pdf(z, 1.2, 0.7)

    grid = np.linspace(lo, hi, 600)
    top = 1.12 * f(grid).max()
    xs = rng.uniform(lo, hi, n_points)
    ys = rng.uniform(0.0, top, n_points)
    under = ys <= f(xs)

    fig = _figure(6.4, 3.6)
    ax = fig.subplots()
    ax.grid(False)
    ax.add_patch(Rectangle((lo, 0.0), hi - lo, top, fill=False, edgecolor="0.2", linewidth=1.0, zorder=2))
    ax.fill_between(grid, 0, f(grid), color=GREEN, alpha=0.15, linewidth=0)
    ax.plot(grid, f(grid), color=GREEN, linewidth=1.8, zorder=3)
    ax.scatter(xs[under], ys[under], s=16, color=GREEN, zorder=4)
    ax.scatter(xs[~under], ys[~under], s=18, marker="x", color=VERMILLION, linewidths=1.0, zorder=4)
    ax.set_xlim(lo - 0.25, hi + 0.25)
    ax.set_ylim(0, top * 1.05)
    ax.set_xlabel("z")
    ax.set_ylabel("density")
    handles = [
        Line2D([], [], color=GREEN, linewidth=1.8),
        Patch(facecolor="none", edgecolor="0.2"),
        Line2D([], [], linestyle="", marker="o", color=GREEN, markersize=4.5),
        Line2D([], [], linestyle="", marker="x", color=VERMILLION, markersize=5),
    ]
    labels = [
        "target density f",
        "box C₁ (sampled uniformly)",
        f"accepted: under f ({int(under.sum())})",
        f"rejected: above f ({int((~under).sum())})",
    ]
    fig.legend(handles, labels, loc="outside right center")
    ax.set_title("Rejection sampling: uniform points in C₁ that land under f\nare uniform under f, so their abscissas follow f", loc="left")
    return fig


# --------------------------------------------------------------------------- Fig 2


FIG2_OLD = Gauss1D(-0.5, 0.9)
FIG2_NEW = Gauss1D(0.6, 0.75)


def importance_mixing_figure(seed: int = 7, n: int = 12) -> Figure:
    """Fig 2: Algorithm 2 between N(-0.5, 0.9²) (old) and N(0.6, 0.75²) (new), N = 12."""
    rng = np.random.default_rng(seed)
    old_samples = FIG2_OLD.sample(n, rng)
    result = extended_importance_mixing(FIG2_NEW, [(FIG2_OLD, old_samples)], n, rng)
    grid = np.linspace(-3.6, 3.4, 700)
    p_old, p_new = FIG2_OLD.pdf(grid), FIG2_NEW.pdf(grid)

    fig = _figure(7.6, 3.8)
    ax = fig.subplots()
    ax.grid(False)
    _shade_regions(ax, grid, p_old, p_new, BLUE)
    ax.plot(grid, p_old, color=BLUE, linewidth=1.8)
    ax.plot(grid, p_new, color=VERMILLION, linewidth=1.8)
    _draw_trials(ax, result.trials, BLUE)
    untried = result.untried.get(1, [])
    if untried:
        ax.scatter(untried, np.zeros(len(untried)), marker="|", s=80, color=GREY, zorder=4, clip_on=False)
    ax.set_xlim(grid[0], grid[-1])
    top = 1.08 * max(p_old.max(), p_new.max())
    ax.set_ylim(-0.025 * top, top)  # room for points drawn at height ~0
    ax.set_xlabel("z")
    ax.set_ylabel("density")
    entries = [
        (Line2D([], [], color=BLUE, linewidth=1.8), "p(z, θ_old)"),
        (Line2D([], [], color=VERMILLION, linewidth=1.8), "p(z, θ_new)"),
        (Patch(facecolor=OVERLAP_FILL, alpha=0.6), "overlap min(p_old, p_new)"),
        (Patch(facecolor=VERMILLION, alpha=0.13), "leftover: under p_new, above p_old"),
    ]
    entries += _trial_legend(result.trials, BLUE)
    if untried:
        entries.append((Line2D([], [], linestyle="", marker="|", color=GREY, markersize=8), f"old samples never tried (generation full): {len(untried)}"))
    fig.legend([h for h, _ in entries], [label for _, label in entries], loc="outside right center")
    kept = result.members()
    reused = sum(1 for t in kept if t.source == "old")
    ax.set_title(
        f"Importance mixing, N = {n}: {reused} old samples reused, {len(kept) - reused} new evaluated\n"
        "old z at height rand₁·p_old(z), new z′ at (1−rand₂)·p_new(z′)",
        loc="left",
    )
    return fig


# --------------------------------------------------------------------------- Fig 3


FIG3_GENS = (Gauss1D(-1.3, 1.0), Gauss1D(-0.3, 0.85), Gauss1D(0.6, 0.7))  # g-2, g-1, g (new)


def _eim_draw(seed: int, n: int):
    rng = np.random.default_rng(seed)
    g2, g1, new = FIG3_GENS
    samples2 = g2.sample(n, rng)
    samples1 = g1.sample(n, rng)
    result = extended_importance_mixing(new, [(g1, samples1), (g2, samples2)], n, rng)
    return result


def _eim_seed(n: int, start: int = 0, tries: int = 1000) -> int:
    """First seed >= start whose draw reuses a sample from the second pass (generation g-2)."""
    for seed in range(start, start + tries):
        result = _eim_draw(seed, n)
        if any(t.source == "old" and t.passno == 2 and t.accepted and not t.removed for t in result.trials):
            return seed
    return start


def extended_importance_mixing_figure(n: int = 10, seed: int | None = None) -> Figure:
    """Fig 3: Algorithm 3 with generations g-2, g-1 archived and N = 10."""
    seed = _eim_seed(n) if seed is None else seed
    result = _eim_draw(seed, n)
    g2, g1, new = FIG3_GENS
    grid = np.linspace(-4.2, 3.4, 700)
    p_new = new.pdf(grid)
    ymax = 1.1 * max(g.pdf(grid).max() for g in FIG3_GENS)

    fig = _figure(10.5, 3.8)
    axes = fig.subplots(1, 3, sharey=True)
    passes = ((1, g1, BLUE, "g−1"), (2, g2, PURPLE, "g−2"))
    for ax, (k, old, color, name) in zip(axes, passes):
        ax.grid(False)
        p_old = old.pdf(grid)
        _shade_regions(ax, grid, p_old, p_new, color)
        ax.plot(grid, p_old, color=color, linewidth=1.8, label=f"p(z, θ_{name})")
        ax.plot(grid, p_new, color=VERMILLION, linewidth=1.8, label="p(z, θ_g) (new)")
        trials = [t for t in result.trials if t.passno == k]
        _draw_trials(ax, trials, color)
        counts = sum(1 for t in trials if t.accepted and not t.removed)
        ax.set_title(f"({'ab'[k - 1]}) pass k = {k}: generation {name} vs new\n{len(trials) // 2} steps, {counts} members added", loc="left")
        ax.set_xlabel("z")
        handles = [h for h, _ in _trial_legend(trials, color, old_name=name)]
        labels = [label for _, label in _trial_legend(trials, color, old_name=name)]
        lines, line_labels = ax.get_legend_handles_labels()
        ax.legend(lines + handles, line_labels + labels, loc="upper left", fontsize=7, handletextpad=0.4, borderaxespad=0.2)
    axes[0].set_ylabel("density")

    ax = axes[2]
    ax.grid(False)
    ax.fill_between(grid, 0, p_new, color=VERMILLION, alpha=0.10, linewidth=0)
    ax.plot(grid, p_new, color=VERMILLION, linewidth=1.8, label="p(z, θ_g)")
    members = result.members()
    origin = [
        ("old", 1, BLUE, "o", "reused from g−1 (IM)"),
        ("old", 2, PURPLE, "o", "reused from g−2 (EIM)"),
        ("new", None, VERMILLION, "^", "new draws (evaluated)"),
        ("fill", None, ORANGE, "s", "fill draws (evaluated)"),
    ]
    for source, passno, color, marker, label in origin:
        pts = [t for t in members if t.source == source and (passno is None or t.passno == passno)]
        if pts:
            ax.scatter([t.z for t in pts], [t.height for t in pts], marker=marker, s=34, color=color, zorder=4, label=f"{label}: {len(pts)}")
    ax.set_title(f"(c) new generation g, N = {n}: every accepted\npoint (a, b) lies under p_new", loc="left")
    ax.set_xlabel("z")
    ax.legend(loc="upper left", fontsize=7)
    for a in axes:
        a.set_xlim(grid[0], grid[-1])
        a.set_ylim(-0.025 * ymax, ymax * 1.25)
    fig.suptitle(f"Extended importance mixing over three generations (seed {seed})")
    return fig


def didactic_figures(_exp=None, _opts=None):
    """Registry entry: yields the three didactic figures (they need no data)."""
    yield "didactic_rejection_sampling", rejection_sampling_figure()
    yield "didactic_importance_mixing", importance_mixing_figure()
    yield "didactic_extended_importance_mixing", extended_importance_mixing_figure()
