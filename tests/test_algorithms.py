"""Tests of the four evolution strategies (imix_cli.core.algorithms).

* API contract, looped over every entry of ALGORITHMS.
* Optimisation on sphere / rotated ellipsoid / Rastrigin (maximising -f, weight_decay=0):
  every threshold below is stated with its starting value and budget and was chosen with
  a margin of >= 2x over the worst of 5 seeds observed when writing the test.
* CMA-ES against pycma, ties and checkpoints: tests/test_cmaes.py.

The test functions live in tests/objectives.py.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from objectives import RotatedEllipsoid, rastrigin, sphere

from imix_cli.core.algorithms import ALGORITHMS, CEM, CMAES, SNES, EvolutionStrategy, OpenES, make_es
from imix_cli.core.distributions import DiagonalGaussian, FullGaussian

DIM = 8
POPSIZE = 20
EXPECTED_DISTRIBUTION = {"openes": DiagonalGaussian, "snes": DiagonalGaussian, "cem": DiagonalGaussian, "cmaes": FullGaussian}


def build(name: str, dim: int = DIM, popsize: int = POPSIZE, **kwargs) -> EvolutionStrategy:
    return make_es(name, dim, popsize=popsize, mean=np.linspace(-1.0, 1.0, dim), **kwargs)


def run_generations(es: EvolutionStrategy, rng: np.random.Generator, generations: int, objective=sphere):
    for _ in range(generations):
        samples = es.ask(rng)
        es.tell(samples, -objective(samples))
    return es


def state(es: EvolutionStrategy):
    """Everything that defines the next generation: the distribution's mean and covariance."""
    dist = es.distribution
    cov = dist.cov if isinstance(dist, FullGaussian) else dist.std
    return np.concatenate([dist.mean, np.ravel(cov)])


# --------------------------------------------------------------------------- registry
def _es_classes_of_the_package() -> dict:
    """Every concrete EvolutionStrategy class the modules of imix_cli.core.algorithms define, by its name (found by
    walking the package, not by asking the registry)."""
    import importlib
    import inspect
    import pkgutil

    import imix_cli.core.algorithms as package

    found = {}
    for info in pkgutil.iter_modules(package.__path__):
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        for _, cls in inspect.getmembers(module, inspect.isclass):
            if issubclass(cls, EvolutionStrategy) and not inspect.isabstract(cls) and cls.__module__ == module.__name__:
                found[cls.name] = cls
    return found


def test_registry_and_make_es():
    """make_es reaches every ES the package defines, under its own name; ALGORITHMS holds those whose members are
    independent draws (the paper's four), MIRRORED_ALGORITHMS those of another generation scheme (ARS)."""
    from imix_cli.core.algorithms import MIRRORED_ALGORITHMS

    classes = _es_classes_of_the_package()
    assert {OpenES, SNES, CEM, CMAES} <= set(classes.values())
    assert {**ALGORITHMS, **MIRRORED_ALGORITHMS} == classes
    assert {name for name, cls in classes.items() if cls.generation_scheme is None} == set(ALGORITHMS)
    for name, cls in classes.items():
        es = make_es(name, 5, popsize=10)
        assert type(es) is cls and es.name == name and es.dim == 5
    with pytest.raises(ValueError, match=".*".join(sorted(classes))):
        make_es("pepg", 5)


