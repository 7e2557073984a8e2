"""One generation of an evolution strategy with importance mixing -- no files, no processes.

This is the step the runner takes for every seed (in lockstep, with one batched rollout for
all of them), the README's library example takes, and the tests take::

    plan = plan_generation(es, archive, settings, rng)          # mix: which members, which to evaluate
    returns = evaluate(plan.generation.samples[plan.evaluate])  # episodes for those only
    fitness = finish_generation(es, archive, settings, plan, returns)  # stored + new returns -> tell

Why the two halves: between them the runner evaluates the members of every seed of a
process in one batch, which only pays off if planning and finishing do no evaluation.

Which members are evaluated. Fresh members always. A reused member keeps the return it was
evaluated with -- that is the point of importance mixing -- unless a remedy for the
selection bias of stored returns asks to measure it again (README, "Reused returns and
selection bias"): its return is older than ``reeval_age`` generations, or a coin of
probability ``reeval_prob`` says so. A re-evaluated member keeps its place and its
parameters; only its return is new, so the generation is distributed exactly as without the
remedy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imix_cli.mixing import Generation, mix


@dataclass(frozen=True)
class MixingSettings:
    """How generations are built.

    Attributes
    ----------
    variant : {None, "paper", "sun2009", "eim", "eim_paper"}
        The :func:`~imix_cli.mixing.mix` variant; None draws every generation fresh.
    eim_generations : int
        K, the archived generations ``"eim"``/``"eim_paper"`` reuse from.
    alpha : float
        ``"sun2009"``'s minimal refresh rate.
    reeval_age : int or None
        Re-evaluate a reused member whose return was measured more than this many
        generations ago (None: never).
    reeval_prob : float
        Re-evaluate each reused member with this probability.
    """

    variant: str | None = None
    eim_generations: int = 3
    alpha: float = 0.0
    reeval_age: int | None = None
    reeval_prob: float = 0.0

    @property
    def depth(self) -> int:
        """Number of generations kept in the archive."""
        if self.variant is None:
            return 0
        return self.eim_generations if self.variant in ("eim", "eim_paper") else 1


@dataclass
class Archive:
    """Earlier generations of one search, newest first, with their members' returns and ages."""

    generations: list = field(default_factory=list)  # Generation objects
    returns: list = field(default_factory=list)  # (popsize,) returns of their members
    ages: list = field(default_factory=list)  # (popsize,) generations since each return was measured


@dataclass
class Plan:
    """A generation about to be evaluated."""

    generation: Generation
    evaluate: np.ndarray  # indices of the members that need an episode
    age: np.ndarray  # age of every member's return once the generation is evaluated

    @property
    def reevaluated(self) -> int:
        """Reused members evaluated again (by ``reeval_age`` / ``reeval_prob``)."""
        return int(np.count_nonzero(self.generation.source[self.evaluate] > 0))


def plan_generation(es, archive: Archive, settings: MixingSettings, rng: np.random.Generator) -> Plan:
    """Draw (or mix) the next generation of ``es`` and decide which members to evaluate."""
    if getattr(es, "mirrored", False):  # mirrored pairs (ARS): anchors mixed, mirrors fresh (imix_cli.mirrored)
        from imix_cli.mirrored import plan_mirrored

        return plan_mirrored(es, archive, settings, rng)
    dist, popsize = es.distribution, es.popsize
    if settings.variant is None or not archive.generations:
        g = Generation(es.ask(rng), np.zeros(popsize, np.int64), np.full(popsize, -1, np.int64), dist)
    else:
        g = mix(dist, archive.generations, popsize, rng, variant=settings.variant, alpha=settings.alpha, eim_generations=settings.eim_generations)
    age = np.zeros(popsize, dtype=np.int64)
    for k, ages in enumerate(archive.ages, start=1):
        from_k = g.source == k
        age[from_k] = ages[g.index[from_k]] + 1
    evaluate = g.source == 0
    reused = np.flatnonzero(~evaluate)
    if settings.reeval_age is not None:
        evaluate[reused] |= age[reused] > settings.reeval_age
    if settings.reeval_prob > 0.0:
        evaluate[reused] |= rng.random(reused.size) < settings.reeval_prob
    age[evaluate] = 0
    return Plan(g, np.flatnonzero(evaluate), age)


def finish_generation(es, archive: Archive, settings: MixingSettings, plan: Plan, returns) -> np.ndarray:
    """Assemble the generation's fitness (stored returns + ``returns`` of ``plan.evaluate``), tell
    the ES, archive the generation; return the fitness (one per member)."""
    if getattr(es, "mirrored", False):
        from imix_cli.mirrored import finish_mirrored

        return finish_mirrored(es, archive, settings, plan, returns)
    g = plan.generation
    fitness = np.empty(g.samples.shape[0])
    for k, stored in enumerate(archive.returns, start=1):  # reused members keep their stored return
        from_k = g.source == k
        fitness[from_k] = stored[g.index[from_k]]
    fitness[plan.evaluate] = returns  # ... unless evaluated again
    es.tell(g.samples, fitness)
    depth = settings.depth
    if depth:
        archive.generations = [g, *archive.generations][:depth]
        archive.returns = [fitness, *archive.returns][:depth]
        archive.ages = [plan.age, *archive.ages][:depth]
    return fitness
