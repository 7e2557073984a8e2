"""Tests of imix's own CMA-ES (imix_cli.core.algorithms.cmaes) against pycma 4.5.

* Trajectory: pycma samples and updates in its own ask/tell loop; our CMAES is told the
  same samples and fitness. Mean, sigma, C, p_sigma and p_c must agree to round-off
  (relative 1e-9, observed <= 1e-12) every generation, for >= 200 generations at d = 10
  and d = 130 (plus options and population sizes that take other code paths).
* Strategy parameters for many (d, lambda) equal pycma's.
* Ties: the update does not depend on the order of tied members, and a tied group gets
  the mean of its positions' weights.
* state_dict / load_state_dict: data only, continuing is bit-identical.
* The dimension guard.

The generic ES tests (API contract, optimisation) are in tests/test_algorithms.py.
"""

from __future__ import annotations

import io
import json
import math
import warnings

import cma
import numpy as np
import pytest
from objectives import RotatedEllipsoid, sphere

from imix_cli.core.algorithms.cmaes import CMAES, MAX_DIM, _Parameters, check_dimension

#: state tolerance: relative to the largest entry of each quantity (round-off grows
#: slowly over generations; observed <= 1e-12 after 300 generations)
RTOL = 1e-9


def _reference_pycma(dim, popsize, x0, sigma, seed, **options):
    """pycma configured as imix's CMAES (the options the former wrapper pinned), sampling itself."""
    gen = np.random.default_rng(seed)
    opts = dict(popsize=popsize, verbose=-9, verb_disp=0, verb_log=0, seed=np.nan, CMA_mirrors=0,
                updatecovwait=0, randn=lambda n, d: gen.standard_normal((n, d)))  # fmt: skip
    opts.update(options)
    return cma.CMAEvolutionStrategy(x0, sigma, opts)


def _close(ours, ref, what):
    ours, ref = np.asarray(ours, dtype=float), np.asarray(ref, dtype=float)
    scale = max(np.max(np.abs(ref)), 1e-300)
    err = np.max(np.abs(ours - ref)) / scale
    assert err <= RTOL, f"{what}: relative difference {err:.2e}"


def _assert_same_state(ours: CMAES, ref: cma.CMAEvolutionStrategy, generation):
    at = f"generation {generation}"
    _close(ours.mean_geno, ref.mean, f"mean, {at}")
    _close(ours.step_size, ref.sigma, f"sigma, {at}")
    _close(ours.C, ref.sm.C, f"C, {at}")
    _close(ours.p_c, ref.pc, f"p_c, {at}")
    _close(ours.p_sigma, ref.adapt_sigma.ps, f"p_sigma, {at}")
    _close(ours.scaling, np.broadcast_to(ref.sigma_vec.scaling, (ours.dim,)), f"scaling, {at}")
    assert ours.countiter == ref.countiter


def _pycma_ask_prelude(ref: cma.CMAEvolutionStrategy) -> None:
    """What pycma's next ask does before sampling (our tell does it at its end); repeating
    it in that ask changes nothing."""
    limits = ref.opts["conditioncov_alleviate"]
    if limits:
        ref.alleviate_conditioning_in_coordinates(limits[0])
        ref.alleviate_conditioning(limits[-1])


def _run_side_by_side(dim, popsize, generations, sizes=None, seed=0, cond=1e2, rotate=True, **options):
    """pycma's own loop and our CMAES told the same samples; compare after every tell."""
    f = RotatedEllipsoid(dim, cond=cond, seed=3, rotate=rotate)
    ref = _reference_pycma(dim, popsize, np.ones(dim), 0.3, seed, **options)
    ours = CMAES(dim, popsize=popsize, sigma=0.3, weight_decay=0.0, mean=np.ones(dim), cma_options=options or None)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="The number of solutions passed to `tell`")
        for g in range(generations):
            n = popsize if sizes is None else sizes[g % len(sizes)]
            samples = np.array(ref.ask(number=n))
            fx = f(samples)
            ref.tell(list(samples), fx.tolist())
            ours.tell(samples, -fx)
            _pycma_ask_prelude(ref)
            _assert_same_state(ours, ref, g + 1)
    return ours, ref, f


