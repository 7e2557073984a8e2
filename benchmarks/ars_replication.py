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

Hopper (``hopper``): the study's 3 seeds had given sb3-contrib a final mean-policy return of 2126
against imix's 694 (p = 0.40). The replication, with the study's settings (V2-t, 1,600 training
episodes, the mean policy on 3 fresh episodes every 5 iterations), runs sb3-contrib on seeds 3-22 and
imix with its normaliser frozen after 5 generations (the preset, which keeps reuse honest) or updated
every generation as ARS and sb3-contrib do (``policy.obs_norm_warmup=100``, the run's length: no
mixing could use it), each with imix's default variance floor 0.01 (what the preset had) and with
ARS's 1e-8 (the preset now), and imix ARS + EIM. ~120 s a seed for sb3-contrib, 20-60 s for imix:

    for k in $(seq 3 22); do python -m imix_cli.bench.ars_peer --envs hopper --seeds 100 --seed $k --episodes 1600 \\
        --eval-every 5 --eval-episodes 3 --experiment ars_hop; done
    C="env=hopper +ars=hopper algo=ars generations=100 eval_mean_every=5 eval_mean_episodes=3 experiment=ars_hop workers=1"
    imix run $C eim=false seeds=20;  imix run $C eim=false policy.obs_norm_warmup=100 seeds=20;  imix run $C eim=true seeds=20
    imix run $C eim=false policy.obs_var_floor=0.01 seeds=40
    imix run $C eim=false policy.obs_var_floor=0.01 policy.obs_norm_warmup=100 seeds=40
    python benchmarks/ars_replication.py results/ars_hop hopper
"""

import glob
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from imix_cli.plotting.ars import p_vs_peer, seed_outcomes

#: Per replication: the ARS paper's threshold, and its arms (label, the run folder's glob, seeds);
#: the first arm is sb3-contrib's, which the others are compared with.
REPLICATIONS = {
    "swimmer": (325.0, [
        ("sb3-contrib ARS (rl-zoo3), seeds 40-99", "sb3_ars-Swimmer-v5", range(40, 100)),
        ("imix ARS, the ARS paper's step, seeds 20-79", "ars-Swimmer-v5-none-*lr=0.02,*", range(20, 80)),
        ("imix ARS at sb3-contrib's step (alpha/sqrt 2), seeds 10-79", "ars-Swimmer-v5-none-*lr=0.0141421356*", range(10, 80)),
    ]),
    "hopper": (3120.0, [
        ("sb3-contrib ARS (rl-zoo3), seeds 3-22", "sb3_ars-Hopper-v5", range(3, 23)),
        ("imix ARS (the preset: variance floor 1e-8, statistics frozen after 5 generations), seeds 0-19",
         "ars-Hopper-v5-none-*obs_norm=5,obs_var_floor=1e-08,*", range(0, 20)),
        ("imix ARS, floor 1e-8, statistics updated every generation, seeds 0-19", "ars-Hopper-v5-none-*obs_norm=100,obs_var_floor=1e-08,*", range(0, 20)),
        ("imix ARS + EIM (the preset), seeds 0-19", "ars-Hopper-v5-eim-*obs_norm=5,obs_var_floor=1e-08,*", range(0, 20)),
        ("imix ARS, imix's default floor 0.01, frozen after 5 generations (the preset before), seeds 0-39",
         "ars-Hopper-v5-none-*obs_norm=5,output*", range(0, 40)),
        ("imix ARS, floor 0.01, updated every generation, seeds 0-39", "ars-Hopper-v5-none-*obs_norm=100,output*", range(0, 40)),
    ]),
}  # fmt: skip


def per_seed(path: Path, seeds, threshold: float) -> dict:
    """The arm's seeds: reached the threshold, episodes to it (inf: never), final return, episodes run."""
    frames = [pd.read_csv(path / f"seed_{seed}.csv") for seed in seeds]
    finals, episodes, _ = seed_outcomes(frames, threshold)  # the study table's reading of a seed
    episodes = np.array(episodes, dtype=float)
    run = np.array([float(frame["evaluations"].iloc[-1]) for frame in frames])
    return {"reached": np.isfinite(episodes), "episodes": episodes, "final": np.array(finals), "run": run}


def main(root: str, env: str = "swimmer") -> int:
    root = Path(root)
    threshold, specs = REPLICATIONS[env]
    arms = {label: per_seed(Path(glob.glob(str(root / folder))[0]), seeds, threshold) for label, folder, seeds in specs}
    peer = arms[specs[0][0]]
    columns = ["method", "seeds", f"reached {threshold:.0f}", f"episodes to {threshold:.0f} (median of those reaching it)"]
    columns += ["final mean-policy return: median (mean)", "training episodes run (mean)"]
    columns.append("vs sb3-contrib: Fisher p (reached) / Mann-Whitney p (episodes, final)")
    print("| " + " | ".join(columns) + " |")
    print("|---|---:|---:|---:|---:|---:|---|")
    for name, arm in arms.items():
        n, k = len(arm["reached"]), int(arm["reached"].sum())
        hits = arm["episodes"][np.isfinite(arm["episodes"])]
        if arm is peer:
            versus = "--"
        else:
            fisher = stats.fisher_exact([[k, n - k], [int(peer["reached"].sum()), len(peer["reached"]) - int(peer["reached"].sum())]])[1]
            versus = f"{fisher:.2f} / {p_vs_peer(list(arm['episodes']), list(peer['episodes'])):.2f}, {p_vs_peer(list(arm['final']), list(peer['final'])):.2f}"
        to_threshold = np.median(hits) if len(hits) else np.nan
        final = f"{np.median(arm['final']):.1f} ({np.mean(arm['final']):.1f})"
        print(f"| {name} | {n} | {k}/{n} ({k / n:.0%}) | {to_threshold:,.0f} | {final} | {np.mean(arm['run']):,.0f} | {versus} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(*(sys.argv[1:] or ["results/ars_rep"])))