# --------------------------------------------------------------------------- API contract
@pytest.mark.parametrize("name", sorted(ALGORITHMS))
def test_api_contract(name):
    rng = np.random.default_rng(1)
    es = build(name)

    # distribution type and shape
    dist = es.distribution
    assert isinstance(dist, EXPECTED_DISTRIBUTION[name])
    assert dist.dim == DIM and dist.mean.shape == (DIM,)
    np.testing.assert_allclose(dist.mean, np.linspace(-1.0, 1.0, DIM))
    np.testing.assert_allclose(dist.std, 0.25, rtol=1e-3)  # sigma^2 I (pycma: C0 off I by < 1e-4)

    # ask shape
    samples = es.ask(rng)
    assert samples.shape == (POPSIZE, DIM) and np.all(np.isfinite(samples))
    assert es.generation == 0

    # tell accepts samples that ask never produced (another rng, hand-made points)
    foreign = es.distribution.sample(POPSIZE, np.random.default_rng(99))
    foreign[0] = es.mean + 3.0 * es.distribution.std  # a legitimate but unlikely member
    foreign[1] = es.mean
    es.tell(foreign, -sphere(foreign))
    assert es.generation == 1
    assert not np.allclose(es.mean, np.linspace(-1.0, 1.0, DIM))  # it moved

    # the generation counter counts tells
    run_generations(es, rng, 3)
    assert es.generation == 4

    # non-finite fitness: no crash, counted, distribution stays finite
    samples = es.ask(rng)
    fitness = -sphere(samples)
    fitness[[0, 3, 5]] = [np.nan, np.inf, -np.inf]
    es.tell(samples, fitness)
    assert es.nonfinite_fitness_count == 3 and es.generation == 5
    assert np.all(np.isfinite(state(es)))

    # tell with another number of rows than popsize (fewer than CMA-ES's mu, a few less, more)
    for n in (3, POPSIZE - 7, POPSIZE + 5):
        samples = es.distribution.sample(n, rng)
        before = es.generation
        es.tell(samples, -sphere(samples))
        assert es.generation == before + 1
        assert np.all(np.isfinite(state(es)))
    assert es.ask(rng).shape == (POPSIZE, DIM)  # ask still returns popsize rows


@pytest.mark.parametrize("name", sorted(ALGORITHMS))
def test_deterministic_given_seed(name):
    a = run_generations(build(name), np.random.default_rng(7), 15)
    b = run_generations(build(name), np.random.default_rng(7), 15)
    np.testing.assert_array_equal(state(a), state(b))
    c = run_generations(build(name), np.random.default_rng(8), 15)
    assert not np.array_equal(state(a), state(c))  # the seed matters


@pytest.mark.parametrize("name", sorted(ALGORITHMS))
def test_pickle_round_trip_continues_identically(name):
    es = run_generations(build(name), np.random.default_rng(3), 5)
    clone = pickle.loads(pickle.dumps(es))
    assert clone.generation == es.generation
    np.testing.assert_array_equal(state(clone), state(es))
    run_generations(es, np.random.default_rng(11), 10)
    run_generations(clone, np.random.default_rng(11), 10)
    np.testing.assert_array_equal(state(clone), state(es))
    assert clone.generation == es.generation == 15


@pytest.mark.parametrize("name", sorted(ALGORITHMS))
def test_weight_decay_forms_run(name):
    for form in ("paper", "estool"):
        es = run_generations(build(name, weight_decay=0.05, weight_decay_form=form), np.random.default_rng(0), 5)
        assert np.all(np.isfinite(state(es)))


def test_two_rows():
    """The base class accepts n >= 2; CMA-ES needs 3 (as pycma) and says so."""
    rng = np.random.default_rng(0)
    for name in ("openes", "snes", "cem"):
        es = build(name)
        samples = es.distribution.sample(2, rng)
        es.tell(samples, -sphere(samples))
        assert es.generation == 1 and np.all(np.isfinite(state(es)))
    es = build("cmaes")
    samples = es.distribution.sample(2, rng)
    with pytest.raises(ValueError, match="at least 3 samples"):
        es.tell(samples, -sphere(samples))


