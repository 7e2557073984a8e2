"""Importance-weighted reuse (``eim_variant=weighted``): archived members weighted into the update, not mixed.

Why a second way to reuse. Importance mixing hands the ES a generation distributed exactly as its search
distribution, so nothing in the ES changes; its price is that a member is reused only where the old and the
new distribution overlap, and the fraction it can reuse is bounded by that overlap (one minus their total
variation distance: rule 1 accepts an old member with probability min(1, p_new/p_old)). Where ES take large
steps in many dimensions (MuJoCo with 64x64 policies) the overlap is small. Importance sampling instead keeps
*every* archived member and weights it into the update (Shirakawa, Akimoto, Ouchi & Ohara, "Sample reuse in
the covariance matrix adaptation evolution strategy based on importance sampling", GECCO 2015; the IGO view:
the update is an expectation under the current distribution, estimated from any sample with weights
p_new/q). This module measures, as an option, whether that reuses more.

What it assumes. The ES's update must be a weighted sum over its members of their utilities times a function
of the member: SNES and OpenES move along ``sum_k u_k s_k`` (their ``weights_utilities`` attribute says so);
CEM, CMA-ES (selection, recombination, evolution paths) and ARS (mirrored pairs) do not take weights and are
refused. Weighting then changes the estimate, never the update rule.

How. A generation draws ``n_fresh`` members fresh and tells the ES the *pool*: those, plus the fresh members of
the last K archived generations (``eim_generations``) with their stored returns. Each pooled member x gets the
self-normalised weight of the balance heuristic (Veach & Guibas 1995): w(x) proportional to p_new(x) / q(x)
with q = sum_g n_g p_g / sum_g n_g, the mixture of every distribution the pool was drawn from (the current
one for the fresh members). The mixture keeps every weight below N / n_fresh, so no single old member can
dominate. The utilities are centred ranks under the weights: a member's utility is the weighted fraction of
the *other* members that it beats, minus 1/2 -- with equal weights exactly :func:`centered_ranks`' r/(n-1) -
1/2 (ties ordered by the ES's salted member keys, as there) -- and the ES is told ``popsize * w_k * u_k``, so
that a pool of equal weights moves it as a plain generation of that size would.

How many fresh. Before drawing, the archived members' own effective sample size under the current
distribution, ESS = (sum w)^2 / sum w^2 with w = p_new / q_archive, says how many fresh draws they stand in
for: ``n_fresh = popsize - floor(ESS)``, at least ``max(min_fresh, 2)``. A CSV's ``reused`` column holds
``popsize - n_fresh``, the episodes the archive saved (so reuse rates read as with mixing), which is that
ESS, floored, unless ``min_fresh`` bound; :attr:`WeightedGeneration.ess` the whole pool's ESS.

What it costs, before measuring: for a move of the mean by delta standard deviations (equal covariances)
mixing reuses a fraction 2 Phi(-delta/2) of a generation, importance weights give an ESS fraction
1 / (1 + chi^2) = exp(-delta^2). At delta = 0.66 (SNES on HalfCheetah, linear policy: 74 % overlap) that is
0.65 against 0.74; at delta = 1.87 (64x64 MLP: 35 %) 0.03 against 0.35. Pooling K generations adds the older
ones' ESS, which falls faster still. Weighting therefore reuses less than mixing exactly where overlap is
small; docs/research/reuse_modes.md measures it and its bias (self-normalised weights are consistent, not
unbiased: O(1/ESS)), and the stored returns it tells again carry the same echo as mixing's
(docs/research/bias.md, "Noisy returns told again").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imix_cli.core import numerics as xp
from imix_cli.core.mixing import Generation


def log_mixture(dists, sizes, x: np.ndarray) -> np.ndarray:
    """log q(x), q = sum_g n_g p_g / sum_g n_g: the balance heuristic's proposal of a pool drawn from ``dists``."""
    sizes = np.asarray(sizes, dtype=np.float64)
    logs = [np.asarray(d.log_prob(x), dtype=np.float64) + xp.log(float(n)) for d, n in zip(dists, sizes) if n > 0]
    top = np.max(logs, axis=0)
    total = np.zeros_like(top)
    for row in logs:  # one fixed order of the sum (numerics' exp and log: the same bits on every CPU)
        total += xp.exp(row - top)
    return top + xp.log(total) - xp.log(float(sizes.sum()))


def normalised_weights(log_w: np.ndarray) -> np.ndarray:
    """Self-normalised weights (summing to 1) from log-weights."""
    w = xp.exp(np.ascontiguousarray(log_w - np.max(log_w), dtype=np.float64))
    return w / xp.dot(np.ones(w.shape[0]), w)


