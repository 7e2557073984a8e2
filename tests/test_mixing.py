"""Importance mixing is correct: mixed generations are distributed as the new Gaussian.

Statistical tests use fixed seeds; each states its tolerance. KS tests pool the members of
many independent mixing steps and require p > 1e-3 (with fixed seeds this is deterministic;
a real bias of the size these tests resolve drives p far below that).
"""

from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from imix_cli.core.mixing import VARIANTS, DiagonalGaussian, FullGaussian, Generation, mix

KS_P_MIN = 1e-3


def pooled_1d(variant, old, new, popsize, repeats, rng, older=None):
    pooled, reused = [], 0
    for _ in range(repeats):
        archive = [(old, old.sample(popsize, rng))]
        if older is not None:
            archive.append((older, older.sample(popsize, rng)))
        g = mix(new, archive, popsize, rng, variant=variant)
        pooled.append(g.samples[:, 0])
        reused += g.reused
    return np.concatenate(pooled), reused / (popsize * repeats)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("shift,scale", [(0.2, 1.0), (1.0, 0.7), (0.0, 1.3), (2.5, 1.0)])
def test_1d_generations_follow_new_distribution(variant, shift, scale):
    rng = np.random.default_rng(1234)
    old, new = DiagonalGaussian([0.0], [1.0]), DiagonalGaussian([shift], [scale])
    older = DiagonalGaussian([-0.5], [1.2])
    x, reuse = pooled_1d(variant, old, new, popsize=20, repeats=1500, rng=rng, older=older)
    assert stats.kstest(x, "norm", args=(shift, scale)).pvalue > KS_P_MIN
    assert 0.0 < reuse <= 1.0


@pytest.mark.slow
@pytest.mark.parametrize("variant", VARIANTS)
def test_full_covariance_3d_mahalanobis_is_chi2(variant):
    """Squared Mahalanobis distances to the new distribution follow chi^2(3) iff the members are N(mu, C)."""
    rng = np.random.default_rng(99)
    a = rng.standard_normal((3, 3))
    old = FullGaussian(np.zeros(3), np.eye(3) + 0.3 * (a @ a.T))
    b = rng.standard_normal((3, 3))
    new = FullGaussian(np.array([0.4, -0.2, 0.3]), 0.8 * np.eye(3) + 0.2 * (b @ b.T))
    older = FullGaussian(np.array([-0.3, 0.0, 0.1]), 1.2 * np.eye(3))
    pooled, reused = [], 0
    for _ in range(1200):
        archive = [(old, old.sample(25, rng)), (older, older.sample(25, rng))]
        g = mix(new, archive, 25, rng, variant=variant)
        pooled.append(g.samples)
        reused += g.reused
    x = np.concatenate(pooled)
    d2 = -2.0 * (new.log_prob(x) - new.log_norm)  # squared Mahalanobis distance
    assert stats.kstest(d2, "chi2", args=(3,)).pvalue > KS_P_MIN
    # and each coordinate's marginal
    for i in range(3):
        assert stats.kstest(x[:, i], "norm", args=(new.mean[i], np.sqrt(new.cov[i, i]))).pvalue > KS_P_MIN
    assert reused > 0


def monte_carlo_overlap(old, new, rng, n=400_000):
    """lambda = integral of min(p_old, p_new) = E_new[min(1, p_old/p_new)]."""
    x = new.sample(n, rng)
    return float(np.mean(np.exp(np.minimum(0.0, old.log_prob(x) - new.log_prob(x)))))


@pytest.mark.parametrize("shift,scale", [(0.3, 1.0), (0.0, 0.8), (1.0, 1.2)])
def test_sun2009_reuse_rate_equals_overlap(shift, scale):
    """With alpha = 0, E[reuse] = lambda exactly; tolerance +-0.01 (the estimate's s.d. is ~0.0015)."""
    rng = np.random.default_rng(7)
    old, new = DiagonalGaussian([0.0, 0.0], [1.0, 1.0]), DiagonalGaussian([shift, 0.0], [scale, 1.0])
    overlap = monte_carlo_overlap(old, new, rng)
    reused = sum(mix(new, [(old, old.sample(50, rng))], 50, rng, variant="sun2009", min_fresh=0).reused for _ in range(2000))
    assert abs(reused / (50 * 2000) - overlap) < 0.01


