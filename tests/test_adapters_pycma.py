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


# --------------------------------------------------------- bbob's findings (issue 45)
def _sharp_ridge(dim=5, seed=7):
    """bbob's f13 in numpy: z = Q Lambda^10 Q (x - 1), f = z_1^2 + 100 |z_2..d| (a ridge pycma solves while C's
    condition number grows without bound)."""
    q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((dim, dim)))
    scale = 10 ** (np.arange(dim) / (dim - 1))

    def f(x):
        z = q @ (scale * (q @ (np.asarray(x) - 1.0)))
        return z[0] ** 2 + 100 * np.sqrt(np.sum(z[1:] ** 2))

    return f


@pytest.mark.parametrize("seed", [0, 2])
def test_the_sharp_ridge_runs_to_the_end_where_pycma_runs_bbob_f13(seed):
    """bbob f13, d = 5: the adapter formed C = A^T A from pycma's factor and factored it again (the condition number
    squared) and raised "FullGaussian: cov is not positive definite" after ~800 generations while pycma went on.
    This numpy ridge, with pycma's stopping rules off but noeffectaxis, crashed the old adapter at generation 940
    (seed 0) and 892 (seed 2). The squared condition was not the cause: pycma's tell *repaired* the members it had
    not sampled itself (``check_points=None`` shortens long steps), the update was no longer pycma's, and the mean
    ran away (4e9 at generation 900) until C broke. Told without repair, as pycma's own draws are, the run ends at
    the optimum, with the old factorisation too (measured); with repair it runs away with the new one too."""
    ridge = _sharp_ridge()
    es = cma.CMAEvolutionStrategy(np.zeros(5), 2.0, {"seed": seed + 1, "verbose": -9, "tolfun": 0, "tolfunhist": 0, "tolx": 0,
                                                     "tolflatfitness": 1e9, "tolstagnation": 0, "tolconditioncov": 1e30})  # fmt: skip
    m = imix_cli.MixingES(es, "exact", rng=seed)
    generations = 0
    while not m.stop() and generations < 2000:
        x = m.ask()
        m.tell(x, [ridge(xi) for xi in x])
        generations += 1
    assert generations > 1000 or m.stop(), (generations, m.stop())
    assert es.best.f < 1e-5, es.best.f
    assert np.max(np.abs(es.mean - 1.0)) < 1e-3, es.mean  # at the optimum, not run away (pycma's repair: see above)


def test_the_gaussian_from_pycmas_factor_is_exact_at_condition_numbers_where_cholesky_of_c_fails():
    """A factor of condition 1e9 (C: 1e18, at the edge of float64): the log-density from the factor matches the one
    computed in the factor's own terms (|A^-1 (x - m)|^2), and the square of the factor is C; a singular factor is
    refused in one line (the adapter then draws without reuse)."""
    from imix_cli.core.adapters.pycma import gaussian_from_factor

    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.standard_normal((6, 6)))
    a = q * np.logspace(0, -9, 6)  # columns scaled: A = Q diag(1 .. 1e-9)
    dist = gaussian_from_factor(np.zeros(6), a)
    x = a @ rng.standard_normal((6, 50))
    z = np.linalg.solve(a, x)
    expected = -0.5 * 6 * np.log(2 * np.pi) - np.sum(np.log(np.logspace(0, -9, 6))) - 0.5 * np.sum(z * z, axis=0)
    np.testing.assert_allclose(dist.log_prob(x.T), expected, rtol=1e-6)  # both at cond(A) * eps
    np.testing.assert_allclose(dist.chol @ dist.chol.T, a @ a.T, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="singular"):
        gaussian_from_factor(np.zeros(6), np.diag([1.0, 1, 1, 1, 1, 0]))


def _stop_after(mixing: bool, seed: int):
    """A flat function (every value 1.0) with pycma's tolfun and tolfunhist off: evaluations until tolflatfitness."""
    es = cma.CMAEvolutionStrategy(np.ones(5), 1.0, {"seed": seed + 1, "verbose": -9, "tolfun": 0, "tolfunhist": 0})
    m = imix_cli.MixingES(es, "exact", rng=seed) if mixing else es
    evaluations = 0
    while not m.stop():
        x = m.ask()
        m.tell(x, [1.0] * len(x))
        evaluations += len(x)
    return evaluations, set(m.stop())


