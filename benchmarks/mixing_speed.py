"""Time one importance-mixing step against plain sampling of the same population.

For d in 10^3, 10^5, 10^6 (N = 50, K = 3 for eim): build an archive of three earlier
generations with a realistic small move of the search distribution between generations
(high overlap, as OpenES/SNES see in the paper), then time `mix` and `new_dist.sample(N)`
in the same run. Samples are float32 from d = 10^5 on (both sides), as the library
recommends for memory. Prints the median of several repetitions and the ratio; the
core-library target is eim <= 1.5x plain sampling at d = 10^6.

    python benchmarks/mixing_speed.py [--dims 1000 100000 1000000] [--repeats 5]
"""

import argparse
import time

import numpy as np

from imix_cli.mixing import DiagonalGaussian, mix


def median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def bench(dim, popsize=50, generations=3, repeats=5, seed=0, variants=("paper", "eim", "sun2009")):
    rng = np.random.default_rng(seed)
    dtype = np.float32 if dim >= 100_000 else np.float64
    # A move of ~0.05 sigma per coordinate in total Mahalanobis length keeps overlap high.
    step = 0.05 / np.sqrt(dim)
    dists = [DiagonalGaussian(np.full(dim, step * k), np.full(dim, 0.25 * (1 - 0.001 * k) ** (1 / np.sqrt(dim))), dtype=dtype) for k in range(generations + 1)]
    archive = []
    for dist in dists[:-1]:
        archive.insert(0, mix(dist, archive, popsize, rng, variant="eim"))
    new = dists[-1]
    results = {"sample": median_time(lambda: new.sample(popsize, rng), repeats)}
    reuse = {}
    for variant in variants:
        results[variant] = median_time(lambda: mix(new, archive, popsize, rng, variant=variant, eim_generations=generations), repeats)
        reuse[variant] = mix(new, archive, popsize, rng, variant=variant).reused / popsize
    return results, reuse


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dims", type=int, nargs="+", default=[1_000, 100_000, 1_000_000])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print("| d | plain sample (s) | variant | mix (s) | ratio | reuse |")
    print("|---:|---:|---|---:|---:|---:|")
    for dim in args.dims:
        results, reuse = bench(dim, repeats=args.repeats)
        for variant in ("paper", "eim", "sun2009"):
            print(f"| {dim} | {results['sample']:.4f} | {variant} | {results[variant]:.4f} | {results[variant] / results['sample']:.2f} | {reuse[variant]:.2f} |")


if __name__ == "__main__":
    main()
