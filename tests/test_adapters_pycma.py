"""Importance mixing for pycma (imix_cli.core.adapters.pycma): the guarantees of imix's own ES, on pycma's.

* the distribution the adapter reads is the one pycma's own ``ask`` samples from (full, diagonal,
  scaled variables, after the conditioning is moved into the phenotype map);
* along pycma's own path of distributions, hundreds of generations mixed through MixingES are
  distributed as pycma's distribution of each generation (the chain statistic of tests/test_mixing.py);
* pycma's update ignores the order of its population (without ties), through the adapter too;
* no fixed point: MixingES's minimal refresh (``min_fresh``) evaluates a member of every generation;
* the stored-return remedies (``reeval_count``) are there; options that make pycma's samples
  non-Gaussian are refused with one line; ``es.stop()``, ``optimize`` and ``countevals`` work.
"""

import copy
import warnings

import numpy as np
import pytest
from adapter_chains import chain_z_scores, whiten
from scipy import stats

cma = pytest.importorskip("cma")

import imix_cli  # noqa: E402
from imix_cli.core.adapters.pycma import PycmaES  # noqa: E402
from imix_cli.core.distributions import DiagonalGaussian  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")


def _run(es, generations, f=cma.ff.elli):
    for _ in range(generations):
        x = es.ask()
        es.tell(x, [f(xi) for xi in x])
    return es


# --------------------------------------------------------------- the distribution read
CASES = {
    "full": ({}, 40),
    "diagonal": ({"CMA_diagonal": True}, 40),
    "scaled": ({"scaling_of_variables": [1, 2, 3, 4, 5], "typical_x": [0.5] * 5}, 40),
    "alleviated": ({"conditioncov_alleviate": [1e8, 10.0]}, 60),  # C's conditioning moved into the phenotype map
}


@pytest.mark.parametrize("case", list(CASES))
def test_the_distribution_read_is_the_one_pycma_samples_from(case):
    """20,000 points of pycma's own ask, whitened by the adapter's distribution: mean 0 and covariance
    I within 6 standard errors, Mahalanobis norms chi2(d). A wrong scale, a missed sigma_vec, a
    stale eigendecomposition or a missed phenotype map shows as entries far outside."""
    options, generations = CASES[case]
    es = _run(cma.CMAEvolutionStrategy(5 * [1.0], 0.5, {"seed": 3, "verbose": -9, **options}), generations)
    dist = PycmaES.__new__(PycmaES)
    dist.es, dist.dim = copy.deepcopy(es), es.N
    read = dist._read_distribution()
    if case == "alleviated":
        assert not dist.es.gp.isidentity, "the case must exercise the phenotype map"
    if case == "diagonal":
        assert isinstance(read, DiagonalGaussian)
    sampler = copy.deepcopy(dist.es)
    z = whiten(read, np.array(sampler.ask(20_000)))
    n = z.shape[0]
    assert np.max(np.abs(z.mean(axis=0))) < 6 / np.sqrt(n), z.mean(axis=0)
    assert np.max(np.abs(np.cov(z.T) - np.eye(5))) < 6 * np.sqrt(2 / n), np.cov(z.T)
    assert stats.kstest(np.sum(z * z, axis=1), stats.chi2(5).cdf).pvalue > 1e-4


# ------------------------------------------------------------------------------ chains
def _pycma_path(generations, seed):
    """pycma's own run (its ask and tell, elli, d = 4): a snapshot before every generation."""
    es = cma.CMAEvolutionStrategy(4 * [1.0], 0.5, {"seed": seed, "verbose": -9, "popsize": 12, "updatecovwait": 0})
    path = []
    for _ in range(generations):
        path.append(copy.deepcopy(es))
        x = es.ask()
        es.tell(x, [cma.ff.elli(xi, cond=1e3) for xi in x])
    return path


def _own_reading(es):
    """pycma's distribution computed independently of the adapter: mean, sigma^2 diag(sigma_vec) C diag(sigma_vec)."""
    sv = es.sigma_vec * np.ones(es.N)
    return np.asarray(es.mean, float), es.sigma**2 * (np.asarray(es.sm.C) * np.outer(sv, sv))


