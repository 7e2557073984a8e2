"""Reuse on tasks nobody tuned: every built-in ES without mixing and with the default EIM, on gymnasium tasks no preset covers.

Why: imix's defaults were tuned on CartPole and Acrobot, whose tied returns hide what a continuous
return shows (once, CEM + EIM froze and SNES + EIM shrank sigma on held-out tasks). This benchmark
runs the registry's tasks as they are (``env=gym env.id=...``), at imix's defaults except the
population size and the generations, stated once below, and reports per task and ES:

* theta, final: the search distribution's mean on 100 fresh episodes per seed (``imix eval``),
  mean and 95 % CI over seeds (t interval);
* inside: whether EIM's final theta lies inside no mixing's 95 % CI ("above" if above it), and Welch's p for
  equal means (5 seeds: a "no" with a large p is a narrow CI, not a clear difference);
* theta at EIM's episodes: no mixing's theta (the CSV's ``mean_policy_score``, 5 fresh episodes
  every 10 generations) at the first generation at which it had run as many episodes as EIM did in
  its whole run -- what the episodes EIM saved would have bought without mixing;
* episodes per seed, reuse;
* sigma ratio: median final ``sigma_mean`` with EIM over the median without;
* stalls: the longest run of generations in which no member was evaluated (``reused == popsize``),
  over all seeds, and their total.

The tasks, their caps and thresholds were chosen before any run (classic control and MuJoCo;
discrete and continuous actions; dense and sparse rewards). ``threshold`` is the return a seed
must reach for the "solved" column (final theta). MuJoCo tasks need the ``mujoco`` extra.

Usage::

    python benchmarks/untuned_tasks.py run   [--tasks ...] [--algos ...] [--seeds 5] [--results-dir results]
    python benchmarks/untuned_tasks.py table [--tasks ...] [--algos ...] [--results-dir results]

(``make untuned``: both.) Finished runs are skipped, so an interrupted benchmark resumes.
"""

from __future__ import annotations

import argparse
import glob
import os
import subprocess
import sys

import numpy as np

#: The tasks: gymnasium id -> (what it is, env.max_steps or None for its own limit, threshold).
TASKS = {
    "MountainCar-v0": ("classic control, discrete, sparse", None, -150.0),
    "MountainCarContinuous-v0": ("classic control, continuous, sparse", 500, 50.0),
    "Pendulum-v1": ("classic control, continuous, dense", None, -400.0),
    "InvertedPendulum-v5": ("MuJoCo, continuous, alive bonus", 500, 450.0),
    "InvertedDoublePendulum-v5": ("MuJoCo, continuous, dense", 200, 1500.0),
    "Reacher-v5": ("MuJoCo, continuous, dense", None, -10.0),
}
ALGOS = ("openes", "snes", "cem", "cmaes", "ars")
#: Stated once: every run uses imix's defaults except these.
POPSIZE, GENERATIONS = 20, 150
EXPERIMENT = "untuned"


def imix(*args: str) -> int:
    return subprocess.call([sys.executable, "-m", "imix_cli.commands.cli", *args])


def run(tasks, algos, seeds: int, results_dir: str) -> int:
    for task in tasks:
        _, cap, _ = TASKS[task]
        common = [f"env.id={task}", f"seeds={seeds}", f"popsize={POPSIZE}", f"generations={GENERATIONS}", f"experiment={EXPERIMENT}",
                  f"results_dir={results_dir}", "progress=false"]  # fmt: skip
        if cap is not None:
            common.append(f"env.max_steps={cap}")
        code = imix("run", "-m", "env=gym", f"algo={','.join(algos)}", "eim=false,true", *common)
        if code:
            return code
    return imix("eval", f"experiment={EXPERIMENT}", f"results_dir={results_dir}", "episodes=100")


def _ci95(values: np.ndarray) -> tuple[float, float]:
    from scipy import stats

    mean = float(np.mean(values))
    if values.size < 2:
        return mean, float("nan")
    return mean, float(stats.t.ppf(0.975, values.size - 1) * np.std(values, ddof=1) / np.sqrt(values.size))


def _welch_p(a: np.ndarray, b: np.ndarray) -> str:
    """Welch's two-sided t-test of equal means ("–" where both samples are constant: nothing to test)."""
    from scipy import stats

    if np.ptp(a) == 0 and np.ptp(b) == 0:
        return "–"
    return f"{stats.ttest_ind(a, b, equal_var=False).pvalue:.2f}"


def _runs(results_dir: str, algo: str, task: str) -> dict:
    """mixing ("none" | "eim") -> the run folder of ``algo`` on ``task`` (any overrides suffix)."""
    found = {}
    for folder in glob.glob(os.path.join(results_dir, EXPERIMENT, f"{algo}-{task}-*")):
        mixing = os.path.basename(folder)[len(f"{algo}-{task}-") :].split("-")[0]
        found[mixing] = folder
    return found


