"""One generation of an evolution strategy with importance mixing -- no files, no processes.

This is the step the runner takes for every seed (in lockstep, with one batched rollout for
all of them), the README's library example takes, and the tests take::

    plan = plan_generation(es, archive, settings, rng)          # mix: which members, which to evaluate
    returns = evaluate(plan.points)                             # episodes for those only (and CMA-ES's TPA points)
    fitness = finish_generation(es, archive, settings, plan, returns)  # stored + new returns -> tell

Why the two halves: between them the runner evaluates the members of every seed of a
process in one batch, which only pays off if planning and finishing do no evaluation.

Which members are evaluated. Fresh members always. A reused member keeps the return it was
evaluated with -- that is the point of importance mixing -- unless a remedy for the
selection bias of stored returns asks to measure it again (docs/research/correctness.md, "Reused
returns and selection bias"): its return is older than ``reeval_age`` generations, a coin of
probability ``reeval_prob`` says so, or it is one of the ``reeval_count`` reused members
drawn every generation to calibrate the others (below). A re-evaluated member keeps its
place and its parameters; only its return is new, so the generation is distributed exactly
as without the remedy.

Calibrating stored returns (``reeval_count``). Why stored returns bias the search: a member
is reused when it lies where the new distribution is dense, and the distribution moved there
because of good returns -- so reused members are enriched in *lucky* returns, and a lucky
return is told again and again. How large the luck is depends on the task: nothing on a
deterministic task, everything under pure noise. Every re-evaluated reused member gives a
pair (stored return, fresh return); the pairs of recent generations (exponentially
forgotten, :data:`PAIR_MEMORY` per generation) give the least-squares line
fresh ~ alpha + beta * stored, with beta clipped to [0, 1], and every other reused member
is told alpha + beta * stored: its best prediction of what a fresh episode would return.
Under pure noise beta -> 0 and the reused members stop outranking the fresh ones; on a
deterministic task beta -> 1 and alpha -> 0, the stored returns are told as they are. Before
:data:`PAIR_MIN` pairs have been seen the stored returns are told unchanged. The archive
keeps the measured returns; only what the ES is told changes. Measured: docs/research/bias.md,
"Reused returns and the search".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imix_cli.core import numerics as xp
from imix_cli.core.bounds import Bound
from imix_cli.core.distributions import AffinePushforward
from imix_cli.core.mixing import MIXING_DEFAULTS, Generation, mix, variant_spec
from imix_cli.core.mixing.weighted_reuse import WeightedGeneration, archived_part, plan_weighted

#: The range of each numeric :class:`MixingSettings` field, checked when one is made and by ``imix run``'s config (its
#: keys ``eim_generations``, ``im_alpha``, ``reeval_*``, ``min_fresh``: :mod:`imix_cli.running.config.keys`): one copy of the numbers.
MIXING_BOUNDS = {
    "eim_generations": Bound(1, integer=True),
    "alpha": Bound(0.0, high=1.0),
    "reeval_age": Bound(1, integer=True),
    "reeval_prob": Bound(0.0, high=1.0),
    "reeval_count": Bound(0, integer=True),
    "min_fresh": Bound(0, integer=True),
}


@dataclass(frozen=True)
class MixingSettings:
    """How generations are built. The defaults are :data:`~imix_cli.core.mixing.MIXING_DEFAULTS`' (``imix run``'s), but
    ``variant``: None, the plain ES, as ``imix run`` without ``im``/``eim``.

    Attributes
    ----------
    variant : {None, "paper", "sun2009", "exact", "conditional", "eim_paper", "weighted"}
        The :func:`~imix_cli.core.mixing.mix` variant (:data:`~imix_cli.core.mixing.VARIANT_SPECS`), or ``"weighted"``:
        the archive weighted into the update (:mod:`imix_cli.core.mixing.weighted_reuse`); None draws every generation fresh.
    eim_generations : int
        K, the archived generations ``"exact"``/``"eim_paper"`` reuse from.
    alpha : float
        ``"sun2009"``'s minimal refresh rate.
    reeval_age : int or None
        Re-evaluate a reused member whose return was measured more than this many
        generations ago (None: never).
    reeval_prob : float
        Re-evaluate each reused member with this probability.
    reeval_count : int
        Re-evaluate this many reused members (drawn at random) every generation, and tell the
        ES the other reused members' stored returns calibrated on them (module docstring).
    min_fresh : int
        The minimal refresh of :func:`~imix_cli.core.mixing.mix`: at least this many members of every mixed
        generation are fresh, in slots drawn at random (no fixed point; the generation keeps its law).
    """

    variant: str | None = None
    eim_generations: int = MIXING_DEFAULTS.eim_generations
    alpha: float = MIXING_DEFAULTS.alpha
    reeval_age: int | None = MIXING_DEFAULTS.reeval_age
    reeval_prob: float = MIXING_DEFAULTS.reeval_prob
    reeval_count: int = MIXING_DEFAULTS.reeval_count
    min_fresh: int = MIXING_DEFAULTS.min_fresh

    def __post_init__(self):
        """Every setting checked here, with the bounds ``imix run`` checks its keys with (:data:`MIXING_BOUNDS`): a bad
        one is a ValueError or TypeError naming it when the object is made, not at the first ``ask`` (``variant='nope'``)
        or deep inside it (``eim_generations=2.5``); ``reeval_prob=5`` and ``eim_generations=0`` were accepted."""
        if self.variant is not None:
            variant_spec(self.variant)  # ValueError naming the valid variants
        for name, bound in MIXING_BOUNDS.items():
            value = getattr(self, name)
            if value is not None or name != "reeval_age":  # reeval_age None: never re-evaluate by age
                bound.check(name, value)
        if self.alpha and not (self.variant is not None and variant_spec(self.variant).uses_alpha):
            raise ValueError(f"alpha={self.alpha!r} applies to a variant with a minimal refresh rate (sun2009) only, not variant={self.variant!r}")
        if self.weighted and (self.reeval_age is not None or self.reeval_prob or self.reeval_count):
            raise ValueError("variant='weighted' re-evaluates no reused member: reeval_age, reeval_prob and reeval_count apply to mixing variants only")

    @property
    def weighted(self) -> bool:
        """Whether the variant weights the archive into the update (:mod:`imix_cli.core.mixing.weighted_reuse`) instead of mixing."""
        return self.variant is not None and variant_spec(self.variant).weights

    @property
    def depth(self) -> int:
        """Number of generations kept in the archive: those the variant looks back at (:meth:`~imix_cli.core.mixing.Variant.depth`)."""
        if self.variant is None:
            return 0
        return variant_spec(self.variant).depth(self.eim_generations)


@dataclass
class Archive:
    """Earlier generations of one search, newest first, with their members' returns and ages."""

    generations: list = field(default_factory=list)  # Generation objects
    returns: list = field(default_factory=list)  # (popsize,) returns of their members
    ages: list = field(default_factory=list)  # (popsize,) generations since each return was measured
    # (stored, fresh) pairs of re-evaluated reused members, as exponentially forgotten sums:
    # count, sum stored, sum fresh, sum stored^2, sum stored * fresh (module docstring)
    pairs: np.ndarray = field(default_factory=lambda: np.zeros(5))

    def reexpress(self, transform) -> None:
        """Re-express every archived generation through the affine map ``transform`` (``forward``, ``inverse``,
        ``log_det``, ``then``): each member becomes ``transform.forward(theta)`` -- the same policy, the same return --
        and its generation's distribution the pushforward (:class:`~imix_cli.core.distributions.AffinePushforward`),
        so that mixing stays exact. Heights (``log_u``, ratios to the density) and ``mean_weights`` stay; so do the
        returns, ages and pairs. Why and when: :mod:`imix_cli.core.evaluation.policies` ("Observation normalisation")."""
        for g in self.generations:
            g.samples = transform.forward(g.samples).astype(g.samples.dtype, copy=False)
            g.dist = AffinePushforward(g.dist, transform)