@pytest.mark.slow
def test_mixed_generations_along_pycmas_path_are_distributed_as_its_distributions():
    """30 chains of 150 generations, each mixed by MixingES along one pycma run's distributions
    (the run's own, so the path does not depend on the mixed members); every member whitened by
    pycma's distribution of its generation (computed here, not by the adapter). Per chain the
    mean of z and of z^2; across chains their z-scores (< 4), as tests/test_mixing.py's chains."""
    generations, chains, burn_in = 150, 30, 10
    path = _pycma_path(generations, seed=5)
    truth = [_own_reading(es) for es in path]
    per_chain, reused = [], 0
    for chain in range(chains):
        m = imix_cli.MixingES(PycmaES(copy.deepcopy(path[0]), step_size="pycma"), "exact", rng=chain)
        m.es.tell = lambda samples, fitness, **probes: None  # the path is pycma's own run: its next state is set below
        zs = []
        for t in range(generations):
            m.es.es, m.es._dist = path[t], None
            x = m.ask()
            mean, cov = truth[t]
            if t >= burn_in:
                zs.append(np.linalg.solve(np.linalg.cholesky(cov), (m.generation.samples - mean).T).T)
                reused += m.generation.reused
            m.tell(x, [cma.ff.elli(xi, cond=1e3) for xi in x])
        per_chain.append(np.concatenate(zs))
    z_mean, z_var, second = chain_z_scores(per_chain)
    assert reused > 0.2 * chains * (generations - burn_in) * 12, "the chains must reuse"
    assert abs(z_mean) < 4 and abs(z_var) < 4, (z_mean, z_var, second)


# ------------------------------------------------------------------------ the update
def test_pycmas_update_through_the_adapter_ignores_the_order_of_the_population():
    m = imix_cli.MixingES(PycmaES(cma.CMAEvolutionStrategy(6 * [1.0], 0.5, {"seed": 2, "verbose": -9}), step_size="pycma"), "exact", rng=0)
    m.optimize(cma.ff.elli, iterations=5)
    a, b, c = (copy.deepcopy(m.es) for _ in range(3))
    x = a.ask(np.random.default_rng(0))
    f = np.array([cma.ff.elli(xi) for xi in x])
    perm = np.random.default_rng(1).permutation(len(f))
    a.tell(x, f)
    b.tell(x[perm], f[perm])
    c.tell(x, f[perm])  # the power: values given to the wrong members
    np.testing.assert_allclose(a.distribution.mean, b.distribution.mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.distribution.cov, b.distribution.cov, rtol=1e-10, atol=1e-14)
    assert np.max(np.abs(a.distribution.mean - c.distribution.mean)) > 1e-3


def test_a_fully_reused_generation_would_not_repeat_the_update_and_is_refreshed():
    """Issue 35's no-fixed-point guarantee on pycma: a nearly still distribution (no covariance or
    step-size adaptation, a mean that barely moves) reuses whole generations; MixingES's default
    must not let more than 3 consecutive generations go without a fresh evaluation."""
    es = cma.CMAEvolutionStrategy(5 * [1.0], 0.5, {"seed": 1, "verbose": -9, "CMA_on": 0, "AdaptSigma": False, "CMA_cmean": 1e-4})
    m = imix_cli.MixingES(PycmaES(es, step_size="pycma"), "exact", rng=0)
    run = longest = 0
    for _ in range(60):
        x = m.ask()
        m.tell(x, [cma.ff.sphere(xi) for xi in x])
        run = run + 1 if x.shape[0] == 0 else 0
        longest = max(longest, run)
    assert longest <= 3, f"{longest} consecutive generations without a fresh evaluation"