# --------------------------------------------------------------------------- optimisation
# (name, objective, d, x0, sigma, generations, threshold on f(final mean), why)
ELL20 = RotatedEllipsoid(20, cond=1e3, seed=1)  # f(ones) = 4.34e3
OPTIMISATION_CASES = [
    # sphere, d = 100, from f(ones) = 100, sigma 0.25.
    # OpenES cannot beat its fixed sigma: 5 seeds ended in 0.11-0.15 after 800 generations.
    ("openes", "sphere", 100, 1.0, 0.25, 800, 0.5),
    # SNES shrinks sigma (to ~0.015) and ends 10x lower: 0.013-0.018 (5 seeds).
    ("snes", "sphere", 100, 1.0, 0.25, 800, 0.05),
    # CEM: 300 generations end at 1.3e-3-1.7e-3 (extra-variance floor 1e-5 -> noise level).
    ("cem", "sphere", 100, 1.0, 0.25, 300, 5e-3),
    # CMA-ES (d = 20 to keep the O(d^3) tells cheap): 2e-6 after 150 generations (worst of 5).
    ("cmaes", "sphere", 20, 1.0, 0.25, 150, 1e-4),
    # rotated ellipsoid, d = 20, condition 1e3, from 4.34e3: observed worst of 5 seeds
    # OpenES 6.2 (1500 gen.), SNES 1.9 (1500), CEM 7.6 (300), CMA-ES 4.9e-10 (300: C learns R).
    ("openes", "ellipsoid", 20, 1.0, 0.25, 1500, 20.0),
    ("snes", "ellipsoid", 20, 1.0, 0.25, 1500, 5.0),
    ("cem", "ellipsoid", 20, 1.0, 0.25, 300, 20.0),
    ("cmaes", "ellipsoid", 20, 1.0, 0.25, 300, 1e-6),
    # Rastrigin, d = 10, from x0 = 2.5 (every coordinate on a local maximum), f = 262.5,
    # sigma 1. Worst of 5 seeds: OpenES 21 (1000 gen.), SNES 24.5 (1000), CEM 6 (300),
    # CMA-ES 5 (300); the global structure is found, the last local minima are not.
    ("openes", "rastrigin", 10, 2.5, 1.0, 1000, 50.0),
    ("snes", "rastrigin", 10, 2.5, 1.0, 1000, 50.0),
    ("cem", "rastrigin", 10, 2.5, 1.0, 300, 20.0),
    ("cmaes", "rastrigin", 10, 2.5, 1.0, 300, 20.0),
]
OBJECTIVES = {"sphere": sphere, "ellipsoid": ELL20, "rastrigin": rastrigin}


@pytest.mark.parametrize(
    "name, objective, dim, x0, sigma, generations, threshold",
    OPTIMISATION_CASES,
    ids=[f"{c[0]}-{c[1]}{c[2]}" for c in OPTIMISATION_CASES],
)
def test_optimisation(name, objective, dim, x0, sigma, generations, threshold):
    f = OBJECTIVES[objective]
    es = make_es(name, dim, popsize=50, sigma=sigma, weight_decay=0.0, mean=np.full(dim, x0))
    f0 = f(es.mean)[0]
    run_generations(es, np.random.default_rng(2024), generations, f)
    f_final = f(es.mean)[0]
    assert f_final < threshold, f"{name} on {objective}{dim}: f {f0:.4g} -> {f_final:.4g}, wanted < {threshold}"
    std = es.distribution.std
    assert np.all(std > 1e-12) and np.all(std < 10 * sigma)  # no collapse, no explosion


def test_snes_adapts_each_coordinate():
    """On an axis-aligned ellipsoid (d = 10, condition 1e3, axis ratio 31.6) SNES's sigma
    must follow the curvature: 3 seeds gave sigma_flattest / sigma_steepest = 24-25 and a
    monotone profile after 1000 generations. Require > 8 and a strong rank correlation."""
    f = RotatedEllipsoid(10, cond=1e3, rotate=False)
    es = SNES(10, popsize=50, weight_decay=0.0, mean=np.ones(10))
    run_generations(es, np.random.default_rng(5), 1000, f)
    log_std = np.log(es.distribution.std)
    assert log_std[0] - log_std[-1] > np.log(8.0)
    assert np.corrcoef(log_std, np.log(f.scales))[0, 1] < -0.9
    assert f(es.mean)[0] < 1.0  # from f(ones) = 2.1e3; observed 0.05-0.07


def test_cem_extra_variance_schedule():
    """eps_t = floor + (eps_0 - floor) * tau^t, eps_0 = sigma^2: with a single elite
    (elite_fraction -> K = 1) the new variance is exactly eps_t."""
    es = CEM(4, popsize=4, sigma=0.5, weight_decay=0.0, elite_fraction=0.25)
    rng = np.random.default_rng(0)
    for t in range(1, 31):
        samples = es.ask(rng)
        fitness = -sphere(samples)
        es.tell(samples, fitness)
        expected = 1e-5 + (0.25 - 1e-5) * 0.95**t
        np.testing.assert_allclose(es.distribution.std**2, expected, rtol=1e-12)
        np.testing.assert_array_equal(es.mean, samples[np.argmax(fitness)])
