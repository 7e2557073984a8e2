"""evaluator=pool|ray: the same returns, steps and observation statistics as the local
evaluator, bit for bit, whatever the worker count and chunking; runs that differ only in
the evaluator write identical CSVs (wall time aside)."""

import numpy as np
import pytest

from imix_cli.commands.cli import main
from imix_cli.core.evaluation import make_evaluator
from imix_cli.core.evaluation.parallel import PoolEvaluator, RayEvaluator
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.files.results import read_run_csv

# CartPole-v1 through the generic path: episodes of very different lengths, cheap to run.
ENV = "CartPole-v1"


def _batch(ev, n=23, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(0.0, 1.0, (n, ev.num_params)), rng.integers(0, 2**62, n)


@pytest.mark.slow  # (make test-fast: test_runs_with_local_and_pool_evaluators_write_identical_csvs)
def test_pool_with_1_and_2_workers_equals_local_bit_for_bit():
    local = make_evaluator(ENV, hidden=(4,))
    params, seeds = _batch(local)
    expected = local.evaluate(params, seeds)
    sums, sumsqs = local.last_obs_stats
    assert len(set(expected[1].tolist())) > 3  # episodes of many lengths: chunks finish at different times
    for workers in (1, 2):
        pool = PoolEvaluator(ENV, hidden=(4,), workers=workers)
        try:
            assert pool.num_params == local.num_params and pool.hidden == (4,)
            for chunks_per_worker in (1, 4):
                pool.chunks_per_worker = chunks_per_worker
                returns, steps = pool.evaluate(params, seeds)
                np.testing.assert_array_equal(returns, expected[0])
                np.testing.assert_array_equal(steps, expected[1])
                np.testing.assert_array_equal(pool.last_obs_stats[0], sums)
                np.testing.assert_array_equal(pool.last_obs_stats[1], sumsqs)
            assert [a.size for a in pool.evaluate(params[:0], seeds[:0])] == [0, 0]
            with pytest.raises(ValueError, match="episode seeds"):
                pool.evaluate(params, seeds[:-1])
        finally:
            pool.close()


def test_runs_with_local_and_pool_evaluators_write_identical_csvs(tmp_path):
    common = ["env=gym", f"env.id={ENV}", "algo=snes", "eim=true", "seeds=2", "generations=4", "popsize=8", "progress=false", "policy.hidden=[4]"]
    frames = {}
    for evaluator in ("local", "pool"):
        extra = ["workers=1"] if evaluator == "local" else ["evaluator_workers=2"]
        assert main(["run", *common, f"evaluator={evaluator}", *extra, f"results_dir={tmp_path}", f"experiment={evaluator}"]) == 0
        run = tmp_path / evaluator / f"snes-{ENV}-eim-hidden=4,popsize=8"
        frames[evaluator] = [read_run_csv(run / f"seed_{k}.csv").drop(columns="wall_time") for k in (0, 1)]
    for a, b in zip(frames["local"], frames["pool"]):
        assert a.equals(b)
    assert frames["local"][0]["reused"].sum() > 0


def test_pool_runs_the_seeds_in_one_process():
    (spec,) = validate_overrides(["env=gym", f"env.id={ENV}", "evaluator=pool"])
    assert spec.workers == 1 and spec.evaluator_workers >= 1
    with pytest.raises(Exception, match="evaluator=pool"):
        validate_overrides(["env=gym", f"env.id={ENV}", "evaluator=pool", "workers=2"])
    (spec,) = validate_overrides(["env=gym", f"env.id={ENV}", "evaluator=pool", "workers=1", "evaluator_workers=3"])
    assert spec.evaluator_workers == 3
    # where episodes run does not change results: not part of the run's identity
    assert spec.identity() == validate_overrides(["env=gym", f"env.id={ENV}", "workers=1"])[0].identity()


@pytest.mark.parametrize(
    "override, key",
    [("evaluator=gpu", "evaluator"), ("evaluator_workers=0", "evaluator_workers"), ("ray_address=auto", "ray_address")],
)
def test_bad_evaluator_keys_are_one_line_errors(tmp_path, capsys, override, key):
    assert main(["run", "env=gym", f"env.id={ENV}", override, f"results_dir={tmp_path}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and key in err


@pytest.mark.slow
@pytest.mark.cluster
def test_ray_evaluator_on_a_local_ray_equals_local(tmp_path):
    """A local Ray started by the evaluator (ray_address null), 2 actors."""
    local = make_evaluator(ENV, hidden=(4,))
    params, seeds = _batch(local, n=17, seed=1)
    expected = local.evaluate(params, seeds)
    ray_ev = RayEvaluator(ENV, hidden=(4,), workers=2)
    try:
        returns, steps = ray_ev.evaluate(params, seeds)
        np.testing.assert_array_equal(returns, expected[0])
        np.testing.assert_array_equal(steps, expected[1])
        np.testing.assert_array_equal(ray_ev.last_obs_stats[0], local.last_obs_stats[0])
    finally:
        ray_ev.close()
    import ray

    assert not ray.is_initialized()  # the Ray it started is shut down


@pytest.mark.cluster
def test_pool_is_refused_under_a_parallel_hydra_launcher():
    from imix_cli.running.config.compose import ConfigError

    with pytest.raises(ConfigError, match="evaluator=pool.*joblib"):
        validate_overrides(["hydra/launcher=joblib", "env=gym", f"env.id={ENV}", "evaluator=pool"])


@pytest.mark.slow
@pytest.mark.cluster
def test_run_with_evaluator_ray_writes_the_same_csvs_as_local(tmp_path, capfd):
    common = [
        "env=gym",
        f"env.id={ENV}",
        "algo=openes",
        "eim=true",
        "seeds=2",
        "generations=3",
        "popsize=6",
        "progress=false",
        "policy.hidden=[4]",
        "workers=1",
    ]
    frames = {}
    for evaluator in ("local", "ray"):
        extra = ["evaluator_workers=2"] if evaluator == "ray" else []
        assert main(["run", *common, f"evaluator={evaluator}", *extra, f"results_dir={tmp_path}", f"experiment={evaluator}"]) == 0
        run = tmp_path / evaluator / f"openes-{ENV}-eim-hidden=4,popsize=6"
        frames[evaluator] = [read_run_csv(run / f"seed_{k}.csv").drop(columns="wall_time") for k in (0, 1)]
    for a, b in zip(frames["local"], frames["ray"]):
        assert a.equals(b)