def test_sun2009_alpha_reuse_rate():
    """Rule 1 keeps min(p_old, (1 - alpha) p_new), so E[reuse] = E_new[min(p_old/p_new, 1 - alpha)]; +-0.01."""
    rng = np.random.default_rng(8)
    old, new = DiagonalGaussian([0.0], [1.0]), DiagonalGaussian([0.3], [1.0])
    alpha = 0.3
    x = new.sample(400_000, rng)
    expected = float(np.mean(np.minimum(np.exp(old.log_prob(x) - new.log_prob(x)), 1 - alpha)))
    assert expected < monte_carlo_overlap(old, new, rng) - 0.1  # alpha really lowers reuse
    reused = sum(mix(new, [(old, old.sample(50, rng))], 50, rng, variant="sun2009", alpha=alpha, min_fresh=0).reused for _ in range(2000))
    assert abs(reused / (50 * 2000) - expected) < 0.01


@pytest.mark.parametrize("variant", VARIANTS)
def test_reused_members_are_archive_rows_never_duplicated(variant):
    rng = np.random.default_rng(3)
    d = 5
    dists = [DiagonalGaussian(np.full(d, 0.05 * k), np.full(d, 1.0 - 0.02 * k)) for k in range(4)]
    # Build a realistic archive: each generation mixed from the previous ones, so entries share rows.
    archive = []
    for dist in dists[:3]:
        archive.insert(0, mix(dist, archive, 30, rng, variant="exact"))
    shared = sum(int(np.count_nonzero(g.source > 0)) for g in archive)
    assert shared > 0, "the archive should contain rows reused across entries"
    for _ in range(50):
        g = mix(dists[3], archive, 30, rng, variant=variant)
        assert g.samples.shape == (30, d)
        assert np.all((g.source == 0) == (g.index == -1))
        for member, (src, idx) in enumerate(zip(g.source, g.index)):
            if src > 0:
                np.testing.assert_array_equal(g.samples[member], archive[src - 1].samples[idx])
        assert np.unique(g.samples, axis=0).shape[0] == 30, "a member appears twice"


def test_eim_draws_from_older_generations_when_previous_is_far():
    rng = np.random.default_rng(5)
    new = DiagonalGaussian([0.0, 0.0], [1.0, 1.0])
    far = DiagonalGaussian([50.0, 50.0], [1.0, 1.0])
    # The pass over the 5-row far generation can yield at most 5 (fresh, rule-2) members; the
    # rest must then come from the older generation, whose density equals the new one.
    archive = [(far, far.sample(5, rng)), (new, new.sample(20, rng))]
    g = mix(new, archive, 20, rng, variant="eim_paper", min_fresh=0)  # the rules alone, here and below
    assert g.reused_from_previous == 0 and g.reused_from_older == 15
    # "exact": every rule-2 draw lands under the older generation's graph (its density is the
    # new one) and under no newer one, so each is swapped for one of its members: all 20.
    g = mix(new, archive, 20, rng, variant="exact", min_fresh=0)
    assert g.reused_from_previous == 0 and g.reused_from_older == 20
    g = mix(new, archive, 20, rng, variant="paper")
    assert g.reused == 0


def test_identical_distribution_reuses_everything():
    rng = np.random.default_rng(6)
    dist = DiagonalGaussian(np.zeros(10), np.ones(10))
    old = dist.sample(50, rng)
    for variant in VARIANTS:
        g = mix(dist, [(dist, old)], 50, rng, variant=variant, min_fresh=0)  # the rules alone
        assert g.reused == 50
        np.testing.assert_array_equal(np.sort(g.index), np.arange(50))


