"""Time one importance-mixing step against plain sampling of the same population.

For each d (N = 50, K = 3 for exact): an archive of three earlier generations with a realistic
small move of the search distribution between generations (high overlap, as OpenES/SNES see in
the paper), then `mix` and `new_dist.sample(N)` timed in the same run. Samples are float32 from
d = 10^5 on (both sides), as the library recommends for memory. Prints the median of several
repetitions and the ratio; the core-library target is exact <= 1.5x plain sampling at d = 10^6.
The measurement lives in :mod:`imix_cli.bench` (``imix bench mixing`` prints the same table).

    python benchmarks/mixing_speed.py [--dims 1000 100000 1000000] [--repeats 5]
"""

import argparse

from imix_cli.bench import format_mixing, median_time, mixing_rows, mixing_times  # noqa: F401  (re-exported)


def bench(dim, popsize=50, generations=3, repeats=5, seed=0, variants=("paper", "exact", "sun2009")):
    """``(median seconds per variant and of plain sampling, reuse rate per variant)`` at dimension ``dim``."""
    return mixing_times(dim, popsize, generations, repeats, seed, variants)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dims", type=int, nargs="+", default=[1_000, 100_000, 1_000_000])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(format_mixing(mixing_rows(args.dims, args.repeats)))


if __name__ == "__main__":
    main()