def test_equals_pycma_trajectory_d10():
    """d = 10, lambda = 16, 300 generations: from f = 82 down to round-off (f ~ 1e-23),
    i.e. through a sigma change of 1e10 and an adapted, ill-conditioned C."""
    ours, ref, f = _run_side_by_side(10, 16, 300)
    assert f(ours.mean[None])[0] < 1e-15 * f(np.ones((1, 10)))[0]  # it did optimise
    # the sampling distribution is pycma's: N(mean, sigma^2 C)
    np.testing.assert_allclose(ours.distribution.cov, ref.sigma**2 * ref.sm.C, rtol=1e-9, atol=0)
    np.testing.assert_allclose(ours.distribution.mean, ref.mean, rtol=1e-12)


def test_equals_pycma_trajectory_d130():
    """The paper's CartPole setting: d = 130, lambda = 50, 200 generations (~3 s)."""
    ours, _, _ = _run_side_by_side(130, 50, 200)
    # C adapts slowly at d = 130 (cmu ~ 1.3e-3): condition 1.93 after 200 generations
    assert np.linalg.cond(ours.C) > 1.5


@pytest.mark.parametrize(
    "dim, popsize, sizes, rotate, options",
    [
        (10, 17, None, True, {}),  # odd lambda: a zero weight in the middle
        (10, 16, [16, 21, 16, 13, 9], True, {}),  # told n != lambda (n >= mu): pycma's own handling
        (10, 16, None, True, {"CMA_active": False}),  # no negative weights
        # axis-parallel ellipsoid: C -> correlation matrix, scales into sigma_vec
        (6, 12, None, False, {"conditioncov_alleviate": [1e2, 1e30]}),
    ],
    ids=["odd-lambda", "varying-n", "passive", "coordinate-alleviation"],
)
def test_equals_pycma_other_paths(dim, popsize, sizes, rotate, options):
    ours, _, _ = _run_side_by_side(dim, popsize, 200, sizes=sizes, cond=1e4, rotate=rotate, **options)
    if "conditioncov_alleviate" in options:
        assert not np.allclose(ours.scaling, 1.0)  # the alleviation did fire


def test_condition_alleviation_keeps_pycmas_distribution():
    """pycma's 1e12 alleviation re-parametrises x = T g (here forced at condition 1e3):
    compare in the space of x, where pycma's ask samples."""
    dim, popsize = 6, 12
    f = RotatedEllipsoid(dim, cond=1e4, seed=3)
    options = {"conditioncov_alleviate": [1e30, 1e3]}
    ref = _reference_pycma(dim, popsize, np.ones(dim), 0.3, 0, **options)
    ours = CMAES(dim, popsize=popsize, sigma=0.3, weight_decay=0.0, mean=np.ones(dim), cma_options=options)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pycma announces the new geno-pheno transformation
        for g in range(150):
            samples = np.array(ref.ask())
            fx = f(samples)
            ref.tell(list(samples), fx.tolist())
            ours.tell(samples, -fx)
            _pycma_ask_prelude(ref)
            if not ref.gp.isidentity:
                t = ref.gp._tf_matrix
                _close(ours.distribution.mean, t @ ref.mean, f"mean, generation {g + 1}")
                cov = ref.sigma**2 * t @ ref.sm.C @ t.T
                _close(ours.distribution.cov, cov, f"covariance, generation {g + 1}")
                _close(ours.transform, t, f"transform, generation {g + 1}")
    assert ours.transform is not None and not ref.gp.isidentity


def test_strategy_parameters_equal_pycmas():
    for dim in (2, 10, 130):
        for lam in (3, 4, 5, 12, 17, 50, 51, 200):
            es = _reference_pycma(dim, lam, np.zeros(dim), 1.0, 0)
            sp = es.sp
            p = es.sm.parameters(mueff=sp.weights.mueff, lam=sp.weights.lambda_)  # what tell uses
            ours = _Parameters(dim, lam, active=True)
            assert ours.mu == sp.weights.mu
            np.testing.assert_allclose(ours.weights, list(sp.weights), rtol=1e-13, atol=1e-16)
            np.testing.assert_allclose([ours.mueff, ours.cc, ours.c1, ours.cmu], [sp.weights.mueff, sp.cc, p["c1"], p["cmu"]], rtol=1e-14)  # fmt: skip


