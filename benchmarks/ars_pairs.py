"""Are mixed ARS pairs distributed as ARS pairs along a run, and how much do they reuse? (docs/ars.md)

Chains of generations as a run builds them (imix_cli.core.mixing.generation's plan/finish with
imix_cli.core.mixing.mirrored), d = 2, N = 10 directions, nu = 1, 300 generations, K = 3. Every member is
standardised by the mean and nu of its generation; per chain E[z^2] after a burn-in of 20; across
independent chains its mean and the z-score of (E[z^2] - 1) with the standard error from the
spread between chains (tests/test_ars.py's statistic).

Motions of the mean:
* ``walk`` / ``drift``: exogenous (the mean is set from outside: 0.25 nu random walk, 0.2 nu drift);
  the setting of imix's mixing guarantees -- E[z^2] must be 1;
* ``ars(lr)``: ARS's own steps on a noisy slope (returns x_0 + N(0, 0.25)): the mean is moved by
  the returns of the members it then reuses. Also OpenES and SNES (not mirrored, 20 members) in
  the same loop, for comparison.

    python benchmarks/ars_pairs.py [--chains 30]
"""

from __future__ import annotations

import argparse

import numpy as np

from imix_cli.core.algorithms import ARS, make_es
from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.mixing.generation import Archive, MixingSettings, finish_generation, plan_generation


def chains(make_es_fn, variant: str, motion: str, chains: int, generations: int = 300, burn_in: int = 20, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    second, reuse = [], []
    for _ in range(chains):
        es = make_es_fn()
        archive, settings, zs, reused, members = Archive(), MixingSettings(variant, 3), [], 0, 0
        mean = np.zeros(es.dim)
        for t in range(generations):
            if motion in ("walk", "drift"):  # exogenous: the mean is set, the ES's step is discarded
                es._mu = mean.copy()
                es._dist = DiagonalGaussian(mean, es.sigma)
            plan = plan_generation(es, archive, settings, rng)
            g, dist = plan.generation, es.distribution
            if t >= burn_in:
                zs.append(((g.samples - dist.mean) / dist.std).ravel())
                reused, members = reused + g.reused, members + g.samples.shape[0]
            x = g.samples[plan.evaluate]
            finish_generation(es, archive, settings, plan, x[:, 0] + 0.5 * rng.standard_normal(x.shape[0]))
            if motion == "walk":
                mean = mean + 0.25 * rng.standard_normal(es.dim)
            elif motion == "drift":
                mean = mean + 0.2 * np.eye(es.dim)[0]
        zs = np.concatenate(zs)
        second.append(np.mean(zs * zs))
        reuse.append(reused / members)
    second = np.array(second)
    return {"E[z^2]": second.mean(), "z": (second.mean() - 1.0) / (second.std(ddof=1) / np.sqrt(chains)), "reuse": float(np.mean(reuse))}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--chains", type=int, default=30)
    args = parser.parse_args(argv)
    cases = [
        ("ARS", "walk", lambda: ARS(2, popsize=20, sigma=1.0, lr=0.4)),
        ("ARS", "drift", lambda: ARS(2, popsize=20, sigma=1.0, lr=0.4)),
        *[(f"ARS lr {lr}", "ars", (lambda lr=lr: ARS(2, popsize=20, sigma=1.0, lr=lr))) for lr in (0.05, 0.2, 0.4)],
        *[(f"OpenES lr {lr}", "own", (lambda lr=lr: make_es("openes", 2, popsize=20, sigma=1.0, lr=lr, weight_decay=0.0))) for lr in (0.05, 0.25)],
        *[(f"SNES lr {lr}", "own", (lambda lr=lr: make_es("snes", 2, popsize=20, sigma=1.0, lr=lr, weight_decay=0.0))) for lr in (0.05, 0.25)],
    ]
    print("| ES | mean moved by | variant | E[z^2] (z-score) | members reused |")
    print("|---|---|---|---|---|")
    for variant in ("sun2009", "exact"):
        for label, motion, make in cases:
            r = chains(make, variant, motion, args.chains)
            moved = {"walk": "random walk 0.25 nu/gen", "drift": "drift 0.2 nu/gen"}.get(motion, "its own steps")
            print(f"| {label} | {moved} | {variant} | {r['E[z^2]']:.3f} ({r['z']:+.1f}) | {100 * r['reuse']:.1f} % |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