def effective_size(weights: np.ndarray) -> float:
    """Kish's effective sample size (sum w)^2 / sum w^2."""
    return float(xp.dot(np.ones(weights.shape[0]), weights) ** 2 / xp.dot(weights, weights))


def weighted_centered_ranks(values: np.ndarray, weights: np.ndarray, tie_break: np.ndarray) -> np.ndarray:
    """Centred ranks under ``weights``: the weighted fraction of the other members that each one beats, minus 1/2.

    Ties are ordered by ``tie_break`` (as :func:`~imix_cli.core.algorithms.base.centered_ranks`); with equal
    weights the result is ``r / (n - 1) - 0.5``, the plain centred rank r of n.
    """
    order = np.lexsort((tie_break, values))
    w = np.asarray(weights, dtype=np.float64)
    below = np.empty_like(w)
    below[order] = np.cumsum(w[order]) - w[order]  # weight of the members ranked below each
    others = w.sum() - w
    return np.where(others > 0, below / np.where(others > 0, others, 1.0), 0.5) - 0.5


@dataclass
class WeightedGeneration(Generation):
    """A pooled generation: ``samples`` the fresh members first, then every archived member told again.

    ``weights``: each pooled member's self-normalised weight (summing to 1); ``fresh_count``: the members
    drawn now; ``saved``: ``popsize - fresh_count`` (what :attr:`reused` reports); ``ess``: the pool's
    effective sample size.
    """

    weights: np.ndarray | None = None
    fresh_count: int = 0
    saved: int = 0
    ess: float = float("nan")
    saved_from_previous: int = 0

    @property
    def reused(self) -> int:
        return self.saved

    @property
    def reused_from_previous(self) -> int:
        return self.saved_from_previous

    @property
    def reused_from_older(self) -> int:
        return self.saved - self.saved_from_previous


def plan_weighted(es, archive, settings, rng: np.random.Generator) -> WeightedGeneration | Generation:
    """The pool of a generation (module docstring): how many fresh, their draws, the archived members and
    every member's weight. An empty archive gives a plain generation of ``popsize`` fresh draws."""
    if not getattr(es, "weights_utilities", False):
        name = getattr(es, "name", type(es).__name__)
        raise ValueError(f"eim_variant=weighted needs an ES whose update is a weighted sum over its members (snes, openes), not {name}")
    dist, popsize = es.distribution, es.popsize
    entries = archive.generations[: settings.depth]
    if not entries:
        return Generation(es.ask(rng), np.zeros(popsize, np.int64), np.full(popsize, -1, np.int64), dist)
    old_x = np.vstack([g.samples for g in entries])
    sizes = [g.samples.shape[0] for g in entries]
    dists = [g.dist for g in entries]
    log_p_new = dist.log_prob(old_x)
    archive_w = normalised_weights(log_p_new - log_mixture(dists, sizes, old_x))
    ess_archive = effective_size(archive_w)
    floor = max(settings.min_fresh, 2)
    n_fresh = int(min(popsize, max(floor, popsize - int(np.floor(ess_archive)))))
    fresh = dist.sample(n_fresh, rng)
    x = np.vstack([fresh, old_x])
    log_q = log_mixture([dist, *dists], [n_fresh, *sizes], x)
    weights = normalised_weights(dist.log_prob(x) - log_q)
    source = np.concatenate([np.zeros(n_fresh, np.int64), *[np.full(n, k, np.int64) for k, n in enumerate(sizes, start=1)]])
    index = np.concatenate([np.full(n_fresh, -1, np.int64), *[np.arange(n, dtype=np.int64) for n in sizes]])
    saved = popsize - n_fresh
    # the saving split by where the archive's effective members come from (the CSV's reused_im / reused_eim)
    previous = effective_size(archive_w[: sizes[0]]) if archive_w[: sizes[0]].sum() > 0 else 0.0
    share = min(1.0, previous / ess_archive) if ess_archive > 0 else 0.0
    return WeightedGeneration(x, source, index, dist, weights=weights, fresh_count=n_fresh, saved=saved,
                              ess=effective_size(weights), saved_from_previous=int(round(saved * share)))  # fmt: skip


def archived_part(generation: Generation) -> Generation:
    """What a weighted search archives of a generation: its fresh members only, with the distribution they
    were drawn from (stored members are in the archive already)."""
    fresh = generation.source == 0
    n = int(np.count_nonzero(fresh))
    return Generation(generation.samples[fresh], np.zeros(n, np.int64), np.full(n, -1, np.int64), generation.dist)