def test_far_members_are_neither_clipped_nor_reweighted():
    """Members reused by importance mixing can lie far out. pycma's own ask produces such a
    population (through its randn: 4 members at 4x pycma's clipping radius sqrt(d) + 2d/(d+2),
    ranked best); pycma never repairs what it sampled itself. Our tell must give its state."""
    dim, popsize = 10, 20
    f = RotatedEllipsoid(dim, cond=1e2, seed=3)
    ref = _reference_pycma(dim, popsize, np.ones(dim), 0.3, 4)
    ours = CMAES(dim, popsize=popsize, sigma=0.3, weight_decay=0.0, mean=np.ones(dim))
    for _ in range(10):
        samples = np.array(ref.ask())
        ref.tell(list(samples), f(samples).tolist())
        ours.tell(samples, -f(samples))
    rng = np.random.default_rng(5)
    z = rng.standard_normal((popsize, dim))
    radius = np.sqrt(dim) + 2 * dim / (dim + 2)
    z[:4] *= 4 * radius / np.linalg.norm(z[:4], axis=1, keepdims=True)
    ref.sm.randn = lambda n, d: z.copy()
    samples = np.array(ref.ask())
    fitness = -f(samples)
    fitness[:4] = fitness.max() + np.arange(4, 0, -1)
    given = samples.copy()
    ref.tell(list(samples), (-fitness).tolist())
    ours.tell(given, fitness)
    np.testing.assert_array_equal(given, samples)  # our input is not modified
    _assert_same_state(ours, ref, 11)
    # the new mean is the weighted recombination of the unclipped best mu members
    w = np.asarray(ours._params[popsize].weights[:10])
    np.testing.assert_allclose(ours.mean, w @ samples[np.argsort(-fitness)[:10]], rtol=1e-12)


# --------------------------------------------------------------------------- ties
def _tied_population(seed=0, dim=12, n=20):
    """A population after 5 generations and CartPole-like utilities: 9 members tie at the best
    value (straddling nothing), 3 at a middle value across the mu boundary (positions 9-11)."""
    es = CMAES(dim, popsize=n, weight_decay=0.0, mean=np.ones(dim))
    rng = np.random.default_rng(seed)
    for _ in range(5):
        x = es.ask(rng)
        es.tell(x, -sphere(x))
    x = es.ask(rng)
    u = -sphere(x)
    order = np.argsort(-u)
    u[order[:9]] = 10.0
    u[order[9:12]] = 5.0
    return es, x, u


def _state(es):
    return np.concatenate([es.mean, es.C.ravel(), es.p_c, es.p_sigma, [es.step_size]])


def test_tied_members_order_does_not_matter():
    es, x, u = _tied_population()
    ref = CMAES(es.dim, popsize=es.popsize, weight_decay=0.0)
    ref.load_state_dict(es.state_dict())
    es._update(x, u)
    for seed in range(3):
        perm = np.random.default_rng(seed).permutation(x.shape[0])
        other = CMAES(es.dim, popsize=es.popsize, weight_decay=0.0)
        other.load_state_dict(ref.state_dict())
        other._update(x[perm], u[perm])
        np.testing.assert_allclose(_state(other), _state(es), rtol=1e-12, atol=1e-15)


def test_tied_group_gets_its_positions_mean_weight():
    """The new mean is linear in the weights: with fractional ranking it is the average of
    the means over all orders of the tied members -- here two tied members, both orders."""
    es, x, u = _tied_population()
    mu = es._params[es.popsize].mu
    order = np.argsort(-u, kind="stable")
    i, j = order[mu - 1], order[mu]  # make exactly the two members at the mu boundary tie
    u = u.copy()
    u[order[9:12]] = np.array([5.0, 4.0, 3.0])
    assert mu == 10
    u[[i, j]] = 4.5
    means = []
    for first, _second in ((i, j), (j, i)):
        broken = u.copy()
        broken[first] += 1e-9  # a strict order among the two
        trial = CMAES(es.dim, popsize=es.popsize, weight_decay=0.0)
        trial.load_state_dict(es.state_dict())
        trial._update(x, broken)
        means.append(trial.mean)
    es._update(x, u)
    np.testing.assert_allclose(es.mean, np.mean(means, axis=0), rtol=1e-12)
    assert not np.allclose(means[0], means[1])  # the order would have mattered