def test_reused_values_do_not_trip_pycma_stopping_rules():
    """pycma counts flat generations in a row (tolflatfitness) as new information: lambda evaluations each. A mixed
    generation repeats most members of the last one with their stored values, and the old adapter stopped after
    9-14 evaluations where pycma alone stops after 16 (d = 5, lambda = 8): stored values counted as new flat
    generations. With the fresh record, the rule fires after at least pycma's own evaluations."""
    for seed in range(5):
        alone, why_alone = _stop_after(False, seed)
        mixed, why_mixed = _stop_after(True, seed)
        assert why_alone == why_mixed == {"tolflatfitness"}, (why_alone, why_mixed)
        assert mixed >= alone, (seed, mixed, alone)


def test_the_fresh_record_is_pycmas_record_of_the_fresh_values():
    """What pycma's stop() reads through the adapter: one entry of fit.hist per lambda fresh values (not per
    generation), each the best of its block, and pycma's own record restored after stop()."""
    from imix_cli.core.adapters.pycma import FreshRecord

    m = imix_cli.MixingES(cma.CMAEvolutionStrategy(6 * [1.0], 0.5, {"seed": 4, "verbose": -9}), "exact", rng=4)
    fresh = []
    for _ in range(40):
        x = m.ask()
        f = [cma.ff.elli(xi) for xi in x]
        fresh += f
        m.tell(x, f)
    es, lam = m.es.es, m.es.es.popsize
    blocks = [sorted(fresh[i : i + lam]) for i in range(0, len(fresh) - lam + 1, lam)]
    record = m.es._fresh.record
    assert isinstance(m.es._fresh, FreshRecord)
    assert m.reuse > 0.3 and len(blocks) < 40
    assert record["fit"] == blocks[-1]
    assert record["hist"] == [b[0] for b in blocks[::-1]][: len(record["hist"])]
    own = list(es.fit.hist)
    m.stop()
    assert es.fit.hist == own


def test_ties_between_reused_and_fresh_members_fall_in_a_random_order():
    """A plateau (bbob f7): every member of a mixed generation has the same value. pycma keeps ties in the order told
    and a mixed generation lists its reused members first, so the old adapter always ranked them first: the mean
    went back to earlier points. Told in a random order, the generation's first member is among pycma's mu
    selected ones mu/lambda of the time (binomial test over 300 generations), as for pycma's own draws."""
    m = imix_cli.MixingES(cma.CMAEvolutionStrategy(6 * [1.0], 0.5, {"seed": 6, "verbose": -9, "tolfun": 0, "tolfunhist": 0,
                                                                       "tolflatfitness": 1e9, "tolx": 0}), "exact", rng=6)  # fmt: skip
    es = m.es.es
    mu, lam = es.sp.weights.mu, es.popsize
    selected, reused_first, trials = 0, 0, 300
    for _ in range(trials):
        x = m.ask()
        m.tell(x, np.ones(len(x)))
        first = m.generation.samples[0]
        reused_first += m.generation.source[0] > 0
        selected += bool(np.any(np.all(np.asarray(es.pop_sorted)[:mu] == first, axis=1)))
    assert reused_first > trials / 3, "the generations must start with reused members"
    p = stats.binomtest(selected, trials, mu / lam).pvalue
    assert p > 1e-3, (selected, trials, mu / lam)


def test_fmin2_runs_pycmas_ipop_and_bipop_with_mixing():
    """imix_cli.fmin2: pycma's own restart loop (IPOP, BIPOP) with mixing in every run: the evaluations pycma counts
    are the objective's calls, fewer than pycma's alone on the sphere; each restart's population is pycma's
    (doubled); noise_handler is refused in one line."""
    calls = {"n": 0}

    def sphere(x):
        calls["n"] += 1
        return cma.ff.sphere(x)

    x0 = lambda: np.random.default_rng(0).uniform(-4, 4, 5)  # noqa: E731
    options = {"verbose": -9, "seed": 1, "ftarget": 1e-8}
    _, alone = cma.fmin2(sphere, x0, 2.0, options)
    alone_calls, calls["n"] = calls["n"], 0
    _, mixed = imix_cli.fmin2(sphere, x0, 2.0, options)
    assert mixed.result.evaluations == calls["n"] < 0.8 * alone_calls
    assert mixed.result.fbest < 1e-8 and "ftarget" in mixed.stop()
    for bipop in (False, True):  # a flat function stops every run: pycma's restarts go on, populations doubled
        _, es = imix_cli.fmin2(lambda x: 1.0, x0, 2.0, {"verbose": -9, "seed": 2, "tolfun": 0, "tolfunhist": 0}, restarts=2, bipop=bipop)
        assert len(es.all_stoppings) - 1 >= 3 and "tolflatfitness" in es.all_stoppings[-1]
    assert es.popsize > 8
    with pytest.raises(ValueError, match="noise_handler"):
        imix_cli.fmin2(sphere, x0, 2.0, options, noise_handler=cma.NoiseHandler(5))