#: Weight per generation of the (stored, fresh) pairs of earlier generations: ~20 generations of memory.
PAIR_MEMORY = 0.95
#: Pairs (forgotten weight) needed before stored returns are calibrated.
PAIR_MIN = 5.0


def calibration(pairs: np.ndarray) -> tuple[float, float] | None:
    """``(alpha, beta)`` of fresh ~ alpha + beta * stored from the forgotten sums, beta in [0, 1]; None if too few pairs."""
    n, s, f, ss, sf = (float(v) for v in pairs)
    if n < PAIR_MIN:
        return None
    mean_s, mean_f = s / n, f / n
    var_s = ss / n - mean_s * mean_s
    beta = 1.0 if var_s <= 1e-12 * max(1.0, mean_s * mean_s) else min(1.0, max(0.0, (sf / n - mean_s * mean_f) / var_s))
    return mean_f - beta * mean_s, beta


@dataclass
class Plan:
    """A generation about to be evaluated."""

    generation: Generation
    evaluate: np.ndarray  # indices of the members that need an episode
    age: np.ndarray  # age of every member's return once the generation is evaluated
    probes: np.ndarray | None = None  # points the ES asks to have evaluated besides its members (CMA-ES's TPA)
    reusable: bool = True  # False: drawn from a distribution without a density (never archived)

    @property
    def points(self) -> np.ndarray:
        """What to evaluate, in order: the members of ``evaluate``, then the probes; :func:`finish_generation`
        takes their returns in this order."""
        members = self.generation.samples[self.evaluate]
        return members if self.probes is None else np.vstack([members, self.probes])

    @property
    def reevaluated(self) -> int:
        """Reused members evaluated again (by ``reeval_age`` / ``reeval_prob`` / ``reeval_count``)."""
        return int(np.count_nonzero(self.generation.source[self.evaluate] > 0))