# ----------------------------------------------------------------- the issue's example
def test_the_issues_sphere_example_reuses_and_saves_evaluations():
    """The issue's done-when: d = 10, seed 1, f(mean) <= 1e-8 with >= 30 % fewer evaluations than
    pycma alone and at most 1.5x its generations."""
    plain = cma.CMAEvolutionStrategy(10 * [1.0], 0.5, {"seed": 1, "verbose": -9})
    generations = 0
    while cma.ff.sphere(plain.mean) > 1e-8:
        x = plain.ask()
        plain.tell(x, [cma.ff.sphere(xi) for xi in x])
        generations += 1
    es = cma.CMAEvolutionStrategy(10 * [1.0], 0.5, {"seed": 1, "verbose": -9})
    m = imix_cli.MixingES(es, "exact", rng=0)
    mixed = 0
    while cma.ff.sphere(m.distribution.mean) > 1e-8 and mixed < 3 * generations:
        x = m.ask()
        m.tell(x, [cma.ff.sphere(xi) for xi in x])
        mixed += 1
    assert cma.ff.sphere(m.distribution.mean) <= 1e-8
    assert m.evaluations <= 0.7 * plain.countevals, (m.evaluations, plain.countevals)
    assert mixed <= 1.5 * generations, (mixed, generations)
    assert es.countevals == m.evaluations  # pycma counts what was evaluated, not what was told


def test_optimize_and_stop_run_pycmas_termination_criteria():
    es = cma.CMAEvolutionStrategy(6 * [1.0], 0.5, {"seed": 4, "verbose": -9, "ftarget": 1e-10})
    m = imix_cli.MixingES(es, "exact", rng=0).optimize(cma.ff.sphere)
    assert "ftarget" in m.stop() and "ftarget" in es.stop()
    assert es.result.evaluations == m.evaluations < es.countiter * es.popsize
    assert cma.ff.sphere(es.result.xfavorite) < 1e-6


# -------------------------------------------------------------- stored-return remedies
def test_reeval_count_re_measures_reused_members_and_calibrates_the_rest():
    rng = np.random.default_rng(0)

    def noisy(x):
        return cma.ff.sphere(x) + rng.standard_normal()

    es = cma.CMAEvolutionStrategy(6 * [1.0], 0.5, {"seed": 1, "verbose": -9})
    m = imix_cli.MixingES(es, "exact", rng=0, reeval_count=2)
    told = []
    original = m.es.tell

    def spy(samples, fitness, **kw):
        told.append(np.array(fitness))
        return original(samples, fitness, **kw)

    m.es.tell = spy
    reevaluated = calibrated = 0
    for _ in range(40):
        x = m.ask()
        plan = m.plan
        stored = m.tell(x, [noisy(xi) for xi in x])
        reevaluated += plan.reevaluated
        kept = (plan.generation.source > 0) & ~np.isin(np.arange(stored.size), plan.evaluate)
        calibrated += int(np.any(told[-1][kept] != stored[kept]))
    assert reevaluated >= 2 * 30, reevaluated
    assert calibrated > 10, "stored returns must be told calibrated once pairs exist"


# ------------------------------------------------------------------------- refusals
@pytest.mark.parametrize(
    "options, option",
    [
        ({"bounds": [-5, 5]}, "bounds"),
        ({"integer_variables": [0]}, "integer_variables"),
        ({"fixed_variables": {0: 1.0}}, "fixed_variables"),
        ({"CMA_elitist": True}, "CMA_elitist"),
        ({"popsize": 4}, "CMA_mirrors"),  # pycma mirrors by default below popsize 6
        ({"mean_shift_line_samples": True}, "mean_shift_line_samples"),
    ],
)
def test_options_that_make_pycmas_samples_non_gaussian_are_refused_in_one_line(options, option):
    es = cma.CMAEvolutionStrategy(5 * [1.0], 0.5, {"verbose": -9, **options})
    with pytest.raises(ValueError) as err:
        imix_cli.MixingES(es, "exact", rng=0)
    message = str(err.value)
    assert "\n" not in message and f"pycma option {option}=" in message


def test_a_bad_step_size_and_a_used_es_are_refused():
    es = cma.CMAEvolutionStrategy(5 * [1.0], 0.5, {"verbose": -9})
    with pytest.raises(ValueError, match="step_size='csa'"):
        PycmaES(es, step_size="csa")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _run(es, 1)
    with pytest.raises(ValueError, match="already been told 1 generations"):
        PycmaES(es)
