"""Reuse rate and bias of the three importance-mixing variants between two 1-D Gaussians.

For each (mean shift, scale change) pair: the overlap lambda = integral of min(p_old, p_new)
(Monte Carlo), the measured reuse rate of each variant, and a bias statistic: the fraction of
members of the mixed generation that fall where p_new > p_old, minus the same fraction under
exact draws from p_new, in units of its standard error (|z| > 4 means a real bias). That region
is where rule 2's samples concentrate, so a procedure that mis-balances rule-1 and rule-2 members
shows up there first. A KS test of the pooled members against p_new is printed too.

    python benchmarks/mixing_bias.py [--popsize 20] [--repeats 20000]
"""

import argparse

import numpy as np
from scipy import stats

from imix_cli.core.mixing import DiagonalGaussian, mix


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--popsize", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=20000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    old = DiagonalGaussian([0.0], [1.0])
    print(f"popsize={args.popsize}, repeats={args.repeats} (members pooled: {args.popsize * args.repeats})")
    print("| shift | scale | lambda | variant | reuse | bias z | KS p |")
    print("|---:|---:|---:|---|---:|---:|---:|")
    for shift, scale in [(0.1, 1.0), (0.3, 1.0), (1.0, 1.0), (0.0, 0.8), (0.0, 1.25), (0.5, 0.7)]:
        new = DiagonalGaussian([shift], [scale])
        exact = new.sample(400000, rng)
        region_exact = np.mean(new.log_prob(exact) > old.log_prob(exact))
        overlap = np.mean(np.minimum(1.0, np.exp(old.log_prob(exact) - new.log_prob(exact))))
        for variant in ("paper", "exact", "sun2009"):
            pooled, reused = [], 0
            for _ in range(args.repeats):
                archive = [(old, old.sample(args.popsize, rng))]
                if variant == "exact":  # a second, older generation drawn from the same old density
                    archive.append((old, old.sample(args.popsize, rng)))
                g = mix(new, archive, args.popsize, rng, variant=variant, min_fresh=0)  # the rules alone
                pooled.append(g.samples[:, 0])
                reused += g.reused
            x = np.concatenate(pooled)[:, None]
            frac = np.mean(new.log_prob(x) > old.log_prob(x))
            z = (frac - region_exact) / np.sqrt(region_exact * (1 - region_exact) / x.shape[0])
            ks = stats.kstest(x[:, 0], "norm", args=(shift, scale))
            print(f"| {shift} | {scale} | {overlap:.3f} | {variant} | {reused / x.shape[0]:.3f} | {z:+.1f} | {ks.pvalue:.3g} |")


if __name__ == "__main__":
    main()
