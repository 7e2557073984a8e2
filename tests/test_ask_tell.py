"""The ask/tell mixing wrapper (imix_cli.MixingES) and the Python entry point imix_cli.run.

The wrapper must be the runner's generation step, not a second implementation: for a fixed seed
it gives exactly the rows ``imix run`` writes (same members asked, same stored returns, same
updates), for each of the four ES, and it adds mixing to a plain ask/tell loop in one line."""

import numpy as np
import pytest

import imix_cli
from imix_cli.core.algorithms import make_es
from imix_cli.core.evaluation import make_evaluator
from imix_cli.core.mixing.ask_tell import MixingES

GENERATIONS = 6


@pytest.fixture(scope="module")
def cartpole():
    return make_evaluator("cartpole")


@pytest.mark.parametrize("algo", ["openes", "snes", "cem", "cmaes"])
def test_the_wrapper_gives_the_runners_rows_for_every_es(algo, cartpole, tmp_path):
    frame = imix_cli.run(algo=algo, env="cartpole", eim=True, seeds=1, generations=GENERATIONS, workers=1, eval_mean_every=0,
                         checkpoint_every=0, results_dir=str(tmp_path), experiment="same", echo=None)  # fmt: skip
    # The runner's streams for seed 0 (imix_cli.running.loop.lockstep.new_seed_state): one for mixing, one for episode seeds.
    sample_seq, episode_seq = np.random.SeedSequence(0).spawn(2)
    episode_rng = np.random.default_rng(episode_seq)
    options = {"step_size_control": "tpa"} if algo == "cmaes" else {}  # what imix run's algo.step_size_control=auto picks with mixing
    es = imix_cli.MixingES(imix_cli.make_es(algo, cartpole.num_params, **options), "exact", rng=np.random.default_rng(sample_seq))
    for g in range(GENERATIONS):
        row = frame.iloc[g]
        assert es.distribution.sigma_mean == pytest.approx(row["sigma_mean"], rel=1e-9)  # the same updates so far (the CSV keeps 10 digits)
        x = es.ask()
        returns, _ = cartpole.evaluate(x, episode_rng.integers(0, np.iinfo(np.int64).max, size=len(x), dtype=np.int64))
        fitness = es.tell(x, returns)
        assert (es.evaluations, es.reused) == (row["evaluations"], frame["reused"].iloc[: g + 1].sum())
        assert np.mean(fitness) == pytest.approx(row["mean_score"], rel=1e-9)
    assert frame["reused"].sum() > 0  # mixing did reuse members, so the stored returns were exercised


def quadratic(x):
    return -np.sum((x - 2.0) ** 2, axis=1)


@pytest.mark.parametrize("algo", ["openes", "snes", "cem", "cmaes"])
def test_one_line_adds_mixing_to_a_plain_loop(algo):
    """The plain loop and the mixing loop differ in the line that builds the ES; mixing reaches the
    same neighbourhood of the optimum with fewer evaluations on a smooth objective."""
    results = {}
    for mixing in (None, "exact"):
        es = imix_cli.make_es(algo, 5, popsize=20, sigma=0.5, lr=0.1, weight_decay=0.0)
        es = imix_cli.MixingES(es, mixing, rng=1)  # the one line that adds mixing (None: the plain ES)
        for _ in range(30):
            x = es.ask()
            es.tell(x, quadratic(x))
        results[mixing] = (es.evaluations, float(quadratic(es.distribution.mean[None])[0]))
    plain, mixed = results[None], results["exact"]
    assert plain[0] == 30 * 20  # no mixing: every member evaluated
    assert mixed[0] < plain[0]  # mixing evaluated fewer members
    assert mixed[1] > -4.0 * 5 / 2  # and still moved from the origin (fitness -20) towards the optimum


def test_without_mixing_the_wrapper_is_the_plain_es():
    plain = imix_cli.make_es("snes", 4, popsize=10)
    wrapped = imix_cli.MixingES(imix_cli.make_es("snes", 4, popsize=10), None, rng=3)
    rng = np.random.default_rng(3)
    for _ in range(5):
        x = plain.ask(rng)
        plain.tell(x, quadratic(x))
        y = wrapped.ask()
        np.testing.assert_array_equal(x, y)
        wrapped.tell(quadratic(y))  # tell(returns) alone
    np.testing.assert_array_equal(plain.distribution.mean, wrapped.distribution.mean)


