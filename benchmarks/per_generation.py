"""Per generation against per episode: SNES on a noise-free sphere, the reuse dialled by ``min_fresh``.

Why (docs/research/bias.md, "Per generation against per episode"): mixing saves episodes, not
generations. In the transient an ES with mixing moves as far per generation as without; at the
noise floor a generation with reuse r holds only (1 - r) N members not told before, and the
steady-state error of the mean grows as ~1/(1 - r). This prints f(mean) at a few generations,
median over seeds, with its ratio to no mixing and the Mann-Whitney p at the last one.

    python benchmarks/per_generation.py [--seeds 10] [--generations 500]

20-d sphere f = |x - 1|^2, N = 50, SNES at imix's defaults (sigma0 0.25, Adam lr 0.01, weight decay
0.05 in the estool form), ``exact`` mixing.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy import stats

from imix_cli import MixingES, make_es

DIM, POPSIZE = 20, 50
ROWS = (("none", None, 0), ("exact, min_fresh 1", "exact", 1), ("exact, min_fresh 10", "exact", 10),
        ("exact, min_fresh 25", "exact", 25), ("exact, min_fresh 40", "exact", 40))  # fmt: skip


def sphere(x: np.ndarray) -> np.ndarray:
    return np.sum((x - 1.0) ** 2, axis=1)


def run(variant, min_fresh: int, seed: int, checks) -> tuple[dict, float, int]:
    es = MixingES(make_es("snes", dim=DIM, popsize=POPSIZE), variant, rng=seed, min_fresh=min_fresh)
    out = {}
    for g in range(1, max(checks) + 1):
        x = es.ask()
        es.tell(x, -sphere(x))
        if g in checks:
            out[g] = float(sphere(es.distribution.mean[None])[0])
    return out, es.reuse, es.evaluations


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--generations", type=int, default=500)
    args = parser.parse_args(argv)
    checks = sorted({c for c in (25, 50, 100, 200) if c < args.generations} | {args.generations})
    print(f"SNES, {DIM}-d sphere, N = {POPSIZE}, {args.seeds} seeds: median f(mean) (ratio to no mixing)\n")
    print("| rule | reuse | episodes | " + " | ".join(f"gen {c}" for c in checks) + " | 1/(1 - r) |")
    print("|---|---:|---:|" + "---:|" * len(checks) + "---:|")
    base = None
    for label, variant, min_fresh in ROWS:
        runs = [run(variant, min_fresh, seed, checks) for seed in range(args.seeds)]
        values = {c: np.array([r[0][c] for r in runs]) for c in checks}
        reuse = float(np.mean([r[1] for r in runs]))
        base = base or values
        cells = []
        for c in checks:
            ratio = np.median(values[c]) / np.median(base[c])
            p = f", p = {stats.mannwhitneyu(values[c], base[c]).pvalue:.2g}" if c == checks[-1] and values is not base else ""
            cells.append(f"{np.median(values[c]):.3g} ({ratio:.2f}×{p})")
        episodes = np.mean([r[2] for r in runs])
        print(f"| {label} | {100 * reuse:.0f} % | {episodes:,.0f} | " + " | ".join(cells) + f" | {1 / (1 - reuse):.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