def test_a_singular_pycma_factor_draws_without_reuse_instead_of_raising(monkeypatch):
    """Where pycma's own factor is singular (a degenerate state pycma goes on sampling from), the adapter has no
    density to mix with: that generation is drawn without reuse (and not archived), not an exception."""
    from imix_cli.core.adapters import pycma as adapter

    m = imix_cli.MixingES(cma.CMAEvolutionStrategy(4 * [1.0], 0.5, {"seed": 8, "verbose": -9}), "exact", rng=8)
    m.optimize(cma.ff.sphere, iterations=5)
    own = adapter._sampler_map
    monkeypatch.setattr(adapter, "_sampler_map", lambda sm, dim: own(sm, dim) * np.array([1.0, 1, 1, 0])[:, None])
    m.es._dist = None
    assert not m.es.mixable
    x = m.ask()
    assert m.generation.reused == 0 and len(x) == m.popsize
    m.tell(x, [cma.ff.sphere(xi) for xi in x])
    assert m.archive.generations == []
    monkeypatch.setattr(adapter, "_sampler_map", own)
    m.es._dist = None
    m.optimize(cma.ff.sphere, iterations=5)
    assert m.reused > 0


def test_the_adapter_gives_pycmas_recombination_weights_to_conditional_mixing():
    """Variant "conditional" conditions each reused member on its weight in the mean's move; the adapter gives
    pycma's: the mu best members of the generation told carry pycma's positive weights by rank (summing to 1), the
    others 0, in the generation's order whatever order they were told in."""
    m = imix_cli.MixingES(cma.CMAEvolutionStrategy(5 * [1.0], 0.5, {"seed": 3, "verbose": -9}), "conditional", rng=3)
    for _ in range(6):
        x = m.ask()
        f = np.array([cma.ff.elli(xi) for xi in x])
        m.tell(x, f)
    es = m.es.es
    samples = m.generation.samples
    values = np.array([cma.ff.elli(xi) for xi in samples])
    c = m.es.mean_weights
    mu = es.sp.weights.mu
    best = np.argsort(values)[:mu]
    np.testing.assert_allclose(c[best], np.asarray(es.sp.weights)[:mu], rtol=0, atol=1e-15)
    assert np.count_nonzero(c) == mu and abs(c.sum() - 1.0) < 1e-12
    assert m.generation.mean_weights is not None and m.reuse > 0.2


def test_a_wrapped_pycma_es_keeps_its_result_logger_and_disp(tmp_path, monkeypatch):
    """A pycma user's tools still work on the wrapped ES: ``es.result`` (its evaluations the episodes run, not the members
    told), ``es.logger`` writing the files ``cma.plot()`` reads, ``es.disp()``, ``es.sigma``. Made to fail: without
    MixingES.__getattr__, ``es.result`` raised AttributeError."""
    monkeypatch.chdir(tmp_path)
    es = imix_cli.MixingES(cma.CMAEvolutionStrategy(np.ones(5), 0.5, {"seed": 1, "verbose": -1}), "exact", rng=1)
    while not es.stop():
        x = es.ask()
        es.tell(x, [float(np.sum(np.asarray(p) ** 2)) for p in x])
        es.logger.add()
    assert es.reused > 0 and es.result.evaluations == es.evaluations < es.members
    assert es.result.fbest < 1e-8 and es.sigma == es.es.es.sigma
    es.disp()
    logged = cma.CMADataLogger().load()
    assert logged.f.shape[0] >= es.countiter and logged.f[-1][1] == es.evaluations  # column 1: evaluations
    with pytest.raises(AttributeError, match="nor has the ES it wraps"):
        es.no_such_thing  # noqa: B018
