"""Importance-weighted reuse over chains of distributions moved from outside: the weighted moments of the pool.

``eim_variant=weighted`` (:mod:`imix_cli.core.mixing.weighted_reuse`) tells the ES a pool of fresh and archived members
with self-normalised weights; under the current distribution the weighted pool should have the moments of N(0, 1)
in every standardised coordinate. Self-normalised weights are consistent, not unbiased (a bias of order 1/ESS).
This measures it, and the same pools told unweighted (what wrong weights would give), over 40 chains x 300
generations (3-D, popsize 20, K = 3; each sigma takes a log-normal step of 0.05 per generation) with the mean
random-walking 0.25 sigma, drifting 0.2 sigma, or random-walking 1 sigma per generation. ``tests/test_weighted_reuse.py``
runs a smaller version with tolerances; docs/research/reuse_modes.md quotes this one.

    python benchmarks/weighted_chains.py
"""

from __future__ import annotations

import numpy as np

from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.mixing.generation import Archive, MixingSettings
from imix_cli.core.mixing.weighted_reuse import archived_part, plan_weighted


class _Chain:
    """What plan_weighted reads of an ES whose distribution is moved from outside."""

    weights_utilities = "sum"

    def __init__(self, dist, n):
        self.distribution, self.popsize = dist, n

    def ask(self, rng):
        return self.distribution.sample(self.popsize, rng)


def chain(seed, gens=300, d=3, n=20, step=0.25, drift=0.0, log_sigma_step=0.05, mode="right"):
    """(E_w[z], E_w[z^2], fresh draws per generation, pool ESS) averaged over generations 10 on."""
    rng = np.random.default_rng(seed)
    mean, sigma = np.zeros(d), np.ones(d)
    settings = MixingSettings("weighted")
    archive = Archive()
    z1 = z2 = 0.0
    count = fresh = 0
    ess = 0.0
    for t in range(gens):
        dist = DiagonalGaussian(mean.copy(), sigma.copy())
        g = plan_weighted(_Chain(dist, n), archive, settings, rng)
        z = (g.samples - mean) / sigma
        w = getattr(g, "weights", None)
        if w is None or mode == "uniform":
            w = np.full(len(z), 1 / len(z))
        if t >= 10:
            z1 += float(w @ z.mean(axis=1))
            z2 += float(w @ (z**2).mean(axis=1))
            count += 1
            fresh += int(np.count_nonzero(g.source == 0))
            ess += getattr(g, "ess", n)
        archive.generations = [archived_part(g), *archive.generations][: settings.depth]
        archive.returns = [np.zeros(int(np.count_nonzero(g.source == 0))), *archive.returns][: settings.depth]
        mean = mean + step * sigma * rng.standard_normal(d) + drift * sigma
        sigma = sigma * np.exp(log_sigma_step * rng.standard_normal(d))
    return z1 / count, z2 / count, fresh / count, ess / count


def main() -> int:
    print("| weights | mean moved by | E[z] (z-score) | E[z^2] (z-score) | fresh per generation | pool ESS |")
    print("|---|---|---:|---:|---:|---:|")
    for mode in ("right", "uniform"):
        for label, kw in (("walk 0.25", {}), ("drift 0.2", {"step": 0.0, "drift": 0.2}), ("walk 1.0", {"step": 1.0})):
            r = np.array([chain(s, mode=mode, **kw) for s in range(40)])
            m = r.mean(0)
            se = r.std(0, ddof=1) / np.sqrt(len(r))
            print(f"| {mode} | {label} | {m[0]:.4f} ({m[0] / se[0]:+.1f}) | {m[1]:.4f} ({(m[1] - 1) / se[1]:+.1f}) | {m[2]:.1f} | {m[3]:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
