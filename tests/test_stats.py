"""imix_cli.core.stats: IQM, stratified bootstrap CIs, probability of improvement, performance profiles.

Known values are computed by hand in the comments; where rliable's ``metrics`` module imports
(it needs only scipy; its bootstrap needs arch, which does not import with pandas 3), the same
data are checked against it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from imix_cli.core.stats import (
    iqm,
    iqm_ci,
    mean_bootstrap_ci,
    mean_ci,
    performance_profile,
    performance_profile_ci,
    probability_of_improvement,
    probability_of_improvement_ci,
)


def test_iqm_hand_values():
    # n=8: cut 2 at each end -> mean(3, 4, 5, 6) = 4.5
    assert iqm(np.arange(1.0, 9.0)) == pytest.approx(4.5)
    # n=5: cut int(1.25) = 1 at each end -> mean(2, 3, 100) ; the 1000 outlier is gone
    assert iqm([1.0, 2.0, 3.0, 100.0, 1000.0]) == pytest.approx(35.0)
    # n=12, skewed: cut 3 at each end -> mean(0, 1, 2, 3, 4, 5) = 2.5 (a 20 % trim would give 14.375)
    assert iqm([0, 0, 0, 0, 1, 2, 3, 4, 5, 100, 200, 300]) == pytest.approx(2.5)
    # a seed that never reaches a threshold (+inf) is trimmed away when fewer than 25 % do
    assert iqm([10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, math.inf]) == pytest.approx(45.0)


def test_probability_of_improvement_hand_values():
    # pairs (x, y): (3,1)=1, (3,3)=0.5, (4,1)=1, (4,3)=1 -> 3.5 / 4
    assert probability_of_improvement([3.0, 4.0], [1.0, 3.0]) == pytest.approx(0.875)
    # two strata averaged: 0.875 and P([0] > [5]) = 0 -> 0.4375
    assert probability_of_improvement([[3.0, 4.0], [0.0]], [[1.0, 3.0], [5.0]]) == pytest.approx(0.4375)
    assert probability_of_improvement([1.0, 2.0], [1.0, 2.0]) == pytest.approx(0.5)
    # "fewer episodes" as -episodes: a seed that never reaches (inf episodes) loses to every finite one
    assert probability_of_improvement([-100.0, -200.0], [-150.0, -math.inf]) == pytest.approx(0.75)


def test_performance_profile_hand_values():
    # fraction strictly above tau of [1, 2, 3, 4]
    assert performance_profile([1.0, 2.0, 3.0, 4.0], [0.0, 2.0, 2.5, 4.0]) == pytest.approx([1.0, 0.5, 0.5, 0.0])


def test_stratified_bootstrap_keeps_each_stratum_size():
    # Strata [0,0,0] and [1]: every stratified resample has three 0s and one 1, so the mean is
    # always 0.25 and the CI collapses onto it. A plain bootstrap over the 4 pooled runs would give
    # a CI of about [0, 0.75].
    point, lo, hi = mean_bootstrap_ci([[0.0, 0.0, 0.0], [1.0]], reps=500, seed=1)
    assert (point, lo, hi) == (0.25, 0.25, 0.25)


def test_bootstrap_ci_is_deterministic_and_covers():
    rng = np.random.default_rng(0)
    data = rng.normal(10.0, 2.0, size=(25, 2))
    a = iqm_ci(data, reps=1000, seed=3)
    assert a == iqm_ci(data, reps=1000, seed=3)
    point, lo, hi = a
    assert lo < point < hi
    # 50 runs of sd 2: the IQM's 95 % CI half-width is about 1.1 * 2 / sqrt(50) * 1.96 ~ 0.6; loose bounds
    assert 0.2 < (hi - lo) / 2 < 1.2


def test_bootstrap_ci_coverage():
    """The percentile CI of the mean covers the true mean in about 95 % of 400 repeated experiments.

    With 400 trials the binomial sd of the coverage is 1.1 %; a bootstrap with n = 25 runs is
    known to under-cover slightly (~93-94 %), so the accepted band is [0.90, 0.98].
    """
    rng = np.random.default_rng(42)
    hits = 0
    for _ in range(400):
        x = rng.normal(0.0, 1.0, size=25)
        _, lo, hi = mean_bootstrap_ci(x, reps=400, seed=int(rng.integers(1 << 30)))
        hits += lo <= 0.0 <= hi
    assert 0.90 <= hits / 400 <= 0.98


def test_poi_ci_brackets_point():
    x = np.arange(10.0)
    y = np.arange(10.0) - 3.0
    point, lo, hi = probability_of_improvement_ci(x, y, reps=1000, seed=0)
    # hand: x_i = i, y_j = j - 3; x_i > y_j iff j - i <= 2. Pairs with j - i >= 3: 7+6+...+1 = 28,
    # of which the 7 with j - i = 3 are ties -> (100 - 28) wins + 0.5 * 7 = 75.5 of 100 pairs
    assert point == pytest.approx(0.755)
    assert lo < point < hi <= 1.0


def test_performance_profile_ci_band():
    scores = np.linspace(0.0, 1.0, 21)
    point, lo, hi = performance_profile_ci(scores, [0.5], reps=500, seed=0)
    assert point[0] == pytest.approx(10 / 21)
    assert lo[0] < point[0] < hi[0]


def test_mean_ci_unchanged():
    mean, half, n = mean_ci([1.0, 2.0, 3.0, 4.0], level=0.95)
    # t_{0.975, 3} = 3.182446 * sd 1.290994 / 2
    assert (mean, n) == (2.5, 4) and half == pytest.approx(3.182446 * 1.290994 / 2, rel=1e-5)


@pytest.mark.rliable
def test_against_rliable_metrics():
    """Point estimates equal rliable 1.2.0's on the same data (skipped where rliable is not importable)."""
    from rliable import metrics

    rng = np.random.default_rng(7)
    x = rng.normal(size=(12, 3))
    y = rng.normal(0.3, size=(12, 3))
    y[0, 0] = x[0, 0]  # a tie
    assert iqm(x) == pytest.approx(metrics.aggregate_iqm(x))
    assert probability_of_improvement(x, y) == pytest.approx(metrics.probability_of_improvement(x, y))