@pytest.mark.parametrize("variant", VARIANTS)
def test_high_dimension_near_zero_overlap_is_finite(variant):
    """d = 10^4: densities under/overflow float64, log-space comparisons must not."""
    rng = np.random.default_rng(11)
    d = 10_000
    old = DiagonalGaussian(np.zeros(d), np.full(d, 1.0))
    new = DiagonalGaussian(np.full(d, 0.5), np.full(d, 0.6))
    with np.errstate(all="raise"):
        g = mix(new, [(old, old.sample(50, rng)), (old, old.sample(50, rng))], 50, rng, variant=variant)
    assert g.reused == 0
    assert np.all(np.isfinite(g.samples))
    # and a tiny move at d = 10^4 still reuses most samples
    near = DiagonalGaussian(np.full(d, 0.001), np.full(d, 1.0))
    g = mix(near, [(old, old.sample(50, rng))], 50, rng, variant=variant)
    assert g.reused > 25


def test_mixing_is_deterministic_and_generation_objects_are_archive_entries():
    old, new = DiagonalGaussian(np.zeros(4), np.ones(4)), DiagonalGaussian(np.full(4, 0.2), np.full(4, 0.9))
    samples = old.sample(30, np.random.default_rng(0))
    plain = mix(new, [(old, samples)], 30, np.random.default_rng(42), variant="exact")
    again = mix(new, [(old, samples)], 30, np.random.default_rng(42), variant="exact")
    as_generation = mix(new, [Generation(samples, np.zeros(30, int), np.full(30, -1), old)], 30, np.random.default_rng(42), variant="exact")
    for other in (again, as_generation):
        np.testing.assert_array_equal(plain.samples, other.samples)
        np.testing.assert_array_equal(plain.source, other.source)
        np.testing.assert_array_equal(plain.index, other.index)


def test_chained_eim_generations_stay_distributed_as_their_distribution():
    """A run-like chain: each generation mixed from the Generation objects of the previous ones.

    After a drift over five generations, the final generation (pooled over independent chains)
    must follow its own distribution; this also checks that members reused twice are tested
    against the density of the generation that holds them.
    """
    rng = np.random.default_rng(21)
    means = [0.0, 0.3, 0.5, 0.6, 0.9]
    stds = [1.0, 0.9, 0.85, 0.8, 0.8]
    pooled = []
    for _ in range(1500):
        archive = []
        for m, s in zip(means, stds):
            archive.insert(0, mix(DiagonalGaussian([m], [s]), archive[:3], 20, rng, variant="exact"))
        pooled.append(archive[0].samples[:, 0])
    assert stats.kstest(np.concatenate(pooled), "norm", args=(means[-1], stds[-1])).pvalue > KS_P_MIN


def test_generation_accounting():
    rng = np.random.default_rng(4)
    old, new = DiagonalGaussian([0.0], [1.0]), DiagonalGaussian([0.2], [1.0])
    g = mix(new, [(old, old.sample(40, rng)), (old, old.sample(40, rng))], 40, rng, variant="exact")
    assert isinstance(g, Generation)
    assert g.reused == g.reused_from_previous + g.reused_from_older
    assert int(g.fresh.sum()) == 40 - g.reused
    empty = mix(new, [], 40, rng)
    assert empty.reused == 0 and empty.samples.shape == (40, 1)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"variant": "bogus"}, "variant"),
        ({"alpha": 1.0, "variant": "sun2009"}, "alpha"),
        ({"eim_generations": 0, "variant": "exact"}, "eim_generations"),
    ],
)
def test_bad_arguments_raise(kwargs, message):
    dist = DiagonalGaussian([0.0], [1.0])
    with pytest.raises(ValueError, match=message):
        mix(dist, [], 10, np.random.default_rng(0), **kwargs)


