"""ARS on Swimmer: does imix's ARS match sb3-contrib's? A replication on new seeds, planned before it ran.

The study (docs/ars.md) had sb3-contrib's ARS reach the ARS paper's threshold (325) on 16/20 seeds
(seeds 0-19) and imix's on 6/20, then 12/20 on sb3-contrib's seeds 20-39. This runs, on seeds no
earlier comparison used, with the study's settings (600 training episodes, the mean policy measured
on 3 fresh episodes every 10 iterations):

* sb3-contrib's ARS with rl-zoo3's settings, seeds 40-99;
* imix's ARS with the ARS paper's step (sigma_R with ddof 0), seeds 20-79;
* imix's ARS at sb3-contrib's step (alpha / sqrt 2: sb3-contrib's sigma_R has ddof 1, which with one
  direction is sqrt 2 larger), seeds 10-79 -- the same method as sb3-contrib's;

and compares seeds reaching 325, episodes to it (a seed that never reaches it ranks last) and the final
mean-policy return. Commands (one process each; ~70 s a seed for sb3-contrib, ~40 s for imix here):

    for k in $(seq 40 99); do python -m imix_cli.bench.ars_peer --envs swimmer --seeds 100 --seed $k --episodes 600 \\
        --eval-every 10 --eval-episodes 3 --experiment ars_rep; done
    imix run env=swimmer +ars=swimmer algo=ars eim=false seeds=80 generations=300 eval_mean_every=10 eval_mean_episodes=3 experiment=ars_rep workers=1
    imix run env=swimmer +ars=swimmer algo=ars eim=false lr=0.0141421356 seeds=80 generations=300 eval_mean_every=10 \\
        eval_mean_episodes=3 experiment=ars_rep workers=1
    python benchmarks/ars_replication.py results/ars_rep
"""

import glob
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from imix_cli.plotting.ars import p_vs_peer

THRESHOLD = 325.0


def per_seed(path: Path, seeds) -> dict:
    reached, episodes, final = [], [], []
    for seed in seeds:
        frame = pd.read_csv(path / f"seed_{seed}.csv")
        measured = frame.dropna(subset=["mean_policy_score"])
        hit = measured[measured["mean_policy_score"] >= THRESHOLD]
        reached.append(len(hit) > 0)
        episodes.append(float(hit["evaluations"].iloc[0]) if len(hit) else np.inf)
        final.append(float(measured["mean_policy_score"].iloc[-1]))
    return {"reached": np.array(reached), "episodes": np.array(episodes), "final": np.array(final)}


def main(root: str) -> int:
    root = Path(root)
    sb3 = root / "sb3_ars-Swimmer-v5"
    paper = Path(glob.glob(str(root / "ars-Swimmer-v5-none-*lr=0.02,*"))[0])
    small = Path(glob.glob(str(root / "ars-Swimmer-v5-none-*lr=0.0141421356*"))[0])
    arms = {
        "sb3-contrib ARS (rl-zoo3), seeds 40-99": per_seed(sb3, range(40, 100)),
        "imix ARS, the ARS paper's step, seeds 20-79": per_seed(paper, range(20, 80)),
        "imix ARS at sb3-contrib's step (alpha/sqrt 2), seeds 10-79": per_seed(small, range(10, 80)),
    }
    peer = arms["sb3-contrib ARS (rl-zoo3), seeds 40-99"]
    columns = ["method", "seeds", "reached 325", "episodes to 325 (median of those reaching it)", "final mean-policy return: median (mean)"]
    columns.append("vs sb3-contrib: Fisher p (reached) / Mann-Whitney p (episodes, final)")
    print("| " + " | ".join(columns) + " |")
    print("|---|---:|---:|---:|---:|---|")
    for name, arm in arms.items():
        n, k = len(arm["reached"]), int(arm["reached"].sum())
        hits = arm["episodes"][np.isfinite(arm["episodes"])]
        if arm is peer:
            versus = "--"
        else:
            fisher = stats.fisher_exact([[k, n - k], [int(peer["reached"].sum()), len(peer["reached"]) - int(peer["reached"].sum())]])[1]
            versus = f"{fisher:.2f} / {p_vs_peer(list(arm['episodes']), list(peer['episodes'])):.2f}, {p_vs_peer(list(arm['final']), list(peer['final'])):.2f}"
        print(f"| {name} | {n} | {k}/{n} ({k / n:.0%}) | {np.median(hits):,.0f} | {np.median(arm['final']):.1f} ({np.mean(arm['final']):.1f}) | {versus} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1] if len(sys.argv) > 1 else "results/ars_rep"))
