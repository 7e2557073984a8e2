"""Figures and table of the ARS study (``make reproduce-ars``, docs/ars.md).

Usage::

    python -m imix_cli.plotting.ars [results_dir=results] [experiment=ars] [resamples=2000]

Reads the seed CSVs of ``<results_dir>/<experiment>/``: imix's ``ars-<EnvId>-<mixing>...`` runs and
sb3-contrib's ``sb3_ars-<EnvId>`` runs (:mod:`imix_cli.bench.ars_peer`, the same column names), and
writes into ``<results_dir>/<experiment>/figures/``:

* ``ars_<env>.png`` / ``.pdf``: the mean policy's return on fresh episodes (``mean_policy_score``)
  against training episodes, one curve per method, the mean over seeds with a 95 % bootstrap
  interval of that mean (:func:`imix_cli.plotting.mujoco.bootstrap_ci`), the ARS paper's threshold dashed;
* ``ars_table.csv`` / ``.md``: per env and method, the seeds, the training episodes and env steps
  to first reach the ARS paper's threshold with the mean policy (mean over the seeds that reached
  it, and how many did), the mean policy's last measured return (mean and 95 % CI), the episodes
  saved by mixing (1 - episodes run / (generations x popsize)), the training episodes and the wall
  time per seed (an imix run's seeds advance together in each of its ``workers`` processes: its
  run time divided by the seeds each process ran);
  and for imix's methods, whether they differ from sb3-contrib's ARS beyond noise: two-sided
  Mann-Whitney p-values (:func:`p_vs_peer`) of the episodes to the threshold (a seed that never
  reached it ranks after every seed that did) and of the last measured return.

Why the mean policy: ARS (and its paper's thresholds) measure the policy at the centre of the
search -- the one a user deploys -- not the perturbed members it was trained on.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from imix_cli.keyvalue import UsageError, at_least, help_requested, parse_key_values
from imix_cli.plotting.mujoco import bootstrap_ci, hold_on_grid
from imix_cli.running.files.writing import atomic_write_text, csv_text, one_line, write_figure

#: The ARS paper's thresholds (Mania et al. 2018, on the -v1 envs), by gymnasium id of the v5 env.
THRESHOLDS = {"Swimmer-v5": 325.0, "Hopper-v5": 3120.0, "HalfCheetah-v5": 3430.0, "Walker2d-v5": 4390.0}
METHODS = (("sb3_ars", "sb3-contrib ARS"), ("none", "imix ARS"), ("eim", "imix ARS + EIM"))
COLORS = {"sb3_ars": "#000000", "none": "#E69F00", "eim": "#0072B2"}
GRID_POINTS = 200


def load(exp_dir: Path) -> dict:
    """``{env id: {method: [frames of its seeds]}}``: method "sb3_ars", "none" or "eim"."""
    import pandas as pd

    runs: dict = {}
    for run in sorted(p for p in exp_dir.iterdir() if p.is_dir()):
        parts = run.name.split("-")
        if run.name.startswith("sb3_ars-"):
            env, method = "-".join(parts[1:3]), "sb3_ars"
        elif run.name.startswith("ars-") and len(parts) >= 4:
            env, method = "-".join(parts[1:3]), parts[3]
        else:
            continue
        frames = [pd.read_csv(p) for p in sorted(run.glob("seed_*.csv")) if ".partial" not in p.name]
        at_once = _seeds_at_once(run) if method != "sb3_ars" else 1.0
        for frame in frames:
            frame["wall_time_per_seed"] = frame["wall_time"] / at_once
        if frames:
            runs.setdefault(env, {}).setdefault(method, []).extend(frames)
    return runs


def _seeds_at_once(run: Path) -> float:
    """How many seeds of an imix run shared its wall time: ``imix run`` advances the seeds of each of
    its ``workers`` processes together, so every seed's last ``wall_time`` is its process's run time.
    sb3-contrib's peer runs one seed at a time (1)."""
    from imix_cli.plotting.data import read_run_config

    config = read_run_config(run / "config.yaml", _warn, fallback="wall time per seed taken as each seed's own")
    try:
        seeds, workers = int(config["seeds"]), int(config["workers"])
    except (KeyError, TypeError, ValueError):
        return 1.0  # no run config: the seed's own time
    return max(1.0, seeds / max(1, min(workers, seeds)))