def stored_returns(archive: Archive, g: Generation, rows: np.ndarray) -> list:
    """The stored returns of members ``rows`` of ``g``, each reused from ``archive`` (its ``source`` and ``index``)."""
    return [archive.returns[k - 1][i] for k, i in zip(g.source[rows].tolist(), g.index[rows].tolist())]


class GenerationScheme:
    """How the generations of an ES are drawn (or mixed), evaluated, told and archived: the polymorphic hook
    behind :func:`plan_generation` and :func:`finish_generation`.

    This class is the scheme of an ES whose members are independent draws of its distribution (every ES of
    the paper): the whole generation is mixed and archived. An ES whose members are built otherwise names
    its own scheme in its ``generation_scheme`` attribute -- ARS's mirrored pairs,
    :data:`imix_cli.core.mixing.mirrored.MIRRORED_PAIRS`, mix the anchors and mirror them -- so this module names no ES
    and no ES is special-cased here.
    """

    def plan(self, es, archive: Archive, settings: MixingSettings, rng: np.random.Generator) -> Plan:
        """Draw (or mix) the next generation of ``es`` and decide which members to evaluate."""
        dist, popsize = es.distribution, es.popsize
        reusable = getattr(es, "mixable", True)  # False: no density now (pycma's degenerate factor): no reuse, no archive
        if not reusable:
            archive.generations, archive.returns, archive.ages = [], [], []
        if settings.variant is None or not archive.generations:
            g = Generation(es.ask(rng), np.zeros(popsize, np.int64), np.full(popsize, -1, np.int64), dist)
        else:
            g = mix(
                dist,
                archive.generations,
                popsize,
                rng,
                variant=settings.variant,
                alpha=settings.alpha,
                eim_generations=settings.eim_generations,
                min_fresh=settings.min_fresh,
            )
        evaluate = g.source == 0
        reused = (~evaluate).nonzero()[0]  # np.flatnonzero's, without its Python wrapper (three per generation)
        age = np.zeros(popsize, dtype=np.int64)
        if reused.size:  # member by member: a few reused members cost less than a pass per archived generation
            age[reused] = [archive.ages[k - 1][i] + 1 for k, i in zip(g.source[reused].tolist(), g.index[reused].tolist())]
        if settings.reeval_age is not None or settings.reeval_prob > 0.0 or settings.reeval_count > 0:
            if settings.reeval_age is not None:
                evaluate[reused] |= age[reused] > settings.reeval_age
            if settings.reeval_prob > 0.0:
                evaluate[reused] |= rng.random(reused.size) < settings.reeval_prob
            if settings.reeval_count > 0:
                waiting = reused[~evaluate[reused]]
                evaluate[rng.permutation(waiting)[: settings.reeval_count]] = True
            age[evaluate] = 0  # (without re-evaluations only fresh members are evaluated, and their age is 0 already)
        probes = es.probes(rng)  # never mixed, never archived: not members
        return Plan(g, evaluate.nonzero()[0], age, probes=probes, reusable=reusable)

    def finish(self, es, archive: Archive, settings: MixingSettings, plan: Plan, returns) -> np.ndarray:
        """Assemble the generation's fitness (stored returns + ``returns`` of ``plan.evaluate``), tell
        the ES, archive the generation; return the fitness (one per member). ``returns`` are those of
        ``plan.points``: the members' first, then the probes' (told to the ES apart)."""
        g = plan.generation
        returns = np.asarray(returns, dtype=np.float64).reshape(-1)
        probe = {} if plan.probes is None else {"probe_fitness": returns[plan.evaluate.size :]}
        returns = returns[: plan.evaluate.size]
        fitness = np.empty(g.samples.shape[0])
        reused = g.source > 0
        members = reused.nonzero()[0]
        if members.size:  # reused members keep their stored return
            fitness[members] = stored_returns(archive, g, members)
        again = plan.evaluate[reused[plan.evaluate]]  # reused members evaluated again: (stored, fresh) pairs
        stored_again = fitness[again]
        fitness[plan.evaluate] = returns  # ... unless evaluated again
        told_fitness = fitness
        if settings.depth:  # the (stored, fresh) pairs, older ones forgotten
            new = 0.0
            if again.size:  # (without re-evaluations, as by default: no pair, and no numpy calls to find none)
                ok = np.isfinite(stored_again) & np.isfinite(fitness[again])
                a, b = stored_again[ok], fitness[again][ok]
                new = np.array([a.size, xp.dot(np.ones(a.size), a), xp.dot(np.ones(b.size), b), xp.dot(a, a), xp.dot(a, b)]) if a.size else 0.0
            archive.pairs = PAIR_MEMORY * archive.pairs + new
        if settings.reeval_count > 0:
            line = calibration(archive.pairs)
            kept = reused & np.isfinite(fitness)  # a non-finite stored return stays what it is (ranked last)
            kept[plan.evaluate] = False
            if line is not None and kept.any():
                told_fitness = fitness.copy()
                told_fitness[kept] = line[0] + line[1] * fitness[kept]
        told = getattr(es, "generation", None)
        es.tell(g.samples, told_fitness, **probe)
        if told is not None and es.generation > told:  # the weights of this generation's members in the move ("conditional" mixing)
            g.mean_weights = getattr(es, "mean_weights", None)
        depth = settings.depth if plan.reusable else 0
        if depth:
            archive.generations = [g, *archive.generations][:depth]
            archive.returns = [fitness, *archive.returns][:depth]
            archive.ages = [plan.age, *archive.ages][:depth]
        return fitness

    def archived_rows(self, es) -> int:
        """Rows of every archived generation (what a checkpoint's archive is checked against): the whole population."""
        return es.popsize