def test_misuse_is_one_clear_error():
    es = imix_cli.MixingES(imix_cli.make_es("cem", 3, popsize=6), rng=0)
    with pytest.raises(RuntimeError, match="before ask"):
        es.tell(np.zeros(6))
    x = es.ask()
    with pytest.raises(RuntimeError, match="twice"):
        es.ask()
    with pytest.raises(ValueError, match="returns for the"):
        es.tell(np.zeros(len(x) + 1))
    with pytest.raises(ValueError, match="not one of the points ask"):
        es.tell(x + 1.0, np.zeros(len(x)))


def test_run_returns_the_csv_rows_and_a_sweep_has_one_run_per_point(tmp_path):
    frame = imix_cli.run("popsize=10,12", algo="cem", env="cartpole", eim=True, seeds=2, generations=3, workers=1,
                         results_dir=str(tmp_path), experiment="api", echo=None)  # fmt: skip
    assert sorted(frame["run"].unique()) == ["cem-cartpole-eim-popsize=10", "cem-cartpole-eim-popsize=12"]
    assert len(frame) == 2 * 2 * 3
    on_disk = imix_cli.Experiment(algo="cem", env="cartpole", eim=True, seeds=2, generations=3, popsize=10, results_dir=str(tmp_path), experiment="api")
    from imix_cli.running.files.results import read_run_csv

    csv = read_run_csv(on_disk.run_dirs[0] / "seed_1.csv")
    mine = frame[(frame["run"] == "cem-cartpole-eim-popsize=10") & (frame["seed"] == 1)].drop(columns="run").reset_index(drop=True)
    assert mine.equals(csv)


def test_run_refuses_a_bad_key_with_the_cli_message(tmp_path):
    with pytest.raises(imix_cli.ConfigError, match="popsize"):
        imix_cli.run(algo="cem", popsize=1, results_dir=str(tmp_path))


def test_single_policy_helpers_match_the_batched_forward():
    from imix_cli.core.evaluation.policies import forward, num_params

    rng = np.random.default_rng(0)
    params = rng.normal(size=num_params(4, 2))
    obs = rng.normal(size=(7, 4))
    batched = forward(np.repeat(params[None], 7, axis=0), obs, 2)
    np.testing.assert_array_equal(imix_cli.policy_output(params, obs, 2), batched)
    np.testing.assert_array_equal(imix_cli.policy_output(params, obs[3], 2), batched[3])
    assert imix_cli.policy_action(params, obs[3], 2) == int(np.argmax(batched[3]))
    with pytest.raises(ValueError, match=r"\(d,\)"):
        imix_cli.policy_output(params[None], obs, 2)


@pytest.mark.parametrize("algo", ["cem", "pycma"])
def test_tell_takes_the_pairs_in_any_order_as_pycmas_tell_does(algo):
    """Issue 47, case 8: ``tell(x, f)`` refused a population told in another order than asked; pycma's tell takes
    the pairs (x, f) in any order. The pairs are matched to the asked points: the ES ends in the same state as
    told in order, and a point never asked is refused in one line."""
    import copy

    if algo == "pycma":
        cma = pytest.importorskip("cma")
        es = cma.CMAEvolutionStrategy(5 * [1.0], 0.5, {"seed": 1, "verbose": -9})
    else:
        es = make_es("cem", dim=5, popsize=12)
    m = MixingES(es, "exact", rng=1)
    for _ in range(5):
        x = m.ask()
        m.tell(x, -np.sum(x * x, axis=1))
    a, b = copy.deepcopy(m), copy.deepcopy(m)
    x = a.ask()
    assert np.array_equal(x, b.ask())
    f = -np.sum(x * x, axis=1)
    perm = np.random.default_rng(0).permutation(len(f))
    a.tell(x, f)
    b.tell(x[perm], f[perm])
    np.testing.assert_array_equal(a.distribution.mean, b.distribution.mean)
    c = copy.deepcopy(m)
    x = c.ask()
    with pytest.raises(ValueError, match=r"samples\[0\] is not one of the points ask\(\) returned"):
        c.tell(x + 1.0, f)


@pytest.mark.parametrize("bad", [None, "1.5", 1j], ids=["None", "str", "complex"])
def test_tell_refuses_returns_that_are_not_real_numbers_in_one_line(bad):
    """Issue 47, case 7: ``tell(x, [None] * n)`` was told as all-NaN without a word, "1.5" was accepted and complex
    values only warned; the CLI refuses a string reward. One line naming the first bad value, nothing told."""
    m = MixingES(make_es("cem", dim=3, popsize=8), "exact", rng=0)
    x = m.ask()
    before = m.distribution.mean.copy()
    with pytest.raises(TypeError, match=r"returns\[0\] = .* is not a real number"):
        m.tell(x, [bad] * len(x))
    np.testing.assert_array_equal(m.distribution.mean, before)