def _warn(message: str) -> None:
    print(f"python -m imix_cli.plotting.ars: warning: {message}", file=sys.stderr)


def _measured(frame):
    """The rows where the mean policy was measured."""
    return frame[np.isfinite(frame["mean_policy_score"].to_numpy(dtype=float))]


def p_vs_peer(ours: list, peer: list) -> float:
    """Two-sided Mann-Whitney U p-value of two samples of seeds, by permutation (exact up to 20,000
    arrangements, else 20,000 random ones from a fixed seed); ``inf`` may stand for "never reached":
    it ties with the other censored seeds, above every number.

    Why a rank test: episodes to a threshold are censored at the budget and final returns of ARS on
    Swimmer are bimodal (seeds stuck near 100 or near 350), so neither is close to normal. Why
    permutations: censored seeds tie, and with ties scipy's exact null does not apply and its normal
    approximation is poor for a handful of seeds."""
    from scipy.stats import PermutationMethod, mannwhitneyu

    ours, peer = np.asarray(ours, dtype=float), np.asarray(peer, dtype=float)
    if len(ours) < 2 or len(peer) < 2:  # one seed on a side: nothing to rank against
        return float("nan")
    both = np.concatenate([ours, peer])
    if np.all(both == both[0]):  # identical samples: no evidence of a difference (scipy returns nan)
        return 1.0
    finite_cap = np.max(both[np.isfinite(both)], initial=0.0) + 1.0  # ranks only: a censored seed after every finite one
    return float(
        mannwhitneyu(
            np.where(np.isfinite(ours), ours, finite_cap),
            np.where(np.isfinite(peer), peer, finite_cap),
            alternative="two-sided",
            method=PermutationMethod(n_resamples=20_000, rng=0),
        ).pvalue
    )


def seed_outcomes(frames: list, threshold) -> tuple[list, list, list]:
    """Per seed: the last measured return, and the episodes and env steps to the threshold (inf: never)."""
    finals, to_episodes, to_steps = [], [], []
    for f in frames:
        m = _measured(f)
        if len(m):
            finals.append(float(m["mean_policy_score"].iloc[-1]))
        hit = m[m["mean_policy_score"] >= threshold] if threshold is not None else m.iloc[:0]
        to_episodes.append(int(hit["evaluations"].iloc[0]) if len(hit) else np.inf)
        to_steps.append(int(hit["env_steps"].iloc[0]) if len(hit) else np.inf)
    return finals, to_episodes, to_steps


def summary_rows(runs: dict, resamples: int) -> list[dict]:
    rows = []
    for env in sorted(runs):
        threshold = THRESHOLDS.get(env)
        peer = seed_outcomes(runs[env].get("sb3_ars", []), threshold)
        for method, label in METHODS:
            frames = runs[env].get(method)
            if not frames:
                continue
            finals, censored_episodes, censored_steps = seed_outcomes(frames, threshold)
            to_episodes = [e for e in censored_episodes if np.isfinite(e)]
            to_steps = [e for e in censored_steps if np.isfinite(e)]
            vs_peer = method != "sb3_ars" and len(peer[0]) > 0
            mean, low, high = bootstrap_ci(np.array(finals), resamples) if finals else (np.nan, np.nan, np.nan)
            episodes = [int(f["evaluations"].iloc[-1]) for f in frames]
            saved = float("nan")
            if method != "sb3_ars":
                members = sum(int(f["popsize"].sum()) for f in frames)
                saved = 1.0 - sum(episodes) / members
            rows.append({
                "env": env, "method": label, "seeds": len(frames), "threshold": threshold,
                "reached": f"{len(to_episodes)}/{len(frames)}",
                "episodes_to_threshold": float(np.mean(to_episodes)) if to_episodes else float("nan"),
                "env_steps_to_threshold": float(np.mean(to_steps)) if to_steps else float("nan"),
                "final_mean_policy_return": float(mean), "ci_low": float(low), "ci_high": float(high),
                "episodes_saved": saved, "episodes_run": float(np.mean(episodes)),
                "wall_time_s": float(np.mean([f.get("wall_time_per_seed", f["wall_time"]).iloc[-1] for f in frames])),
                "p_episodes_vs_sb3": p_vs_peer(censored_episodes, peer[1]) if vs_peer and threshold is not None else float("nan"),
                "p_final_vs_sb3": p_vs_peer(finals, peer[0]) if vs_peer else float("nan"),
            })  # fmt: skip
    return rows