# --------------------------------------------------------------------------- state
def _to_checkpoint_and_back(state: dict) -> dict:
    """npz for the arrays, JSON for the scalars, as the checkpoint writer does."""
    arrays = {k: v for k, v in state.items() if isinstance(v, np.ndarray)}
    scalars = {k: v for k, v in state.items() if not isinstance(v, np.ndarray)}
    assert set(arrays) | set(scalars) == set(state)
    assert all(type(v) in (int, float, str, bool) for v in scalars.values()), scalars
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    buf.seek(0)
    with np.load(buf, allow_pickle=False) as npz:
        restored = {k: npz[k] for k in npz.files}
    restored.update(json.loads(json.dumps(scalars)))
    return restored


@pytest.mark.parametrize("options", [None, {"conditioncov_alleviate": [5, 10]}], ids=["default", "alleviated"])
def test_state_dict_resume_is_bit_identical(options):
    f = RotatedEllipsoid(8, cond=1e4, seed=1)

    def run(es, rng, generations):
        for _ in range(generations):
            x = es.ask(rng)
            es.tell(x, -f(x))

    def build():
        return CMAES(8, popsize=12, weight_decay=0.01, mean=np.ones(8), cma_options=options)

    es = build()
    run(es, np.random.default_rng(0), 40)
    if options:
        assert es.transform is not None  # the transform is part of the state
    clone = build()
    clone.load_state_dict(_to_checkpoint_and_back(es.state_dict()))
    run(es, np.random.default_rng(1), 30)
    run(clone, np.random.default_rng(1), 30)
    for key, value in es.state_dict().items():
        np.testing.assert_array_equal(clone.state_dict()[key], value, err_msg=key)
    np.testing.assert_array_equal(clone.distribution.cov, es.distribution.cov)
    assert clone.generation == es.generation == 70


def test_load_state_dict_rejects_wrong_shapes():
    state = CMAES(5).state_dict()
    with pytest.raises(ValueError, match="mean_geno.* expected float64\\[6\\]"):
        CMAES(6).load_state_dict(state)


# --------------------------------------------------------------------------- guards
def test_dimension_guard():
    check_dimension(MAX_DIM)  # the limit itself is allowed
    with pytest.raises(ValueError, match=f"{MAX_DIM + 1}.*snes.*openes"):
        CMAES(MAX_DIM + 1)


def test_rejects_unsupported_options():
    with pytest.raises(ValueError, match="CMA_mirrors"):
        CMAES(5, cma_options={"CMA_mirrors": 1})
    assert not CMAES(5, cma_options={"CMA_active": False}).active


def test_fewer_than_mu_members_use_the_parameters_of_that_population_size():
    """n < mu (pycma refuses): one update with lambda = n's weights; popsize's stay."""
    es = CMAES(6, popsize=20, weight_decay=0.0)
    x = es.ask(np.random.default_rng(0))[:5]
    before = es.mean.copy()
    es.tell(x, -sphere(x))
    w = _Parameters(6, 5, True).weights
    np.testing.assert_allclose(es.mean, np.dot(w[:2], x[np.argsort(sphere(x))[:2]]), rtol=1e-12)
    assert not np.allclose(es.mean, before)
    assert es._parameters(20)[0].lam == 20


