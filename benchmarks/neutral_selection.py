"""Selection bias of stored returns: what each ES does with and without mixing when fitness carries no signal.

Under *neutral selection* -- every episode's return an independent N(0, 1) draw, nothing to
learn -- an ES should behave the same whether or not it reuses members: the step size follows
its own neutral drift, the mean random-walks. Importance mixing reuses a member's return after
that return already moved the distribution toward it; a lucky member is then likely to be
reused (it sits where the new density is high) and stays elite, which pulls the distribution
in again. This script measures the size of that feedback for every ES and mixing variant, and
what the remedies (``reeval_age``, ``reeval_prob``: re-evaluate reused members) do to it.

Also a *noisy* benchmark: a sphere whose every evaluation carries noise of the size of the
fitness differences across the population, where a lucky return can be reused for many
generations.

Usage::

    python benchmarks/neutral_selection.py [--seeds 3] [--generations 400] [--out table.md]

Prints a markdown table: sigma/sigma0 at the end (mean over seeds; OpenES keeps sigma fixed,
so its column shows the mean's displacement instead), reuse, and for the noisy sphere the
final true f(mean). d = 130 (the CartPole policy's size), popsize 50, the paper's sigma and lr.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time

import numpy as np

from imix_cli.core.algorithms import make_es
from imix_cli.core.mixing.generation import Archive, MixingSettings, finish_generation, plan_generation

ALGOS = ("openes", "snes", "cem", "cmaes")
VARIANTS = (None, "paper", "sun2009", "exact", "eim_paper")
REMEDIES = {"none": {}, "age 5": {"reeval_age": 5}, "age 20": {"reeval_age": 20}, "prob 0.1": {"reeval_prob": 0.1}}


def run(algo, settings, objective, seed, generations, dim=130, popsize=50):
    rng = np.random.default_rng(seed)
    noise_rng = np.random.default_rng(seed + 10_000)
    es = make_es(algo, dim, popsize=popsize, sigma=0.25, lr=0.01, weight_decay=0.0, mean=np.full(dim, 0.5) if objective == "noisy" else None)
    archive = Archive()
    mean0, sigma0 = es.mean.copy(), es.distribution.sigma_mean
    reused = evaluated = 0
    for _ in range(generations):
        plan = plan_generation(es, archive, settings, rng)
        x = plan.generation.samples[plan.evaluate]
        if objective == "neutral":
            returns = noise_rng.standard_normal(x.shape[0])
        else:  # noisy sphere: true f spread across a population ~ sigma^2 sqrt(2d); noise of that size
            returns = -np.sum(x * x, axis=1) + 0.25**2 * np.sqrt(2 * dim) * noise_rng.standard_normal(x.shape[0])
        finish_generation(es, archive, settings, plan, returns)
        reused += plan.generation.reused
        evaluated += plan.evaluate.size
    sigma_ratio = es.distribution.sigma_mean / sigma0
    displacement = float(np.linalg.norm(es.mean - mean0) / (sigma0 * np.sqrt(dim)))
    true_f = float(np.sum(es.mean**2))
    return sigma_ratio, displacement, reused / (generations * popsize), evaluated, true_f


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--generations", type=int, default=400)
    parser.add_argument("--algos", default=",".join(ALGOS))
    parser.add_argument("--remedies", default=",".join(REMEDIES))
    parser.add_argument("--objective", choices=("neutral", "noisy"), default="neutral")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    head = "| ES | mixing | remedy | sigma/sigma0 | mean displacement | reuse | episodes | true f(mean) |"
    print(f"objective={args.objective}, d=130, popsize 50, {args.generations} generations, {args.seeds} seeds (mean over seeds)")
    print(head)
    print("|---|---|---|---|---|---|---|---|")
    for algo, variant in itertools.product(args.algos.split(","), VARIANTS):
        for remedy in args.remedies.split(",") if variant else ["none"]:
            settings = MixingSettings(variant, **REMEDIES[remedy])
            out = np.array([run(algo, settings, args.objective, s, args.generations) for s in range(args.seeds)])
            sig, disp, reuse, episodes, f = out.mean(axis=0)
            print(f"| {algo} | {variant or 'none'} | {remedy} | {sig:.3f} | {disp:.3f} | {100 * reuse:.1f} % | {episodes:,.0f} | {f:.3g} |", flush=True)
    print(f"({time.perf_counter() - started:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