# ------------------------------------------------------------------ chains of generations
# A single mixing step can be exact while a chain of them is not: archived generations share
# members, and a member that was NOT reused carries the information that rule 1 rejected it.
# These tests run whole chains, as a run does: the search distribution random-walks (or drifts)
# by about 0.125 sigma per generation (overlap lambda ~ 0.95, the regime of OpenES/SNES on
# CartPole), each generation mixed from the previous K = 3. Members are standardised by the
# distribution of their generation. Statistics: per chain, the mean of z and of z^2 over the
# generations after a burn-in; across 60 independent chains, their means with standard errors
# computed from the chains (members of one chain are correlated: the same member is reused for
# ~20 generations, so pooling them as independent would understate the error ~10x). Tolerance
# |z-score| < 4. Power: the paper's Algorithm 3 gives E[z^2] = 1.14 in the walk (z ~ +16) and a
# forward-shifted mean in the drift (z ~ +6); a variance error of ~2 % is the smallest this sees.
# Plus a KS test of the last generation of every chain (independent across chains).

CHAIN_GENERATIONS, CHAIN_REPEATS, CHAIN_BURN_IN = 200, 60, 20


def chain_statistics(variant, drift, seed, min_fresh=0):
    """``benchmarks/mixing_chains.py``'s statistic (one implementation): z-scores of the mean of z
    and of E[z^2], KS p of the last generations, E[z^2]."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "benchmarks" / "mixing_chains.py"
    spec = importlib.util.spec_from_file_location("mixing_chains", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    r = module.chains(variant, drift, chains=CHAIN_REPEATS, generations=CHAIN_GENERATIONS, seed=seed, burn_in=CHAIN_BURN_IN, min_fresh=min_fresh)
    return r["z_mean"], r["z_var"], r["ks_p_last"], r["E[z^2]"]


@pytest.mark.slow
@pytest.mark.parametrize("min_fresh", [0, 3], ids=["rules-alone", "min_fresh-3"])
@pytest.mark.parametrize("drift", [0.0, 0.1], ids=["random-walk", "drift"])
@pytest.mark.parametrize("variant", ["paper", "sun2009", "exact"])
def test_chains_of_generations_stay_distributed_as_their_distribution(variant, drift, min_fresh):
    """Also with the minimal refresh (imix_cli.core.mixing, "A minimal refresh"): slots drawn independently
    of the members keep every generation's law, over chains too."""
    z_mean, z_var, ks_p, second = chain_statistics(variant, drift, seed=2024, min_fresh=min_fresh)
    assert abs(z_mean) < 4 and abs(z_var) < 4, (z_mean, z_var, second)
    assert ks_p > KS_P_MIN


@pytest.mark.slow
def test_paper_algorithm_3_is_biased_over_chains():
    """The finding behind eim_variant=exact: the paper's Algorithm 3 (kept as "eim_paper" for
    reproduction) inflates the variance of its generations over a random walk, and shifts them
    forward along a drift. Also shows the chain test above has the power to see it."""
    _, z_var, _, second = chain_statistics("eim_paper", 0.0, seed=2024)
    assert z_var > 8 and second > 1.08, (z_var, second)
    z_mean, _, _, _ = chain_statistics("eim_paper", 0.1, seed=2024)
    assert z_mean > 4, z_mean


