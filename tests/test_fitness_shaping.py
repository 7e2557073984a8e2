"""Fitness shaping (paper section 4.1): centred ranks and the two weight-decay forms, on hand-computed values.

Every ES ranks members by the utilities of :meth:`EvolutionStrategy.utilities`, so an error
here (a flipped penalty sign, a sum where a mean belongs) changes every run while the ES
still optimises; only exact values catch it. The examples are small enough to check by hand,
and chosen so that the penalty changes which member ranks best.
"""

from __future__ import annotations

import numpy as np
import pytest

from imix_cli.core.algorithms import CEM, make_es
from imix_cli.core.algorithms.base import centered_ranks
from imix_cli.core.registry import ES_NAMES

# --------------------------------------------------------------------------- centred ranks
# rank r in 0..n-1 (worst 0) maps to r / (n - 1) - 0.5; a single member gets 0.


@pytest.mark.parametrize(
    "values, expected",
    [
        ([5.0], [0.0]),
        ([3.0, -1.0], [0.5, -0.5]),
        # sorted: -2 (rank 0), 0 (1), 0.3 (2), 1 (3), 7 (4)
        ([0.3, -2.0, 7.0, 1.0, 0.0], [0.0, -0.5, 0.5, 0.25, -0.25]),
    ],
    ids=["n=1", "n=2", "n=5"],
)
def test_centered_ranks_hand_values(values, expected):
    np.testing.assert_array_equal(centered_ranks(np.array(values)), expected)


@pytest.mark.parametrize(
    "values, expected",
    [
        ([1.0, 2.0, 2.0, 3.0], [-0.5, 0.0, 0.0, 0.5]),  # ranks 0, 1.5, 1.5, 3 over n - 1 = 3
        ([5.0, 5.0], [0.0, 0.0]),
        ([1.0, 1.0, 1.0, 2.0, 0.0], [0.0, 0.0, 0.0, 0.5, -0.5]),  # the three 1s share rank (1 + 2 + 3) / 3 = 2
    ],
)
def test_centered_ranks_ties_share_their_average_rank(values, expected):
    np.testing.assert_allclose(centered_ranks(np.array(values)), expected, rtol=0, atol=1e-15)


# --------------------------------------------------------------------------- weight decay
# Four members in d = 2 with w = 0.1:
#   member       theta    raw fitness   ||theta||^2   mean(theta^2)
#   a            (0, 0)   1.0           0             0
#   b            (3, 0)   2.0           9             4.5
#   c            (1, 1)   1.5           2             1
#   d            (0, 2)   0.0           4             2
# Raw fitness ranks d < a < c < b: b is best. With either penalty c overtakes b.
SAMPLES = np.array([[0.0, 0.0], [3.0, 0.0], [1.0, 1.0], [0.0, 2.0]])
FITNESS = np.array([1.0, 2.0, 1.5, 0.0])
W = 0.1
THIRD = 1.0 / 3.0

# paper: penalised fitness a 1.0, b 2 - 0.9 = 1.1, c 1.5 - 0.2 = 1.3, d 0 - 0.4 = -0.4
# -> ranks d 0, a 1, b 2, c 3 -> r / 3 - 0.5
PAPER_UTILITIES = np.array([THIRD - 0.5, 2 * THIRD - 0.5, 0.5, -0.5])
# estool: centred ranks of the raw fitness (a -1/6, b 1/2, c 1/6, d -1/2) minus 0.1 * mean(theta^2)
ESTOOL_UTILITIES = np.array([THIRD - 0.5, 0.5 - 0.45, 2 * THIRD - 0.5 - 0.1, -0.5 - 0.2])


@pytest.mark.parametrize("name", ES_NAMES)
@pytest.mark.parametrize("form, expected", [("paper", PAPER_UTILITIES), ("estool", ESTOOL_UTILITIES)])
def test_weight_decay_utilities_hand_values(name, form, expected):
    es = make_es(name, 2, popsize=4, weight_decay=W, weight_decay_form=form)
    utilities = es.utilities(SAMPLES, FITNESS)
    np.testing.assert_allclose(utilities, expected, rtol=0, atol=1e-15)
    assert np.argmax(utilities) == 2 and np.argmax(FITNESS) == 1  # the penalty changed the best member


@pytest.mark.parametrize("form", ["paper", "estool"])
def test_no_weight_decay_leaves_the_centred_ranks_of_the_fitness(form):
    es = make_es("openes", 2, popsize=4, weight_decay=0.0, weight_decay_form=form)
    np.testing.assert_array_equal(es.utilities(SAMPLES, FITNESS), [THIRD - 0.5, 0.5, 2 * THIRD - 0.5, -0.5])


def test_nonfinite_fitness_ranks_last_and_is_counted():
    es = make_es("openes", 2, popsize=4, weight_decay=W, weight_decay_form="paper")
    fitness = FITNESS.copy()
    fitness[2] = np.inf  # c, best after the penalty on finite fitness, now ranks last
    # penalised: a 1.0, b 1.1, c -inf, d -0.4 -> ranks c 0, d 1, a 2, b 3
    np.testing.assert_allclose(es.utilities(SAMPLES, fitness), [2 * THIRD - 0.5, 0.5, -0.5, THIRD - 0.5], rtol=0, atol=1e-15)
    assert es.nonfinite_fitness_count == 1


@pytest.mark.parametrize("form", ["paper", "estool"])
def test_tell_moves_towards_the_member_the_penalty_favours(form):
    """Through ``tell``: CEM with a single elite (K = 1) moves its mean onto the best-utility member.

    Raw fitness would pick b = (3, 0); both penalties pick c = (1, 1) (tables above).
    """
    es = CEM(2, popsize=4, weight_decay=W, weight_decay_form=form, elite_fraction=0.25)
    es.tell(SAMPLES, FITNESS)
    np.testing.assert_array_equal(es.mean, SAMPLES[2])