def _seed_frames(folder: str):
    import pandas as pd

    csvs = sorted(f for f in glob.glob(os.path.join(folder, "seed_*.csv")) if os.path.basename(f)[5:-4].isdigit())
    return [pd.read_csv(f) for f in csvs]


def _final_theta(folder: str) -> np.ndarray:
    import pandas as pd

    path = os.path.join(folder, "eval.csv")
    if not os.path.exists(path):
        return np.array([])
    frame = pd.read_csv(path)
    return frame[frame["which"] == "mean"]["mean_return"].to_numpy(dtype=float)


def _stalls(frames) -> tuple[int, int]:
    longest = total = 0
    for f in frames:
        full = (f["reused"] == f["popsize"]).to_numpy()
        run = 0
        for v in full:
            run = run + 1 if v else 0
            longest = max(longest, run)
        total += int(full.sum())
    return longest, total


def _theta_at(frames, episodes: float) -> float:
    """Mean over seeds of the last measured theta at or before the generation where ``evaluations`` reaches ``episodes``."""
    values = []
    for f in frames:
        upto = f[f["evaluations"] <= episodes]["mean_policy_score"].dropna()
        if len(upto):
            values.append(upto.iloc[-1])
    return float(np.mean(values)) if values else float("nan")


def table(tasks, algos, results_dir: str) -> int:
    print(f"Population {POPSIZE}, {GENERATIONS} generations, imix's defaults otherwise; theta on 100 fresh episodes per seed (mean ± 95 % CI).\n")
    print("| task | ES | theta, no mixing | theta, EIM | EIM inside? | Welch p | no mixing at EIM's episodes | episodes/seed none → EIM "
          "| reuse | solved none / EIM | σ ratio | stalls (longest, total) |")  # fmt: skip
    print("|---|---|---:|---:|:-:|---:|---:|---:|---:|:-:|---:|---:|")
    for task in tasks:
        threshold = TASKS[task][2]
        for algo in algos:
            runs = _runs(results_dir, algo, task)
            if "none" not in runs or "eim" not in runs:
                print(f"| {task} | {algo} | (not run) |||||||||")
                continue
            none, eim = _seed_frames(runs["none"]), _seed_frames(runs["eim"])
            theta_none, theta_eim = _final_theta(runs["none"]), _final_theta(runs["eim"])
            if theta_none.size == 0 or theta_eim.size == 0:
                print(f"| {task} | {algo} | (no eval.csv: imix eval experiment={EXPERIMENT} episodes=100) |||||||||||")
                continue
            (m_none, h_none), (m_eim, h_eim) = _ci95(theta_none), _ci95(theta_eim)
            inside = "yes" if abs(m_eim - m_none) <= h_none else ("above" if m_eim > m_none else "**no**")
            welch = _welch_p(theta_none, theta_eim)
            episodes_none = np.mean([f["evaluations"].iloc[-1] for f in none])
            episodes_eim = np.mean([f["evaluations"].iloc[-1] for f in eim])
            reuse = np.mean([f["reused"].sum() / f["popsize"].sum() for f in eim])
            sigma = np.median([f["sigma_mean"].iloc[-1] for f in eim]) / np.median([f["sigma_mean"].iloc[-1] for f in none])
            longest, total = _stalls(eim)
            solved = f"{int(np.sum(theta_none >= threshold))}/{theta_none.size} / {int(np.sum(theta_eim >= threshold))}/{theta_eim.size}"
            print(
                f"| {task} | {algo} | {m_none:.1f} ± {h_none:.1f} | {m_eim:.1f} ± {h_eim:.1f} | {inside} | {welch} | {_theta_at(none, episodes_eim):.1f} "
                f"| {episodes_none:,.0f} → {episodes_eim:,.0f} | {100 * reuse:.1f} % | {solved} | {sigma:.2f} | {longest}, {total} |"
            )
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("action", choices=("run", "table"))
    parser.add_argument("--tasks", default=",".join(TASKS), help="comma-separated gymnasium ids of TASKS")
    parser.add_argument("--algos", default=",".join(ALGOS))
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--results-dir", default="results")
    args = parser.parse_args(argv)
    tasks, algos = args.tasks.split(","), args.algos.split(",")
    unknown = [t for t in tasks if t not in TASKS] + [a for a in algos if a not in ALGOS]
    if unknown:
        parser.error(f"unknown task or ES: {', '.join(unknown)}")
    if args.action == "run":
        return run(tasks, algos, args.seeds, args.results_dir)
    return table(tasks, algos, args.results_dir)


if __name__ == "__main__":
    sys.exit(main())
