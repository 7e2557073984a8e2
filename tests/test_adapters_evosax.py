"""Importance mixing for evosax (imix_cli.core.adapters.evosax): the guarantees of imix's own ES, on evosax's.

* the distribution the adapter reads is the one evosax's own ``ask`` samples from (SNES, Open_ES,
  CMA_ES, Sep_CMA_ES), and evosax's update is what is applied (the adapter's tell is evosax's tell);
* along evosax's own path of states, hundreds of generations mixed through MixingES are distributed
  as evosax's distribution of each generation (the chain statistic of tests/test_mixing.py);
* evosax's update ignores the order of its population (without ties), through the adapter too;
* Open_ES's antithetic pairs are mixed as mirrored pairs (anchors mixed, mirrors fresh);
* no fixed point: MixingES's minimal refresh (``min_fresh``) evaluates a member of every generation;
* ``reeval_count`` is there; the state, archive included, is data: saved and loaded, a run goes on
  exactly as without the interruption.
"""

import numpy as np
import pytest
from adapter_chains import chain_z_scores, whiten
from conftest import extra_installed  # noqa: E402

pytestmark = pytest.mark.peers  # jax and evosax (the peers extra: evosax's own extra has no gymnax, these tests need none)

if extra_installed("peers"):  # collected, and skipped by the marker, without them
    import evosax.algorithms as evosax_algorithms
    import jax
    import jax.numpy as jnp

import imix_cli  # noqa: E402
from imix_cli.core.adapters.evosax import from_evosax, snes_for_mixing  # noqa: E402
from imix_cli.running.files.mixing_checkpoint import load_mixing, save_mixing  # noqa: E402

ALGORITHMS = {
    "SNES": lambda n, d: evosax_algorithms.SNES(population_size=n, solution=jnp.zeros(d)),
    "Open_ES": lambda n, d: evosax_algorithms.Open_ES(population_size=n, solution=jnp.zeros(d), use_antithetic_sampling=False),
    "CMA_ES": lambda n, d: evosax_algorithms.CMA_ES(population_size=n, solution=jnp.zeros(d)),
    "Sep_CMA_ES": lambda n, d: evosax_algorithms.Sep_CMA_ES(population_size=n, solution=jnp.zeros(d)),
}


def sphere(x):
    return np.sum((np.asarray(x, dtype=np.float64) - 0.5) ** 2, axis=1)


_BUILT = {}


def _algorithm(name, n, d):
    """One algorithm object per (name, n, d): evosax jits ask/tell per object, so reusing it compiles once."""
    if (name, n, d) not in _BUILT:
        _BUILT[name, n, d] = ALGORITHMS[name](n, d)
    return _BUILT[name, n, d]


def _mixing(name, n=16, d=5, seed=0, **kw):
    algorithm = _algorithm(name, n, d)
    return imix_cli.MixingES(from_evosax(algorithm, algorithm.default_params, jax.random.key(seed), mean=jnp.ones(d)), "exact", rng=seed, **kw)


def _advance(m, generations):
    for _ in range(generations):
        x = m.ask()
        m.tell(x, sphere(x))
    return m


@pytest.mark.parametrize("name", list(ALGORITHMS))
def test_the_distribution_read_is_the_one_evosax_samples_from(name):
    """After 15 generations with mixing: 256 of evosax's own asks (4,096 points), whitened by the
    adapter's distribution: mean 0, covariance I within 6 standard errors."""
    m = _advance(_mixing(name), 15)
    es = m.es
    state = es.state
    keys = jax.random.split(jax.random.key(7), 256)
    population = np.concatenate([np.asarray(es.algorithm.ask(k, state, es.params)[0]) for k in keys])  # compiled once, by the adapter
    z = whiten(es.distribution, population)
    n = z.shape[0]
    assert np.max(np.abs(z.mean(axis=0))) < 6 / np.sqrt(n), z.mean(axis=0)
    assert np.max(np.abs(np.cov(z.T) - np.eye(es.dim))) < 6 * np.sqrt(2 / n), np.cov(z.T)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["SNES", "CMA_ES"])
def test_mixed_generations_along_evosaxs_path_are_distributed_as_its_distributions(name):
    """20 chains of 120 generations, each mixed by MixingES along one evosax run's own states (so
    the path does not depend on the mixed members); members whitened by the distribution of their
    generation. Per chain the mean of z and of z^2; across chains their z-scores (< 4)."""
    generations, chains, burn_in = 120, 20, 10
    m = _mixing(name, seed=3)
    algorithm, params, es = m.es.algorithm, m.es.params, m.es
    path, state, key = [], es.state, jax.random.key(11)
    for _ in range(generations):  # evosax's own run: its ask, its tell
        path.append(state)
        key, k_ask, k_tell = jax.random.split(key, 3)
        population, asked = algorithm.ask(k_ask, state, params)
        state, _ = algorithm.tell(k_tell, population, jnp.asarray(sphere(population)), asked, params)
    per_chain, reused = [], 0
    for chain in range(chains):
        m = _mixing(name, seed=3)
        m.rng = np.random.default_rng(chain)
        m.es.tell = lambda samples, fitness: None  # the path is evosax's own run: its next state is set below
        zs = []
        for t in range(generations):
            m.es.state, m.es._asked = path[t], None
            x = m.ask()
            if t >= burn_in:
                zs.append(whiten(m.es.distribution, m.generation.samples))
                reused += m.generation.reused
            m.tell(x, sphere(x))
        per_chain.append(np.concatenate(zs))
    z_mean, z_var, second = chain_z_scores(per_chain)
    assert reused > 0.2 * chains * (generations - burn_in) * 16, "the chains must reuse"
    assert abs(z_mean) < 4 and abs(z_var) < 4, (z_mean, z_var, second)