def test_an_oscillating_chain_reuses_older_generations_exactly_and_never_twice():
    """Where multi-generation mixing matters: the distribution alternates between N(0, 1) and
    N(0.6, 1), so generation t-2's distribution is generation t's and rule-2 draws keep landing in
    its region. "exact" then takes ~21 % of its members from older generations, stays distributed
    as its distribution (|z| < 4 over 60 chains x 100 generations; Algorithm 3 gives E[z^2] 1.11,
    z ~ +16 here) and never holds a point twice. A version that forgot the heights which decided
    each member's fate (drawing them anew at every mix) put 139,354 duplicate members into these
    generations: the duplicate check is what sees it."""
    rng = np.random.default_rng(7)
    first, second, older, members, duplicates = [], [], 0, 0, 0
    for _ in range(60):
        archive, zs = [], []
        for t in range(100):
            mean = 0.6 * (t % 2)
            g = mix(DiagonalGaussian([mean], [1.0]), archive, 50, rng, variant="exact", eim_generations=3)
            duplicates += 50 - np.unique(g.samples[:, 0]).size
            if t >= 10:
                zs.append(g.samples[:, 0] - mean)
                older, members = older + g.reused_from_older, members + 50
            archive = [g, *archive][:3]
        zs = np.concatenate(zs)
        first.append(zs.mean())
        second.append(np.mean(zs * zs))
    first, second = np.array(first), np.array(second)
    z_mean = first.mean() / (first.std(ddof=1) / np.sqrt(60))
    z_var = (second.mean() - 1.0) / (second.std(ddof=1) / np.sqrt(60))
    assert duplicates == 0
    assert abs(z_mean) < 4 and abs(z_var) < 4, (z_mean, z_var)
    assert older / members > 0.15, older / members


def _walk_steps(rng, dim, generations):
    """A random walk of diagonal Gaussians, mean and per-coordinate std both moving."""
    mean, std = np.zeros(dim), np.full(dim, 0.3)
    for _ in range(generations):
        mean = mean + 0.05 * rng.standard_normal(dim) * std
        std = std * np.exp(0.02 * rng.standard_normal(dim))
        yield DiagonalGaussian(mean, std)


@pytest.mark.parametrize("min_fresh", [0, 2])
@pytest.mark.parametrize("variant", ["paper", "sun2009", "exact"])
@pytest.mark.parametrize("dim,popsize", [(1, 50), (130, 50), (2, 3)])
def test_the_compiled_step_is_the_numpy_step(variant, dim, popsize, min_fresh):
    """imix_cli.core.mixing.kernels draws the same random numbers in the same order as the numpy step:
    along 100-generation chains, every generation has the same members (source, index, samples to
    1e-12), the same trial count, the same heights, and leaves the Generator in the same state.
    This equality is what lets the statistical tests above, which run on the compiled step (the
    default for float64 diagonal Gaussians), vouch for both paths."""
    rng = np.random.default_rng(dim * 100 + popsize)
    archive_numpy, archive_compiled = [], []
    for t, dist in enumerate(_walk_steps(rng, dim, 100)):
        r_numpy, r_compiled = np.random.default_rng(t), np.random.default_rng(t)
        g_numpy = mix(dist, archive_numpy, popsize, r_numpy, variant=variant, compiled=False, min_fresh=min_fresh)
        g_compiled = mix(dist, archive_compiled, popsize, r_compiled, variant=variant, compiled=None if t == 0 else True, min_fresh=min_fresh)
        if t and min_fresh:
            assert np.count_nonzero(g_numpy.source == 0) >= min(min_fresh, popsize), t
        assert np.array_equal(g_numpy.source, g_compiled.source) and np.array_equal(g_numpy.index, g_compiled.index), t
        np.testing.assert_allclose(g_compiled.samples, g_numpy.samples, rtol=0, atol=1e-12)
        assert g_numpy.trials == g_compiled.trials and r_numpy.random() == r_compiled.random(), t
        for a, b in zip(archive_numpy, archive_compiled):
            assert (a.log_u is None and b.log_u is None) or np.array_equal(a.log_u, b.log_u)
        archive_numpy = [g_numpy, *archive_numpy][:3]
        archive_compiled = [g_compiled, *archive_compiled][:3]


def _full_walk_steps(rng, dim, generations):
    """A random walk of FullGaussians made from their factor (as pycma's adapter makes them): mean and factor moving."""
    mean, factor = np.zeros(dim), 0.3 * np.eye(dim)
    for _ in range(generations):
        mean = mean + 0.05 * factor @ rng.standard_normal(dim)
        factor = factor @ (np.eye(dim) + 0.03 * rng.standard_normal((dim, dim)))
        r = np.linalg.qr(factor.T, mode="r")
        yield FullGaussian.from_cholesky(mean, np.tril((r * np.where(np.diag(r) < 0, -1.0, 1.0)[:, None]).T))


