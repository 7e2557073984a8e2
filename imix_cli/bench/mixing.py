"""``imix bench mixing``: one importance-mixing step against plain sampling of the same population."""

from __future__ import annotations

import numpy as np

from imix_cli.bench.common import median_time, table


def mixing_times(dim: int, popsize: int = 50, generations: int = 3, repeats: int = 5, seed: int = 0,
                 variants=("paper", "exact", "sun2009")):  # fmt: skip
    """Median seconds of one ``mix`` per variant and of ``new_dist.sample(popsize)``, and reuse rates.

    The archive holds ``generations`` earlier generations with a realistic small move of the
    search distribution between them (high overlap, as OpenES/SNES see in the paper). Samples
    are float32 from d = 10^5 on (both sides), as the library recommends for memory.
    """
    from imix_cli.core.mixing import DiagonalGaussian, mix

    rng = np.random.default_rng(seed)
    dtype = np.float32 if dim >= 100_000 else np.float64
    # A move of ~0.05 sigma per coordinate in total Mahalanobis length keeps overlap high.
    step = 0.05 / np.sqrt(dim)
    dists = [DiagonalGaussian(np.full(dim, step * k), np.full(dim, 0.25 * (1 - 0.001 * k) ** (1 / np.sqrt(dim))), dtype=dtype) for k in range(generations + 1)]
    archive = []
    for dist in dists[:-1]:
        archive.insert(0, mix(dist, archive, popsize, rng, variant="exact", min_fresh=0))
    new = dists[-1]
    # Small steps (tens of microseconds at d = 130) are timed over batches of calls; the compiled
    # steps (imix_cli.core.mixing.kernels) are loaded or compiled by a first, untimed call.
    calls = max(1, 200_000 // (popsize * dim))

    def per_call(fn):
        return median_time(lambda: [fn() for _ in range(calls)], repeats) / calls

    results = {"sample": per_call(lambda: new.sample(popsize, rng))}
    reuse = {}
    for variant in variants:
        # the rules alone (min_fresh=0), as this table has always measured them
        reuse[variant] = mix(new, archive, popsize, rng, variant=variant, eim_generations=generations, min_fresh=0).reused / popsize
        results[variant] = per_call(lambda v=variant: mix(new, archive, popsize, rng, variant=v, eim_generations=generations, min_fresh=0))
    return results, reuse


def mixing_rows(dims=(130, 1_000, 10_000, 100_000, 1_000_000), repeats: int = 5, variants=("paper", "exact", "sun2009")) -> list[dict]:
    rows = []
    for dim in dims:
        results, reuse = mixing_times(dim, repeats=repeats, variants=variants)
        for v in variants:
            rows.append({"dim": dim, "sample": results["sample"], "variant": v, "mix": results[v], "reuse": reuse[v]})
    return rows


def format_mixing(rows: list[dict]) -> str:
    body = [
        [r["dim"], f"{r['sample'] * 1e3:.3f}", r["variant"], f"{r['mix'] * 1e3:.3f}", f"{r['mix'] / r['sample']:.2f}",
         f"{r['reuse']:.2f}"]
        for r in rows
    ]  # fmt: skip
    return table(["d", "plain sample (ms)", "variant", "mix (ms)", "mix / sample", "reuse"], body, "rrlrrr")
