"""No ES may care about the order of the population it is told.

With importance mixing a generation lists its reused members first; on CartPole ~40 of 50
members tie at the maximum return. When ties were broken by position, the fresh rule-2 draws
(which sit where the new density exceeds the old) became the elites and pushed the search
distribution outward (measured: CMA-ES + EIM ended at 181.8 instead of 196, sigma 3x too
large). Tied members now share ranks and recombination weights, so telling a permutation of
a generation gives the same update, to round-off -- for every ES, with and without ties.
"""

import numpy as np
import pytest

from imix_cli.core.algorithms import ALGORITHMS, make_es
from imix_cli.core.algorithms.base import centered_ranks, member_keys, rank_weights


def population_with_ties(rng, dim=8, popsize=20):
    samples = rng.standard_normal((popsize, dim)) * 0.3
    fitness = rng.integers(0, 4, size=popsize).astype(float)  # 4 levels: large tied groups
    fitness[: popsize // 2] = 3.0  # and a big tie at the top, as on CartPole
    return samples, fitness


def told(algo, samples, fitness, generations=3):
    es = make_es(algo, samples.shape[1], popsize=samples.shape[0], sigma=0.3, weight_decay=0.0)
    for _ in range(generations):  # repeated tells: state (paths, Adam moments) must agree too
        es.tell(samples, fitness)
    d = es.distribution
    return d.mean, getattr(d, "cov", None) if hasattr(d, "cov") else d.std


@pytest.mark.parametrize("algo", sorted(ALGORITHMS))
def test_every_es_ignores_the_order_of_its_population(algo):
    rng = np.random.default_rng(0)
    for trial in range(5):
        samples, fitness = population_with_ties(rng)
        mean, spread = told(algo, samples, fitness)
        perm = rng.permutation(samples.shape[0])
        mean_p, spread_p = told(algo, samples[perm], fitness[perm])
        np.testing.assert_allclose(mean_p, mean, rtol=1e-10, atol=1e-12, err_msg=f"{algo} trial {trial}: mean")
        np.testing.assert_allclose(spread_p, spread, rtol=1e-10, atol=1e-12, err_msg=f"{algo} trial {trial}: spread")


def test_tied_values_are_ranked_by_their_keys_else_share_their_ranks():
    np.testing.assert_allclose(centered_ranks([1.0, 1.0, 0.0], tie_break=np.array([7, 3, 1])), [0.5, 0.0, -0.5])
    x = np.random.default_rng(0).standard_normal((6, 4))
    perm = np.array([3, 5, 0, 1, 4, 2])
    np.testing.assert_array_equal(member_keys(x[perm]), member_keys(x)[perm])  # a key belongs to its member
    assert np.unique(member_keys(x)).size == 6
    np.testing.assert_allclose(centered_ranks([1.0, 2.0, 2.0, 3.0]), [-0.5, 0.0, 0.0, 0.5])
    np.testing.assert_allclose(centered_ranks([5.0, 5.0, 5.0]), [0.0, 0.0, 0.0])
    np.testing.assert_allclose(centered_ranks([-np.inf, 0.0, -np.inf]), [-0.25, 0.5, -0.25])


def test_rank_weights_share_the_weights_of_the_positions_a_tie_spans():
    # best (5, 5) share positions 0-1, then 1, then 0
    np.testing.assert_allclose(rank_weights([1.0, 5.0, 5.0, 0.0], [0.5, 0.3, 0.2, 0.0]), [0.2, 0.4, 0.4, 0.0])
    # a tie straddling the elite boundary: 3 tied for positions 1-3, two of them elite
    np.testing.assert_allclose(rank_weights([9.0, 2.0, 2.0, 2.0, 1.0], [0.5, 0.25, 0.25, 0.0, 0.0]), [0.5, 1 / 6, 1 / 6, 1 / 6, 0.0])
    w = np.array([0.4, 0.3, 0.2, 0.1])
    np.testing.assert_allclose(rank_weights([4.0, 1.0, 3.0, 2.0], w), [0.4, 0.1, 0.3, 0.2])  # no ties: plain ranking


@pytest.mark.parametrize("algo", ["cem", "cmaes"])
def test_ties_are_not_decided_by_the_weight_decay_penalty(algo):
    """With every return tied, the estool penalty (a tiny term added to the ranks) must not
    decide who is elite: selection ES would then keep the members nearest the origin and pull
    the mean in (CMA-ES on CartPole fell to a mean return of 60). Ties are broken at random
    instead, so under constant fitness the mean wanders and its norm does not collapse.
    Measured with penalty-ordered ties: |mean| falls below 0.3 x its start within 40
    generations; with random ties it stays near its start (> 0.7)."""
    rng = np.random.default_rng(1)
    dim = 10
    es = make_es(algo, dim, popsize=20, sigma=0.3, weight_decay=0.05, weight_decay_form="estool", mean=np.ones(dim))
    for _ in range(40):
        x = es.ask(rng)
        es.tell(x, np.zeros(len(x)))
    assert np.linalg.norm(es.mean) > 0.7 * np.sqrt(dim), np.linalg.norm(es.mean)