def test_indefinite_covariance_is_repaired_as_pycma_does():
    """An eigenvalue <= 0 after an update: pycma adds the smallest previous eigenvalue to the
    diagonal (repeatedly, growing) until C is positive definite; so do we."""
    ours = CMAES(4, popsize=8)
    sampler = cma.sampler.GaussFullSampler(4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for c in (ours, sampler):
            c.C[0, 1] = c.C[1, 0] = 5.0  # eigenvalues -4 and 6 in that block: three repairs
        ours._decompose()
        sampler._decompose_C()
    np.testing.assert_allclose(ours.C, sampler.C, rtol=1e-14)
    np.testing.assert_allclose(ours.eigenvalues_sqrt, sampler.D, rtol=1e-13)
    assert ours.eigenvalues_sqrt.min() > 0


# --------------------------------------------------------------- two-point step-size adaptation
def _tpa_run(es, f, generations, rng):
    """The loop imix runs: the probes drawn with the generation, their fresh returns told with it."""
    for _ in range(generations):
        x = es.ask(rng)
        probes = es.probes(rng)
        es.tell(x, f(x), probe_fitness=None if probes is None else f(probes))


def test_tpa_probes_lie_on_the_last_move_of_the_mean_at_a_fresh_draws_length():
    es = CMAES(6, popsize=10, step_size_control="tpa", weight_decay=0.0)
    rng = np.random.default_rng(0)
    assert es.probes(rng) is None  # the mean has not moved yet
    x = es.ask(rng)
    es.tell(x, -np.sum(x**2, axis=1))
    assert es.step_size == es.sigma  # no points were told: sigma stays
    move, mean, cov = es.tpa_move.copy(), es.mean.copy(), es.distribution.cov
    length = np.linalg.norm(np.random.default_rng(5).standard_normal(6))  # the draw probes() makes
    ahead, behind = es.probes(np.random.default_rng(5))
    np.testing.assert_allclose(ahead + behind, 2 * mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose((ahead - mean) / np.linalg.norm(ahead - mean), move / np.linalg.norm(move), atol=1e-12)
    assert math.isclose(float(np.sqrt((ahead - mean) @ np.linalg.solve(cov, ahead - mean))), length, rel_tol=1e-9)


def test_tpa_grows_sigma_on_a_slope_and_shrinks_it_at_an_optimum():
    slope = CMAES(10, popsize=12, step_size_control="tpa", weight_decay=0.0)
    _tpa_run(slope, lambda x: x[:, 0], 60, np.random.default_rng(1))
    assert slope.step_size > 3 * slope.sigma, slope.step_size
    bowl = CMAES(10, popsize=12, sigma=1.0, step_size_control="tpa", weight_decay=0.0)
    _tpa_run(bowl, lambda x: -np.sum(x**2, axis=1), 100, np.random.default_rng(2))
    assert bowl.step_size < 0.05 * bowl.sigma, bowl.step_size


def test_tpa_keeps_sigma_when_the_points_tie():
    """Constant fitness: the two points tie with every member, z = 0 and sigma never moves."""
    es = CMAES(10, popsize=12, step_size_control="tpa", weight_decay=0.0)
    _tpa_run(es, lambda x: np.zeros(len(x)), 50, np.random.default_rng(3))
    assert es.step_size == es.sigma


def test_tpa_does_not_care_about_the_order_of_the_generation():
    rng = np.random.default_rng(4)
    es = CMAES(8, popsize=10, step_size_control="tpa", weight_decay=0.01)
    _tpa_run(es, lambda x: -np.sum(x**2, axis=1), 5, rng)
    other = CMAES(8, popsize=10, step_size_control="tpa", weight_decay=0.01)
    other.load_state_dict(es.state_dict())
    x = es.ask(rng)
    probes = es.probes(rng)
    f, fp = -np.sum(x**2, axis=1), -np.sum(probes**2, axis=1)
    order = rng.permutation(len(x))
    es.tell(x, f, probe_fitness=fp)
    other.tell(x[order], f[order], probe_fitness=fp)
    for key, value in es.state_dict().items():
        np.testing.assert_array_equal(other.state_dict()[key], value, err_msg=key)


def test_tpa_state_resume_is_bit_identical():
    def build():
        return CMAES(8, popsize=12, step_size_control="tpa", weight_decay=0.01, mean=np.ones(8))

    f = RotatedEllipsoid(8, cond=1e3, seed=1)
    es = build()
    _tpa_run(es, lambda x: -f(x), 30, np.random.default_rng(0))
    clone = build()
    clone.load_state_dict(_to_checkpoint_and_back(es.state_dict()))
    _tpa_run(es, lambda x: -f(x), 20, np.random.default_rng(1))
    _tpa_run(clone, lambda x: -f(x), 20, np.random.default_rng(1))
    for key, value in es.state_dict().items():
        np.testing.assert_array_equal(clone.state_dict()[key], value, err_msg=key)
    with pytest.raises(ValueError, match="tpa_move"):
        build().load_state_dict(CMAES(8, popsize=12).state_dict())  # a CSA state has no TPA state


def test_probe_returns_are_checked():
    x = np.zeros((12, 8))
    with pytest.raises(ValueError, match="probe_fitness"):
        CMAES(8, popsize=12).tell(x, np.zeros(12), probe_fitness=[0.0, 1.0])  # CSA takes no probes
    with pytest.raises(ValueError, match="probe_fitness"):
        CMAES(8, popsize=12, step_size_control="tpa").tell(x, np.zeros(12), probe_fitness=[0.0])
    with pytest.raises(ValueError, match="step_size_control"):
        CMAES(8, step_size_control="auto")  # resolved by imix run, not by the class