@pytest.mark.parametrize("min_fresh", [0, 1])
@pytest.mark.parametrize("dim,popsize", [(1, 6), (10, 10), (40, 15)])
def test_the_compiled_full_step_is_the_numpy_step_bit_for_bit(dim, popsize, min_fresh):
    """The compiled ``"exact"`` step between FullGaussians (mixing.kernels.mix_full_exact: pycma's adapter, imix's CMA-ES)
    draws the same random numbers in the same order and computes the same log-densities as the numpy step: along
    60-generation chains every generation is the same bit for bit (samples, source, index, trials, heights), and the
    Generator is left in the same state -- at d = 40 with the archived log-densities kept between steps, below
    computed in the step. Made to fail (d = 10, 40) by summing each draw's L eps in the other order in _full_draws."""
    rng = np.random.default_rng(dim * 100 + popsize)
    archive_numpy, archive_compiled = [], []
    for t, dist in enumerate(_full_walk_steps(rng, dim, 60)):
        r_numpy, r_compiled = np.random.default_rng(t), np.random.default_rng(t)
        g_numpy = mix(dist, archive_numpy, popsize, r_numpy, variant="exact", compiled=False, min_fresh=min_fresh)
        g_compiled = mix(dist, archive_compiled, popsize, r_compiled, variant="exact", compiled=None if t == 0 else True, min_fresh=min_fresh)
        assert np.array_equal(g_numpy.source, g_compiled.source) and np.array_equal(g_numpy.index, g_compiled.index), t
        assert np.array_equal(g_numpy.samples.view(np.int64), g_compiled.samples.view(np.int64)), t
        assert g_numpy.trials == g_compiled.trials and r_numpy.random() == r_compiled.random(), t
        for a, b in zip(archive_numpy, archive_compiled):
            assert (a.log_u is None and b.log_u is None) or np.array_equal(a.log_u, b.log_u)
        archive_numpy = [g_numpy, *archive_numpy][:3]
        archive_compiled = [g_compiled, *archive_compiled][:3]
    assert sum(g.reused for g in archive_compiled) > 0


def test_the_compiled_step_takes_smaller_generations_and_refuses_what_it_does_not_compute():
    rng = np.random.default_rng(3)
    dist = DiagonalGaussian(np.zeros(4), np.ones(4))
    archive = [Generation(dist.sample(n, rng), np.zeros(n, np.int64), np.full(n, -1, np.int64), dist) for n in (30, 40, 20)]
    new = DiagonalGaussian(np.full(4, 0.1), np.ones(4))
    a = mix(new, archive, 50, np.random.default_rng(1), variant="exact", compiled=True)
    for g in archive:
        g.log_u = None
    b = mix(new, archive, 50, np.random.default_rng(1), variant="exact", compiled=False)
    assert np.array_equal(a.source, b.source) and np.array_equal(a.index, b.index)
    with pytest.raises(ValueError, match="compiled"):
        mix(FullGaussian(np.zeros(4), np.eye(4)), [(dist, dist.sample(5, rng))], 5, rng, variant="exact", compiled=True)
    with pytest.raises(ValueError, match="compiled"):  # a generation larger than popsize
        mix(new, [(dist, dist.sample(60, rng))], 50, rng, variant="sun2009", compiled=True)


def _kernels_without_random_interval(tmp_path):
    """A copy of imix_cli.core.mixing.kernels whose import of numba's ``random_interval`` fails, as it
    would with a numba release that moved it."""
    import importlib.util

    import imix_cli.core.mixing.kernels as kernels

    line = "from numba.np.random.random_methods import random_interval"
    source = Path(kernels.__file__).read_text()
    assert line in source
    copy = tmp_path / "mixing_kernels_fallback.py"
    copy.write_text(source.replace(line, "from numba.np.random.random_methods import random_interval_moved as random_interval"))
    spec = importlib.util.spec_from_file_location("mixing_kernels_fallback", copy)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.random_interval is None
    return module


