"""Importance mixing for mirrored pairs (ARS): reuse members, and complete each into a pair around the new mean.

Why whole pairs cannot be reused
--------------------------------
A mirrored pair of N(m, nu^2 I) is (m + nu delta, m - nu delta) with delta ~ N(0, I): a point of
R^2d whose two halves sum to 2m. The law of the pair lives on the d-dimensional plane
{(a, b): a + b = 2m}. Once the mean moves to m' != m, the new pairs live on another, parallel
plane {a + b = 2m'}: the two laws are mutually singular -- an old pair has density zero under the
new pair law, and no acceptance rule (rule 1's min(1, p_new/p_old) is 0 there) can reuse it.
Reusing pairs whole is exact only if the mean did not move; with the directions' returns,
ARS moves it every generation.

What is reused instead (exact)
------------------------------
A pair is its *anchor* theta+ = m + nu delta, and the mirror 2m - theta+ is a function of the
anchor and the mean. The anchors of a generation are N independent draws from N(m, nu^2 I)
-- an ordinary ES generation, which :func:`imix_cli.core.mixing.mix` can build from earlier ones.
So a generation is built as:

1. anchors: ``mix(N(m', nu^2 I), archive of earlier anchors, N)`` -- any exact variant
   ("sun2009", "exact"): the anchors are N independent draws from N(m', nu^2 I), some of them
   members of earlier generations whose returns are known;
2. mirrors: 2m' - theta for every anchor, always evaluated (a reused anchor's old mirror was
   taken around the old mean, and 2m - theta = 2m' - theta only if m = m').

Then delta_k = (theta_k - m') / nu are N independent N(0, I) directions, and (theta_k, 2m' - theta_k)
= (m' + nu delta_k, m' - nu delta_k): exactly ARS's N pairs around m'. Each reused anchor saves
one episode of two, so mixing saves at most half of the episodes (2x fewer).

Only anchors enter the archive (the new anchor generation, with the heights EIM keeps on it):
an old pair's two halves are not independent draws (they sum to 2m), so archiving both would
break the independence EIM's multi-generation step relies on; and the mirrors are the same
draws seen through the mean, adding nothing exact to reuse.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imix_cli.core.mixing import MIXING_DEFAULTS, Generation, mix
from imix_cli.core.mixing.generation import Archive, GenerationScheme, MixingSettings, Plan


@dataclass
class MirroredPlan(Plan):
    """A generation of N pairs about to be evaluated: ``generation`` holds the 2N members
    ``[anchors; mirrors]`` (a mirror's source is 0: always fresh), ``anchors`` the N anchors as
    :func:`~imix_cli.core.mixing.mix` built them (what the archive keeps)."""

    anchors: Generation | None = None


def mix_pairs(dist, archive: list, directions: int, rng: np.random.Generator, variant: str | None, alpha: float = MIXING_DEFAULTS.alpha,
              eim_generations: int = MIXING_DEFAULTS.eim_generations):  # fmt: skip
    """N mirrored pairs of ``dist`` (mean m'), their anchors mixed from ``archive`` (module docstring).

    Returns ``(anchors, members)``: the anchors' :class:`~imix_cli.core.mixing.Generation` (N rows) and
    the 2N members ``[anchors; 2m' - anchors]``. ``variant`` None (or an empty archive): all fresh. No minimal
    refresh (``min_fresh=0``): every mirror is fresh, so no generation is reused whole (:mod:`imix_cli.core.mixing`).
    """
    if variant is None or not archive:
        n = directions
        anchors = Generation(dist.sample(n, rng), np.zeros(n, np.int64), np.full(n, -1, np.int64), dist)
    else:
        anchors = mix(dist, archive, directions, rng, variant=variant, alpha=alpha, eim_generations=eim_generations, min_fresh=0)
    return anchors, np.concatenate([anchors.samples, mirror(anchors.samples, dist.mean)])


def mirror(members: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """The mirror images 2m - theta of ``members`` through ``mean``: the other half of each pair."""
    return 2.0 * np.asarray(mean)[None, :] - members


class MirroredPairs(GenerationScheme):
    """The generation scheme of an ES of N mirrored pairs ``[anchors; mirrors]`` (``es.directions`` = N):
    the anchors are mixed (module docstring), the mirrors always fresh, and only the anchors archived."""

    def plan(self, es, archive: Archive, settings: MixingSettings, rng: np.random.Generator) -> MirroredPlan:
        """N pairs: the anchors mixed from the archived anchors, the mirrors fresh; which members to evaluate."""
        dist, n = es.distribution, es.directions
        anchors, members = mix_pairs(dist, archive.generations, n, rng, settings.variant, settings.alpha, settings.eim_generations)
        source = np.concatenate([anchors.source, np.zeros(n, np.int64)])
        index = np.concatenate([anchors.index, np.full(n, -1, np.int64)])
        generation = Generation(members, source, index, dist, anchors.trials)
        age = np.zeros(2 * n, dtype=np.int64)
        for k, ages in enumerate(archive.ages, start=1):
            from_k = source == k
            age[from_k] = ages[index[from_k]] + 1
        evaluate = source == 0
        reused = np.flatnonzero(~evaluate)
        if settings.reeval_age is not None:
            evaluate[reused] |= age[reused] > settings.reeval_age
        if settings.reeval_prob > 0.0:
            evaluate[reused] |= rng.random(reused.size) < settings.reeval_prob
        age[evaluate] = 0
        return MirroredPlan(generation, np.flatnonzero(evaluate), age, anchors=anchors)

    def finish(self, es, archive: Archive, settings: MixingSettings, plan: MirroredPlan, returns) -> np.ndarray:
        """Stored + new returns, tell,
        archive the anchors (and their returns and ages); return the 2N members' fitness."""
        g, n = plan.generation, plan.anchors.samples.shape[0]
        fitness = np.empty(g.samples.shape[0])
        for k, stored in enumerate(archive.returns, start=1):
            from_k = g.source == k
            fitness[from_k] = stored[g.index[from_k]]
        fitness[plan.evaluate] = returns
        es.tell(g.samples, fitness)
        depth = settings.depth
        if depth:
            archive.generations = [plan.anchors, *archive.generations][:depth]
            archive.returns = [fitness[:n].copy(), *archive.returns][:depth]
            archive.ages = [plan.age[:n].copy(), *archive.ages][:depth]
        return fitness

    def archived_rows(self, es) -> int:
        """Rows of every archived generation: the N anchors."""
        return es.directions


#: The scheme of ARS (and of an adapted library ES of antithetic pairs): ``generation_scheme = MIRRORED_PAIRS``.
MIRRORED_PAIRS = MirroredPairs()