class WeightedScheme(GenerationScheme):
    """``variant="weighted"`` (:mod:`imix_cli.core.mixing.weighted_reuse`): fresh members are evaluated, the archived ones
    are pooled with them and weighted into the update; only the fresh members are archived."""

    def plan(self, es, archive: Archive, settings: MixingSettings, rng: np.random.Generator) -> Plan:
        if getattr(es, "generation_scheme", None) is not None:
            raise ValueError(f"eim_variant=weighted cannot weight {es.name}'s generations (built by its own scheme), only independent members")
        g = plan_weighted(es, archive, settings, rng)
        evaluate = np.flatnonzero(g.source == 0)
        return Plan(g, evaluate, np.zeros(g.samples.shape[0], dtype=np.int64), probes=es.probes(rng))

    def finish(self, es, archive: Archive, settings: MixingSettings, plan: Plan, returns) -> np.ndarray:
        g = plan.generation
        returns = np.asarray(returns, dtype=np.float64).reshape(-1)
        fitness = np.empty(g.samples.shape[0])
        fitness[plan.evaluate] = returns[: plan.evaluate.size]
        old = np.flatnonzero(g.source > 0)
        fitness[old] = stored_returns(archive, g, old)
        if isinstance(g, WeightedGeneration):
            es.tell(g.samples, fitness, weights=g.weights)
        else:
            es.tell(g.samples, fitness)
        fresh = g.source == 0
        archive.generations = [archived_part(g), *archive.generations][: settings.depth]
        archive.returns = [fitness[fresh], *archive.returns][: settings.depth]
        archive.ages = [np.zeros(int(np.count_nonzero(fresh)), dtype=np.int64), *archive.ages][: settings.depth]
        return fitness


#: The scheme of an ES of independent members, the default of every ES that names none.
INDEPENDENT = GenerationScheme()
#: The scheme of ``variant="weighted"``, whatever the ES.
WEIGHTED = WeightedScheme()


def scheme_of(es, settings: MixingSettings | None = None) -> GenerationScheme:
    """The generation scheme of ``es`` under ``settings``: :data:`WEIGHTED` for a weighted variant, else the ES's
    ``generation_scheme`` (a class attribute of imix's ES, None for independent members; an adapted library ES
    may set it per instance), else :data:`INDEPENDENT`."""
    if settings is not None and settings.weighted:
        return WEIGHTED
    return getattr(es, "generation_scheme", None) or INDEPENDENT


def plan_generation(es, archive: Archive, settings: MixingSettings, rng: np.random.Generator) -> Plan:
    """Draw (or mix) the next generation of ``es`` and decide which members to evaluate (by its scheme)."""
    return scheme_of(es, settings).plan(es, archive, settings, rng)


def finish_generation(es, archive: Archive, settings: MixingSettings, plan: Plan, returns) -> np.ndarray:
    """Tell ``es`` its generation's fitness (stored returns + ``returns`` of ``plan.points``) and archive the
    generation, by its scheme; return the fitness (one per member)."""
    return scheme_of(es, settings).finish(es, archive, settings, plan, returns)
