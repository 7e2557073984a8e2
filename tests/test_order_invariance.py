"""No ES may care about the order of the population it is told.

With importance mixing a generation lists its reused members first; on CartPole ~40 of 50
members tie at the maximum return. When ties were broken by position, the fresh rule-2 draws
(which sit where the new density exceeds the old) became the elites and pushed the search
distribution outward (issue 11: CMA-ES + EIM ended at 181.8 instead of 196, sigma 3x too
large). Tied members now share ranks and recombination weights, so telling a permutation of
a generation gives the same update, to round-off -- for every ES, with and without ties.
"""

import numpy as np
import pytest

from imix_cli.algorithms import ALGORITHMS, make_es
from imix_cli.algorithms.base import centered_ranks, rank_weights


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


def test_tied_values_share_their_ranks():
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