def markdown(rows: list[dict]) -> str:
    head = (
        "| env | method | seeds | threshold | reached | episodes to threshold | env steps to threshold | "
        "final mean-policy return (95 % CI) | episodes saved by mixing | training episodes | wall time per seed (s) | "
        "vs sb3-contrib: p (episodes to threshold / final return) |"
    )
    lines = [head, "|" + "---|" * 12]

    def num(x, fmt="{:,.0f}"):
        return "–" if x is None or (isinstance(x, float) and not np.isfinite(x)) else fmt.format(x)

    for r in rows:
        lines.append(
            f"| {one_line(r['env'])} | {one_line(r['method'])} | {r['seeds']} | {num(r['threshold'])} | {r['reached']} | {num(r['episodes_to_threshold'])} | "
            f"{num(r['env_steps_to_threshold'])} | {num(r['final_mean_policy_return'], '{:.1f}')} "
            f"({num(r['ci_low'], '{:.1f}')} – {num(r['ci_high'], '{:.1f}')}) | {num(r['episodes_saved'], '{:.1%}')} | "
            f"{num(r['episodes_run'])} | {num(r['wall_time_s'])} | "
            f"{num(r['p_episodes_vs_sb3'], '{:.2f}')} / {num(r['p_final_vs_sb3'], '{:.2f}')} |"
        )
    return "\n".join(lines) + "\n"


def figure(env: str, methods: dict, out: Path, resamples: int, root=None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for method, label in METHODS:
        frames = [_measured(f) for f in methods.get(method, [])]
        frames = [f for f in frames if len(f)]
        if not frames:
            continue
        end = min(float(f["evaluations"].iloc[-1]) for f in frames)
        start = max(float(f["evaluations"].iloc[0]) for f in frames)
        grid = np.linspace(start, end, GRID_POINTS) if end > start else np.array([end])
        ys = np.array([hold_on_grid(f["evaluations"].to_numpy(float), f["mean_policy_score"].to_numpy(float), grid) for f in frames])
        mean, low, high = bootstrap_ci(ys, resamples)
        ax.plot(grid, mean, color=COLORS[method], label=f"{label} ({len(frames)} seeds)")
        ax.fill_between(grid, low, high, color=COLORS[method], alpha=0.2, linewidth=0)
    if env in THRESHOLDS:
        ax.axhline(THRESHOLDS[env], color="grey", linestyle="--", linewidth=1, label=f"ARS paper's threshold {THRESHOLDS[env]:g}")
    ax.set_xlabel("training episodes")
    ax.set_ylabel("mean policy's return (fresh episodes)")
    ax.set_title(f"{env}: ARS, mean over seeds, 95 % bootstrap CI")
    ax.legend(fontsize=8)
    fig.tight_layout()
    for suffix in (".png", ".pdf"):
        write_figure(fig, out / f"ars_{env.split('-')[0].lower()}{suffix}", root=root, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if help_requested(argv, __doc__):
        return 0
    try:
        opts = parse_key_values(argv, "ars plots", {"results_dir": "results", "experiment": "ars", "resamples": 2000}, {"resamples": at_least(1)})
    except UsageError as err:
        print(f"python -m imix_cli.plotting.ars: error: {err}", file=sys.stderr)
        return err.status
    resamples = opts["resamples"]
    exp_dir = Path(opts["results_dir"]) / opts["experiment"]
    if not exp_dir.is_dir():
        print(f"python -m imix_cli.plotting.ars: error: {exp_dir}: no such experiment folder", file=sys.stderr)
        return 2
    runs = load(exp_dir)
    if not runs:
        print(f"python -m imix_cli.plotting.ars: error: {exp_dir}: no ARS runs (ars-* or sb3_ars-*)", file=sys.stderr)
        return 2
    out, root = exp_dir / "figures", opts["results_dir"]
    rows = summary_rows(runs, resamples)
    import pandas as pd

    atomic_write_text(out / "ars_table.csv", csv_text(pd.DataFrame(rows)), root=root)
    atomic_write_text(out / "ars_table.md", markdown(rows), root=root)
    for env, methods in runs.items():
        figure(env, methods, out, resamples, root)
    print(markdown(rows))
    print(f"figures and table: {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
