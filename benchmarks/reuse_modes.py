"""Reuse modes on MuJoCo: no reuse, exact mixing, importance-weighted reuse -- the table of docs/research/reuse_modes.md.

Every number here is read from the run CSVs of ``make reproduce-reuse-modes`` (SNES, popsize 20, sigma 0.1, lr 0.02,
observations normalised after a 3-generation warm-up, 100 generations, 10 seeds per run; HalfCheetah-v5 and Hopper-v5
with a linear policy, HalfCheetah-v5 with a 64x64 MLP; and ARS V2-t on Hopper-v5, ``+ars=hopper policy.bias=true``,
frozen or updated observation statistics). Everything is measured on theta, the distribution mean, on fresh episodes
(``mean_policy_score``: 5 episodes every 10 generations, ARS 3 every 5), never on stored returns. A run is compared
with the run without reuse of the same ES and settings. Per run:

* episodes per seed and reuse (the share of a generation's members not evaluated: the episodes saved);
* final theta (generation 100), mean over seeds with a 95 % percentile-bootstrap interval, and the two-sided
  permutation p-value of the difference of means with the run without reuse at the same settings;
* the theta of the run without reuse when it had run as many episodes as this run did in all (return at equal
  episodes: its last measurement at or before that budget);
* per threshold: seeds whose theta reached it, median episodes (and wall seconds) to the first measurement that
  did, among those, and the ratio to the run without reuse (its median over this one's: > 1, fewer episodes); then
  the median over all seeds, a seed that never reached it counted as infinite (infinite when half the seeds or more
  did not), and the same ratio on those medians: the one that does not flatter a run whose weaker seeds drop out.
  theta is measured every 10 generations, so episodes to a threshold are rounded up to the next measurement:
  by up to 200 episodes without reuse and 10 generations' fresh episodes with it (fewer), which favours reuse by
  at most that much.

    python benchmarks/reuse_modes.py [--experiment results/reuse_mujoco --experiment results/ars_obsnorm] [--page docs/research/reuse_modes.md]

``--page`` replaces the text between the page's ``<!-- reuse-modes-table -->`` and ``<!-- /reuse-modes-table -->``
marks with the tables (what ``make reproduce-reuse-modes`` does).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

#: Return thresholds by env: ones the study's budget reaches, then the ARS paper's (Mania et al. 2018, Table 1).
THRESHOLDS = {"HalfCheetah-v5": (500, 1000, 2000, 3430), "Hopper-v5": (500, 1000, 2000, 3120)}


def _mode(name: str) -> str:
    if "-none-" in name or name.endswith("-none"):
        return "none"
    found = re.search(r"eim_variant=(\w+)", name)
    return found.group(1) if found else "exact"


def _settings(name: str) -> str:
    """The settings of a run other than its reuse mode: the policy and anything else in its name (lr)."""
    rest = name.split("-", 3)[3] if name.count("-") >= 3 else ""
    shared = ("eim_variant", "obs_norm=", "popsize", "sigma", "algo.", "obs_var", "output", "weight_decay")  # the same in every run compared
    tokens = [t for t in re.split(r"[-,]", rest) if "=" in t and not t.startswith(shared)]
    return ",".join(sorted(tokens))


def load(experiment: Path) -> list[dict]:
    from imix_cli.running.files.results import read_run_csv

    runs = []
    for folder in sorted(p for p in experiment.iterdir() if p.is_dir()):
        frames = [read_run_csv(p) for p in sorted(folder.glob("seed_*.csv")) if re.fullmatch(r"seed_\d+\.csv", p.name)]  # not .partial
        frames = [f for f in frames if len(f)]
        if not frames:
            continue
        runs.append(
            {"name": folder.name, "env": str(frames[0]["env"].iloc[0]), "mode": _mode(folder.name), "settings": _settings(folder.name), "frames": frames}
        )
    return runs


def _theta(frame):
    rows = frame[np.isfinite(frame["mean_policy_score"].to_numpy(float))]
    return rows["evaluations"].to_numpy(float), rows["mean_policy_score"].to_numpy(float), rows["wall_time"].to_numpy(float)


def bootstrap(values: np.ndarray, resamples: int = 4000, seed: int = 0) -> tuple[float, float, float]:
    values = np.asarray(values, dtype=float)
    idx = np.random.default_rng(seed).integers(0, values.size, size=(resamples, values.size))
    means = values[idx].mean(axis=1)
    return float(values.mean()), float(np.quantile(means, 0.025)), float(np.quantile(means, 0.975))


def permutation_p(a: np.ndarray, b: np.ndarray, resamples: int = 20000, seed: int = 0) -> float:
    rng = np.random.default_rng(seed)
    both, observed = np.concatenate([a, b]), abs(a.mean() - b.mean())
    hits = 0
    for _ in range(resamples):
        p = rng.permutation(both)
        hits += abs(p[: a.size].mean() - p[a.size :].mean()) >= observed - 1e-12
    return (hits + 1) / (resamples + 1)


def summarise(run: dict) -> dict:
    frames = run["frames"]
    out = {
        "episodes": float(np.mean([f["evaluations"].iloc[-1] for f in frames])),
        "reuse": float(sum(f["reused"].sum() for f in frames) / sum(f["popsize"].sum() for f in frames)),
        "final": np.array([_theta(f)[1][-1] for f in frames]),
        "wall": float(np.mean([f["wall_time"].iloc[-1] for f in frames])),
        "hits": {},
    }
    for threshold in THRESHOLDS.get(run["env"], ()):
        firsts = []
        for f in frames:
            episodes, theta, wall = _theta(f)
            hit = np.flatnonzero(theta >= threshold)
            if hit.size:
                firsts.append((episodes[hit[0]], wall[hit[0]]))
        out["hits"][threshold] = firsts
    return out


def _median_all(firsts, seeds: int) -> float:
    """The median over all ``seeds`` of the episodes to a threshold, a seed that never reached it counted as infinite."""
    return float(np.median([e for e, _ in firsts] + [np.inf] * (seeds - len(firsts))))


def theta_at(frames, budget: float) -> np.ndarray:
    """Each seed's theta at its last measurement with at most ``budget`` episodes run (NaN before the first)."""
    values = []
    for f in frames:
        episodes, theta, _ = _theta(f)
        k = np.flatnonzero(episodes <= budget)
        values.append(theta[k[-1]] if k.size else np.nan)
    return np.array(values)