@pytest.mark.parametrize("fallback", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_the_compiled_permutation_is_numpys(fallback, tmp_path):
    """mixing.kernels._permutation (its own 1-d loop, for compile time; numba's permutation if numba
    moved the draw it uses) gives ``Generator.permutation(n)``'s array and leaves the Generator in
    the same state, for sizes around the 32-bit draws' masks."""
    if fallback:
        _permutation = _kernels_without_random_interval(tmp_path)._permutation
    else:
        from imix_cli.core.mixing.kernels import _permutation

    for seed in range(40):
        for n in (0, 1, 2, 3, 7, 8, 9, 50, 150, 1025):
            r_numpy, r_compiled = np.random.default_rng(seed), np.random.default_rng(seed)
            assert np.array_equal(r_numpy.permutation(n), _permutation(r_compiled, n)), (seed, n)
            assert r_numpy.bit_generator.state == r_compiled.bit_generator.state, (seed, n)


class _Laplace:
    """A SearchDistribution that is not a Gaussian: i.i.d. Laplace(loc, 1) coordinates."""

    def __init__(self, loc, dim=2):
        self.loc, self.dim = loc, dim

    def sample(self, n, rng):
        return self.loc + rng.laplace(size=(n, self.dim))

    def log_prob(self, x):
        return -np.abs(np.atleast_2d(x) - self.loc).sum(axis=1) - self.dim * np.log(2.0)


@pytest.mark.parametrize("variant", ["paper", "sun2009", "exact"])
def test_any_search_distribution_mixes_through_the_generic_path(variant):
    """mix needs only the SearchDistribution protocol: Laplace generations mixed from a shifted
    Laplace are Laplace(0.3) (KS p > 1e-3 on each coordinate's pooled members) and reuse most."""
    from imix_cli.core.distributions import SearchDistribution

    old, new = _Laplace(0.0), _Laplace(0.3)
    assert isinstance(new, SearchDistribution)
    rng = np.random.default_rng(11)
    pooled, reused = [], 0
    for _ in range(400):
        g = mix(new, [(old, old.sample(20, rng))], 20, rng, variant=variant)
        pooled.append(g.samples)
        reused += g.reused
    pooled = np.concatenate(pooled)
    for j in range(2):
        assert stats.kstest(pooled[:, j] - 0.3, "laplace").pvalue > KS_P_MIN
    assert reused / (400 * 20) > 0.6


def test_a_registered_variant_is_what_mix_and_the_settings_read(monkeypatch):
    """A variant is one object (imix_cli.core.mixing.VARIANT_SPECS): mix() runs its own step over the generations
    its look-back rule allows, and MixingSettings keeps that many in the archive."""
    from imix_cli.core import mixing
    from imix_cli.core.mixing.generation import MixingSettings

    depths = []

    def step(builder, new_dist, archive, entries, depth, alpha, rng):
        depths.append(depth)
        return mixing._step_alternate(builder, new_dist, archive, entries, depth, alpha, rng)

    monkeypatch.setitem(mixing.VARIANT_SPECS, "probe", mixing.Variant("probe", looks_back=True, kernel=0, heights=False, uses_alpha=False, step=step))
    rng = np.random.default_rng(0)
    dist = DiagonalGaussian(np.zeros(3), np.ones(3))
    archive = [(dist, dist.sample(10, rng)) for _ in range(4)]
    g = mix(dist, archive, 10, rng, variant="probe", eim_generations=4, min_fresh=0)
    assert depths == [4] and g.samples.shape == (10, 3) and g.reused == 10  # the same distribution: all reused
    assert MixingSettings("probe", eim_generations=4).depth == 4
    for name in VARIANTS:
        assert MixingSettings(name, eim_generations=5).depth == (5 if name in ("exact", "eim_paper") else 1), name
    with pytest.raises(ValueError, match="unknown mixing variant 'nope'"):
        _ = MixingSettings("nope").depth
