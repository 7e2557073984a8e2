"""Is a chain of mixed generations distributed as its distributions? (README, "Correctness of importance mixing")

A single mixing step can be exact while a chain of them drifts: archived generations share
members, and a member that was not reused carries the information that rule 1 rejected it.
Here the search distribution random-walks (or drifts) in 1-D by ~0.125 sigma per generation
(overlap lambda ~ 0.95, K = 3 archived generations), each generation mixed from the previous
ones as a run does. Members are standardised by their generation's distribution; per chain,
the mean of z and of z^2 after a burn-in; across independent chains, their means with standard
errors from the spread between chains (members of one chain are correlated, so pooling them
would understate the error). Also a KS test of the last generation of every chain.

    python benchmarks/mixing_chains.py [--chains 100] [--generations 200] [variants ...]
    python benchmarks/mixing_chains.py --drift5 [--chains 2000]

``--drift5``: the library's ``imix_cli.mix`` as a user calls it, in 5-D: ``exact``, K = 3, N = 20,
``min_fresh=1``, the mean drifting 0.05 sigma per generation along the first coordinate, 200
generations (the first 10 dropped); E[z] and E[z^2] per coordinate over independent chains, each
chain its own seed, standard errors from the spread between chains.

tests/test_mixing.py runs the same statistic (60 chains) as a test.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy import stats

from imix_cli.core.mixing import VARIANTS, DiagonalGaussian, mix, variant_spec


def chains(variant, drift, chains=100, generations=200, popsize=50, k=3, step=0.125, seed=0, burn_in=20, min_fresh=0):
    rng = np.random.default_rng(seed)
    first, second, last = [], [], []
    reused = older = 0
    for _ in range(chains):
        mean, log_std, archive, zs = 0.0, 0.0, [], []
        for t in range(generations):
            g = mix(DiagonalGaussian([mean], [np.exp(log_std)]), archive, popsize, rng, variant=variant, eim_generations=k, min_fresh=min_fresh)
            z = (g.samples[:, 0] - mean) / np.exp(log_std)
            if t >= burn_in:
                zs.append(z)
                reused, older = reused + g.reused, older + g.reused_from_older
            archive = [g, *archive][: variant_spec(variant).depth(k)]
            mean += np.exp(log_std) * (drift + step * rng.standard_normal())
            log_std += 0.02 * rng.standard_normal()
        zs = np.concatenate(zs)
        first.append(zs.mean())
        second.append(np.mean(zs * zs))
        last.append(z)
    first, second = np.array(first), np.array(second)
    n = (generations - burn_in) * chains * popsize
    return {
        "mean": first.mean(),
        "z_mean": first.mean() / (first.std(ddof=1) / np.sqrt(chains)),
        "E[z^2]": second.mean(),
        "z_var": (second.mean() - 1.0) / (second.std(ddof=1) / np.sqrt(chains)),
        "ks_p_last": stats.kstest(np.concatenate(last), "norm").pvalue,
        "reuse": reused / n,
        "from_older": older / n,
    }


def drift5(chains=2000, generations=200, popsize=20, dim=5, k=3, drift=0.05, burn_in=10):
    """Per coordinate: E[z^2] and E[z] over ``chains`` chains of ``imix_cli.mix`` (see the module docstring)."""
    from imix_cli import mix

    second, first = np.empty((chains, dim)), np.empty((chains, dim))
    for c in range(chains):
        rng = np.random.default_rng(10_000 + c)
        archive, s1, s2, n = [], np.zeros(dim), np.zeros(dim), 0
        for t in range(generations):
            mean = np.zeros(dim)
            mean[0] = drift * t
            g = mix(DiagonalGaussian(mean, np.ones(dim)), archive, popsize, rng, variant="exact", eim_generations=k, min_fresh=1)
            archive = [g, *archive][:k]
            if t >= burn_in:
                z = g.samples - mean
                s1, s2, n = s1 + z.sum(axis=0), s2 + (z * z).sum(axis=0), n + popsize
        first[c], second[c] = s1 / n, s2 / n
    print(
        f"{chains} chains x {generations} generations (first {burn_in} dropped), N={popsize}, d={dim}, K={k}, exact, min_fresh=1, "
        f"mean drifting {drift} sigma/generation on coordinate 0"
    )
    print("| coordinate | E[z^2] ± s.e. (z-score) | E[z] ± s.e. (z-score) |")
    print("|---|---:|---:|")
    for j in range(dim):
        m2, se2 = second[:, j].mean(), second[:, j].std(ddof=1) / np.sqrt(chains)
        m1, se1 = first[:, j].mean(), first[:, j].std(ddof=1) / np.sqrt(chains)
        print(f"| {j} | {m2:.4f} ± {se2:.4f} ({(m2 - 1) / se2:+.2f}) | {m1:+.4f} ± {se1:.4f} ({m1 / se1:+.2f}) |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("variants", nargs="*", default=list(VARIANTS))
    parser.add_argument("--chains", type=int, default=100)
    parser.add_argument("--generations", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--drift5", action="store_true", help="the 5-D drifting chain of imix_cli.mix (module docstring)")
    args = parser.parse_args(argv)
    if args.drift5:
        drift5(args.chains if args.chains != 100 else 2000, args.generations)
        return 0
    print("| variant | motion | mean of z (z-score) | E[z^2] (z-score) | KS p, last generations | reuse | from older generations |")
    print("|---|---|---|---|---|---|---|")
    for variant in args.variants:
        for drift, motion in ((0.0, "random walk"), (0.1, "drift 0.1 sigma/gen")):
            r = chains(variant, drift, args.chains, args.generations, seed=args.seed)
            print(
                f"| {variant} | {motion} | {r['mean']:+.4f} ({r['z_mean']:+.1f}) | {r['E[z^2]']:.4f} ({r['z_var']:+.1f}) | "
                f"{r['ks_p_last']:.2g} | {100 * r['reuse']:.1f} % | {100 * r['from_older']:.2f} % |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