def table(runs: list[dict]) -> str:
    lines = [
        "| env | policy, settings | reuse mode | seeds | episodes/seed | reuse | final θ (95 % CI) | p vs none | none's θ at these episodes | wall s/run |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    hits = [
        "| env | policy, settings | reuse mode | threshold | reached | median episodes to it (seeds that reached it) | fewer than none |"
        " median episodes, all seeds (never: ∞) | fewer than none, all seeds | median wall s to it |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    order = {"none": 0, "exact": 1, "weighted": 2}
    groups: dict = {}
    for run in runs:
        groups.setdefault((run["env"], run["settings"]), []).append(run)
    for (env, settings), members in sorted(groups.items()):
        members.sort(key=lambda r: order.get(r["mode"], 9))
        stats = {r["mode"]: summarise(r) for r in members}
        base_run = next((r for r in members if r["mode"] == "none"), None)
        base = stats.get("none")
        for run in members:
            s = stats[run["mode"]]
            mean, lo, hi = bootstrap(s["final"])
            p = f"{permutation_p(s['final'], base['final']):.2f}" if base is not None and run["mode"] != "none" else ""
            if base_run is not None and run["mode"] != "none":
                m, lo2, hi2 = bootstrap(theta_at(base_run["frames"], s["episodes"]))
                at = f"{m:.1f} [{lo2:.1f}, {hi2:.1f}]"
            else:
                at = ""
            lines.append(
                f"| {env} | {settings} | {run['mode']} | {len(run['frames'])} | {s['episodes']:,.0f} | {100 * s['reuse']:.1f} % | "
                f"{mean:.1f} [{lo:.1f}, {hi:.1f}] | {p} | {at} | {s['wall']:.0f} |"
            )
            for threshold, firsts in s["hits"].items():
                n = len(run["frames"])
                ref = base["hits"].get(threshold) if base is not None and run["mode"] != "none" else None
                every = _median_all(firsts, n)
                ratio_all = (
                    f"{_median_all(ref, len(base_run['frames'])) / every:.2f}×"
                    if ref and np.isfinite(every) and np.isfinite(_median_all(ref, len(base_run["frames"])))
                    else ""
                )
                every_text = f"{every:,.0f}" if np.isfinite(every) else "∞"
                if firsts:
                    med, wall = float(np.median([e for e, _ in firsts])), float(np.median([w for _, w in firsts]))
                    ratio = f"{float(np.median([e for e, _ in ref])) / med:.2f}×" if ref else ""
                    cells = f"{len(firsts)}/{n} | {med:,.0f} | {ratio} | {every_text} | {ratio_all} | {wall:.0f}"
                    hits.append(f"| {env} | {settings} | {run['mode']} | {threshold} | {cells} |")
                else:
                    hits.append(f"| {env} | {settings} | {run['mode']} | {threshold} | 0/{n} | – | | ∞ | | – |")
    return "\n".join(lines) + "\n\n" + "\n".join(hits) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiment", action="append", type=Path, help="a folder of runs (repeat for several); default results/reuse_mujoco")
    parser.add_argument("--page", default=None, type=Path, help="write the tables into this page, between its reuse-modes-table marks")
    args = parser.parse_args(argv)
    runs = []
    for folder in args.experiment or [Path("results/reuse_mujoco")]:
        if not folder.is_dir():
            parser.error(f"--experiment {folder}: no such folder (make reproduce-reuse-modes makes it)")
        found = load(folder)
        if not found:
            parser.error(f"--experiment {folder}: no run CSVs in it")
        runs += [{**run, "settings": f"{run['name'].split('-')[0]} {run['settings']}"} for run in found]
    text = table(runs)
    print(text)
    if args.page is not None:
        from imix_cli.running.files.writing import atomic_write_text

        page = args.page.read_text(encoding="utf-8")
        start, end = "<!-- reuse-modes-table -->", "<!-- /reuse-modes-table -->"
        if start not in page or end not in page:
            parser.error(f"--page {args.page}: no {start} ... {end} marks in it")
        head, rest = page.split(start, 1)
        atomic_write_text(args.page, head + start + "\n" + text + rest[rest.index(end) :])
    return 0


if __name__ == "__main__":
    sys.exit(main())