@pytest.mark.parametrize("name", list(ALGORITHMS))
def test_evosaxs_update_through_the_adapter_is_evosaxs_and_ignores_the_order(name):
    m = _advance(_mixing(name), 5)
    es = m.es
    x = es.ask(np.random.default_rng(0))
    f = sphere(x)
    perm = np.random.default_rng(1).permutation(len(f))
    asked_state, _ = es._prepared()
    key = es.key
    # evosax's own tell of the same population, with the key the adapter will split
    _, k_tell = jax.random.split(key)
    expected, _ = es.algorithm.tell(k_tell, jnp.asarray(x, jnp.float32), jnp.asarray(f, jnp.float32), asked_state, es.params)
    saved = es.state_dict()
    es.tell(x[perm], f[perm])
    permuted = np.max(np.abs(np.asarray(es.state.mean, dtype=np.float64) - np.asarray(expected.mean)))
    es.load_state_dict(saved)
    es.tell(x, f[perm])  # the power: values given to the wrong members
    wrong = np.max(np.abs(np.asarray(es.state.mean, dtype=np.float64) - np.asarray(expected.mean)))
    assert permuted <= 1e-6 * max(1.0, float(np.max(np.abs(x)))), permuted  # float32 round-off of a reordered sum
    assert wrong > 30 * max(permuted, 1e-7), (wrong, permuted)


def test_open_es_antithetic_pairs_are_mixed_as_mirrored_pairs():
    algorithm = evosax_algorithms.Open_ES(population_size=20, solution=jnp.zeros(4))
    m = imix_cli.MixingES(from_evosax(algorithm, algorithm.default_params, jax.random.key(0)), "exact", rng=0)
    reused = 0
    for _ in range(30):
        x = m.ask()
        g = m.generation
        mean = m.es.distribution.mean
        np.testing.assert_allclose(g.samples[:10] + g.samples[10:], np.tile(2 * mean, (10, 1)), atol=1e-9)  # pairs around the mean
        assert np.all(g.source[10:] == 0), "mirrors are always fresh"
        reused += g.reused
        m.tell(x, sphere(x))
    assert reused > 0


def test_a_fully_reused_generation_would_not_repeat_the_update_and_is_refreshed():
    """Open_ES at its default learning rate (1e-3) barely moves: whole generations are reused and
    told again. MixingES's default must not let more than 3 consecutive generations go without a
    fresh evaluation (measured without the rule: 190 of 200 generations in a row)."""
    m = _mixing("Open_ES", n=20, d=10)
    run = longest = 0
    for _ in range(60):
        x = m.ask()
        m.tell(x, sphere(x))
        run = run + 1 if x.shape[0] == 0 else 0
        longest = max(longest, run)
    assert longest <= 3, f"{longest} consecutive generations without a fresh evaluation"


def test_reeval_count_re_measures_reused_members():
    m = _mixing("SNES", reeval_count=2)
    reevaluated = 0
    for _ in range(20):
        x = m.ask()
        reevaluated += m.plan.reevaluated
        m.tell(x, sphere(x))
    assert reevaluated >= 2 * 15


@pytest.mark.parametrize("name", ["SNES", "CMA_ES"])
def test_state_and_archive_are_data_and_a_loaded_run_goes_on_exactly(name, tmp_path):
    straight = _advance(_mixing(name, seed=4), 12)
    first = _advance(_mixing(name, seed=4), 6)
    save_mixing(tmp_path / "m.npz", first)
    raw = np.load(tmp_path / "m.npz", allow_pickle=False)  # plain arrays: nothing to unpickle
    assert any(k.startswith("archive/") for k in raw.files) and any("state" in k for k in raw.files)
    resumed = load_mixing(tmp_path / "m.npz", _mixing(name, seed=99))
    _advance(resumed, 6)
    np.testing.assert_array_equal(np.asarray(resumed.es.state.mean), np.asarray(straight.es.state.mean))
    assert resumed.evaluations == straight.evaluations
    np.testing.assert_array_equal(resumed.ask(), straight.ask())


def test_snes_for_mixing_keeps_consecutive_distributions_overlapping():
    """snes_for_mixing's step sizes are what make mixing pay with evosax's SNES (docs/adapters.md): on a
    10-d sphere (popsize 16, 40 generations, 2 seeds) MixingES reuses more than 70 % of the members,
    where evosax's defaults (a whole natural-gradient step per generation) reuse about half."""

    def reuse(algorithm, params, seed):
        m = imix_cli.MixingES(from_evosax(algorithm, params, jax.random.key(seed), mean=jnp.ones(10)), "exact", rng=seed)
        return _advance(m, 40).reuse

    algorithm, params = snes_for_mixing(16, jnp.zeros(10), std_init=0.25)
    default = evosax_algorithms.SNES(population_size=16, solution=jnp.zeros(10))
    for seed in (0, 1):
        assert reuse(algorithm, params, seed) > 0.7
        assert reuse(default, default.default_params.replace(std_init=jnp.asarray(0.25)), seed) < 0.6


def test_an_algorithm_without_an_adapter_is_refused_in_one_line():
    algorithm = evosax_algorithms.PGPE(population_size=8, solution=jnp.zeros(3))
    with pytest.raises(ValueError) as err:
        from_evosax(algorithm, algorithm.default_params, jax.random.key(0))
    assert "\n" not in str(err.value) and "PGPE" in str(err.value)
    with pytest.raises(TypeError, match="from_evosax"):
        imix_cli.MixingES(algorithm, "exact")
