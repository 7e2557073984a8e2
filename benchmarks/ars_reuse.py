"""ARS's reuse against its step size (docs/ars.md): the table of the ``experiment=ars_reuse`` runs.

Reads, for each run of the two sweeps below (one seed each), its CSV and its final checkpoint
(kept in ``.checkpoints/seed_0.npz``) and prints one Markdown row: the members reused after the
V2 warm-up (= episodes saved, at most 50 % for mirrored pairs), the anchors reused, the episodes,
the population's mean training return over the last 5 generations, and E[z^2] of the last archived
anchors about the final mean in units of nu^2 per coordinate (1 for draws of N(m, nu^2 I); ~0 when
the mean has moved onto the anchors it reuses).

    imix run -m algo=ars env=swimmer +ars=swimmer eim=true lr=0.02,0.005,0.002,0.0005 seeds=1 generations=40 eval_mean_every=0 experiment=ars_reuse
    imix run -m algo=ars env=hopper +ars=hopper eim=true lr=0.01,0.001,0.0001 seeds=1 generations=12 eval_mean_every=0 experiment=ars_reuse
    python benchmarks/ars_reuse.py [results_dir]
"""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd

from imix_cli.core.evaluation.parallel import build_evaluator
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.config.run_spec import resume_identity
from imix_cli.running.loop.lockstep import loop_settings, new_seed_state
from imix_cli.running.loop.resume import load_checkpoint

#: env -> (step sizes, generations, warm-up generations that do not mix), as in the sweeps above
SWEEPS = {"hopper": (("0.01", "0.001", "0.0001"), 12, 5), "swimmer": (("0.02", "0.005", "0.002", "0.0005"), 40, 0)}


def main(results_dir: str = "results") -> None:
    print("| env | α | ν | 2α/ν | generations | members reused (= episodes saved) | anchors reused | episodes | "
          "population mean training return, last 5 generations | last archived anchors' E[z²] about the final mean |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for env, (step_sizes, generations, warmup) in SWEEPS.items():
        for lr in step_sizes:
            overrides = ["algo=ars", f"env={env}", f"+ars={env}", "eim=true", f"lr={lr}", "seeds=1", f"generations={generations}", "eval_mean_every=0"]
            (spec,) = validate_overrides([*overrides, "experiment=ars_reuse", f"results_dir={results_dir}"])
            frame = pd.read_csv(spec.run_dir / "seed_0.csv")
            mixing = frame[frame["generation"] >= warmup]
            members = float(mixing["reused"].sum() / mixing["popsize"].sum())
            evaluator = build_evaluator(spec)
            fresh = new_seed_state(loop_settings(spec, evaluator), 0)
            st = load_checkpoint(
                spec.run_dir, 0, resume_identity(spec.identity()), fresh, spec=spec, max_steps=int(evaluator.max_steps), policy_dim=evaluator.num_params
            )
            if st is None:
                raise SystemExit(f"{spec.run_dir}: no final checkpoint to read")
            anchors = st.archive.generations[-1].samples
            z2 = float(np.mean((anchors - st.es.distribution.mean) ** 2) / spec.sigma**2)
            runs = f"{generations} ({warmup} warm-up)" if warmup else str(generations)
            print(f"| {evaluator.env_name} | {float(lr):g} | {spec.sigma:g} | {2 * float(lr) / spec.sigma:.3g} | {runs} | {members:.1%} | "
                  f"{2 * members:.1%} | {int(frame['evaluations'].iloc[-1])} | {frame['mean_score'].iloc[-5:].mean():.1f} | {z2:.2g} |")  # fmt: skip


if __name__ == "__main__":
    main(*sys.argv[1:2])
