"""MuJoCo locomotion: env configs, policies at this scale, honest reuse under observation
normalisation, the missing-extra message and the CMA-ES dimension guard.

The normaliser tests run on Pendulum-v1 (gymnasium's classic control, no MuJoCo needed): what
they check is the runner's bookkeeping, not the physics.
"""

import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from conftest import interrupted_run

from imix_cli.commands.cli import main
from imix_cli.core.algorithms.cmaes import MAX_DIM as CMAES_MAX_DIM
from imix_cli.core.evaluation import MUJOCO_EXTRA_HINT, make_evaluator
from imix_cli.core.evaluation.policies import BatchPolicy, ObsNormalizer, fold_normalizer, num_params
from imix_cli.core.registry import MUJOCO_ENVS
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.files.results import read_run_csv
from imix_cli.running.loop.lockstep import advance_lockstep, loop_settings, new_seed_state

needs_mujoco = pytest.mark.mujoco

TINY = ["generations=2", "seeds=1", "popsize=4", "progress=false", "workers=1"]


def imix(*args, results_dir):
    return main(["run", *args, f"results_dir={results_dir}"])


# ------------------------------------------------------------------------------ env configs
@needs_mujoco
@pytest.mark.parametrize("name", sorted(MUJOCO_ENVS))
def test_each_mujoco_env_config_composes_and_runs_two_generations(tmp_path, name, monkeypatch):
    env_id = MUJOCO_ENVS[name]
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    (spec,) = validate_overrides([f"env={name}", "algo=snes"])
    assert (spec.env_name, spec.env_id, spec.env_max_steps) == (env_id, env_id, 1000)
    assert imix(f"env={name}", "algo=snes", "eim=true", "policy.hidden=[]", *TINY, results_dir=tmp_path) == 0
    frame = read_run_csv(tmp_path / "default" / f"snes-{env_id}-eim-hidden=linear,popsize=4" / "seed_0.csv")
    assert len(frame) == 2 and (frame["env"] == env_id).all()
    assert 0 < frame["env_steps"].iloc[-1] <= 1000 * frame["evaluations"].iloc[-1]
    assert np.isfinite(frame["mean_score"]).all()
    assert list(work.iterdir()) == []  # mujoco 4's warnings (HalfCheetah) must not write ./MUJOCO_LOG.TXT


@needs_mujoco
def test_gym_evaluator_returns_the_envs_own_reward_alone_or_in_a_batch():
    """Each member's return equals a plain gym.make rollout of the same policy and seed."""
    ev = make_evaluator("Hopper-v5", hidden=(4,))
    rng = np.random.default_rng(3)
    params = rng.normal(0.0, 0.5, (5, ev.num_params))
    seeds = np.array([0, 11, 22, 33, 44])
    returns, steps = ev.evaluate(params, seeds)
    env = gym.make("Hopper-v5")
    for i in range(5):
        policy = BatchPolicy(params[i : i + 1], 11, 3, discrete=False, hidden=(4,), low=-1.0, high=1.0)
        obs, _ = env.reset(seed=int(seeds[i]))
        total, n, done = 0.0, 0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(policy(obs[None, :])[0].astype(np.float32))
            total, n, done = total + float(reward), n + 1, terminated or truncated
        assert (returns[i], steps[i]) == (total, n)
        alone = ev.evaluate(params[i : i + 1], seeds[i : i + 1])
        assert (alone[0][0], alone[1][0]) == (returns[i], steps[i])
    assert len(set(steps.tolist())) > 1  # episodes of different lengths: the alive-only stepping is exercised


@needs_mujoco
def test_any_mujoco_id_through_env_gym(tmp_path):
    assert imix("env=gym", "env.id=InvertedPendulum-v5", "algo=openes", "policy.hidden=[]", *TINY, results_dir=tmp_path) == 0
    frame = read_run_csv(tmp_path / "default" / "openes-InvertedPendulum-v5-none-hidden=linear,popsize=4" / "seed_0.csv")
    assert (frame["env"] == "InvertedPendulum-v5").all()


def test_missing_mujoco_names_the_extra_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # `import mujoco` now raises ImportError
    assert imix("env=hopper", "algo=snes", *TINY, results_dir=tmp_path) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and MUJOCO_EXTRA_HINT in err and "Hopper-v5" in err
    assert not tmp_path.exists() or not any(tmp_path.rglob("*"))
    with pytest.raises(ValueError, match=r'pip install "\.\[mujoco\]" from the imix clone'):
        make_evaluator("Walker2d-v5")


# ---------------------------------------------------------------------------------- policies
def test_default_policy_layout_is_unchanged():
    assert num_params(4, 2) == 130 and num_params(6, 3) == 155
    assert num_params(11, 3, ()) == 36 and num_params(11, 3, (64, 64)) == 11 * 64 + 64 + 64 * 64 + 64 + 64 * 3 + 3


def test_results_of_before_the_new_keys_still_resume(tmp_path):
    """The paper's runs are unchanged: a default policy is not written to config.yaml, and the
    evaluator keys are not part of a run's identity, so a folder made before they existed is
    accepted as the same run."""
    import yaml

    args = ["algo=snes", "env=cartpole", "generations=2", "popsize=4", "progress=false"]
    assert imix(*args, "seeds=1", "workers=1", results_dir=tmp_path) == 0
    config_file = tmp_path / "default" / "snes-cartpole-none-popsize=4" / "config.yaml"
    config = yaml.safe_load(config_file.read_text())
    assert "policy" not in config
    for key in ("evaluator", "evaluator_workers", "ray_address"):
        config.pop(key)
    config_file.write_text(yaml.safe_dump(config, sort_keys=False))
    assert imix(*args, "seeds=2", "evaluator=pool", "evaluator_workers=1", results_dir=tmp_path) == 0  # seed 1 added to the old folder
    assert (config_file.parent / "seed_1.csv").exists()


def test_linear_policy_is_obs_times_w_plus_b():
    rng = np.random.default_rng(0)
    params, obs = rng.normal(size=(3, 17 * 6 + 6)), rng.normal(size=(3, 17))
    W, b = params[:, : 17 * 6].reshape(3, 17, 6), params[:, 17 * 6 :]
    expected = np.tanh(np.einsum("bi,bij->bj", obs, W) + b)
    np.testing.assert_allclose(BatchPolicy(params, 17, 6, discrete=False, hidden=())(obs), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("hidden", [(), (8, 8), (16,)])
def test_folded_normaliser_equals_normalising_the_observations(hidden):
    rng = np.random.default_rng(1)
    obs_dim, out_dim = 11, 3
    params = rng.normal(size=(4, num_params(obs_dim, out_dim, hidden)))
    mean, std = rng.normal(size=obs_dim) * 5, rng.uniform(0.1, 10, obs_dim)
    obs = mean + std * rng.normal(size=(4, obs_dim))
    folded = fold_normalizer(params, obs_dim, out_dim, hidden, mean, std)
    plain = BatchPolicy(params, obs_dim, out_dim, discrete=False, hidden=hidden).outputs((obs - mean) / std)
    np.testing.assert_allclose(BatchPolicy(folded, obs_dim, out_dim, discrete=False, hidden=hidden).outputs(obs), plain, rtol=1e-10, atol=1e-10)
    assert not np.shares_memory(folded, params)


def test_normaliser_statistics_and_freeze():
    rng = np.random.default_rng(2)
    x = rng.normal(3.0, 2.0, (1000, 2))
    norm = ObsNormalizer(2, warmup=1)
    norm.add([x[:400].sum(0), x[400:].sum(0)], [(x[:400] ** 2).sum(0), (x[400:] ** 2).sum(0)], [400, 600])
    np.testing.assert_allclose(norm.mean, x.mean(0), rtol=1e-12)
    np.testing.assert_allclose(norm.std, x.std(0), rtol=1e-9)
    norm.end_generation()
    assert norm.frozen
    norm.add([np.ones(2) * 1e6], [np.ones(2) * 1e12], [1])
    np.testing.assert_allclose(norm.mean, x.mean(0), rtol=1e-12)  # frozen: nothing changes it


class RecordingEvaluator:
    """Wraps an evaluator and remembers every parameter row it evaluated (as bytes)."""

    def __init__(self, inner):
        self.inner, self.seen = inner, set()

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def evaluate(self, params, seeds):
        self.seen.update(np.ascontiguousarray(row).tobytes() for row in params)
        return self.inner.evaluate(params, seeds)


def test_reused_returns_were_measured_under_the_current_normaliser():
    """Honest reuse: every reused member's policy function (its parameters with the current
    statistics folded in) is exactly one that was evaluated. Fails if the statistics change
    while returns are reused (e.g. a normaliser that never freezes, or an archive that keeps
    warm-up generations)."""
    (spec,) = validate_overrides(
        ["env=gym", "env.id=Pendulum-v1", "algo=snes", "eim=true", "popsize=10", "sigma=0.05", "lr=0.01",
         "policy.hidden=[4]", "policy.obs_norm=true", "policy.obs_norm_warmup=3", "seeds=1"]
    )  # fmt: skip
    ev = RecordingEvaluator(make_evaluator(spec.evaluator_key, spec.env_max_steps, hidden=spec.hidden))
    settings = loop_settings(spec, ev)
    st = new_seed_state(settings, 0)
    reused_total = 0
    for generation in range(10):
        advance_lockstep([st], settings, ev)
        row = st.rows[-1]
        if generation < spec.obs_norm_warmup:
            assert row["reused"] == 0 and not st.archive.generations
            continue
        assert st.obs_norm.frozen
        g = st.archive.generations[0]  # this generation
        for i in np.flatnonzero(g.source > 0):
            folded = st.obs_norm.fold(g.samples[i : i + 1], ev.out_dim, ev.hidden)[0]
            assert folded.tobytes() in ev.seen, f"generation {generation}: member {i} reused under other statistics"
        reused_total += row["reused"]
    assert reused_total > 20  # the check above was exercised
    assert np.abs(st.obs_norm.mean).max() > 0.1  # and the statistics are not the identity


# ------------------------------------------------------------------------------ CMA-ES guard
@needs_mujoco
def test_cmaes_refuses_large_policies_before_anything_runs(tmp_path, capsys):
    assert imix("algo=cmaes", "env=hopper", "policy.hidden=[64,64]", *TINY, results_dir=tmp_path) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "5123" in err and "snes" in err and "openes" in err
    assert not tmp_path.exists() or not any(tmp_path.rglob("*"))
    assert num_params(4, 2, (48, 48)) > CMAES_MAX_DIM  # a built-in env is guarded too
    assert imix("algo=cmaes", "env=cartpole", "policy.hidden=[48,48]", *TINY, results_dir=tmp_path) == 2
    (spec,) = validate_overrides(["algo=cmaes", "env=hopper", "policy.hidden=[16]"])  # 243 parameters: fine
    assert spec.hidden == (16,)


# ------------------------------------------------------------------------ install with extra
@pytest.mark.slow
@needs_mujoco
def test_pip_install_with_the_mujoco_extra_then_run_hopper(tmp_path):
    """`pip install ".[mujoco]"` into a new venv (offline: the shared venv's packages are on
    its path, so pip checks the extra's requirements and installs only imix), then the issue's
    command from a directory without the sources."""
    repo = Path(__file__).resolve().parent.parent
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    site = next((venv / "lib").glob("python3*/site-packages"))
    shared = [p for p in sys.path if p.endswith("site-packages")]
    (site / "shared.pth").write_text("\n".join(shared) + "\n")
    py = venv / "bin" / "python"
    env = {**os.environ, "PYTHONPATH": "", "PIP_NO_INDEX": "1"}
    install = subprocess.run(
        [str(py), "-m", "pip", "install", "-q", "--no-build-isolation", f"{repo}[mujoco]"], env=env, capture_output=True, text=True, timeout=600
    )
    assert install.returncode == 0, install.stderr
    assert "does not provide the extra" not in install.stderr
    requires = subprocess.run(
        [str(py), "-c", "import importlib.metadata as m; print(m.requires('imix-cli'))"], env=env, capture_output=True, text=True, check=True
    ).stdout
    assert "gymnasium[mujoco]" in requires and 'extra == "mujoco"' in requires
    work = tmp_path / "work"
    work.mkdir()
    proc = subprocess.run(
        [str(venv / "bin" / "imix"), "run", "algo=snes", "env=hopper", "eim=true", "seeds=2", "generations=3", "progress=false"],
        cwd=work, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    for seed in (0, 1):
        assert len(read_run_csv(work / "results" / "default" / "snes-Hopper-v5-eim" / f"seed_{seed}.csv")) == 3


# ------------------------------------------------------------------------------ the study's plots
def test_bootstrap_interval_covers_the_mean_and_shrinks_with_more_seeds():
    from imix_cli.plotting.mujoco import bootstrap_ci

    rng = np.random.default_rng(0)
    few, many = rng.normal(100, 30, (5, 1)), rng.normal(100, 30, (80, 1))
    m5, lo5, hi5 = bootstrap_ci(few)
    m80, lo80, hi80 = bootstrap_ci(many)
    assert lo5[0] < m5[0] < hi5[0] and lo80[0] < m80[0] < hi80[0]
    # The bootstrap distribution of a mean has std s/sqrt(n) (s with ddof 0): the 95 % percentile
    # interval is close to +-1.96 of it -- within 10 % at n = 80, 30 % at n = 5 (discrete resampling).
    for values, (_m, lo, hi), tolerance in ((few, (m5, lo5, hi5), 0.3), (many, (m80, lo80, hi80), 0.1)):
        normal = 2 * 1.96 * values.std() / np.sqrt(len(values))
        assert abs((hi - lo)[0] / normal - 1) < tolerance


def test_study_table_counts_episodes_and_wall_time_to_threshold(tmp_path):
    from imix_cli.plotting.mujoco import main as plot_main
    from imix_cli.running.files.results import write_run_csv

    def rows(algo, mixing, seed, scores, per_gen):
        out, evaluations = [], 0
        for g, (score, n) in enumerate(zip(scores, per_gen)):
            evaluations += n
            out.append({"algo": algo, "env": "Hopper-v5", "mixing": mixing, "seed": seed, "generation": g, "evaluations": evaluations,
                        "env_steps": 100 * evaluations, "mean_score": score, "best_score": score, "reused": 10 - n, "reused_im": 10 - n,
                        "reused_eim": 0, "reevaluated": 0, "popsize": 10, "sigma_mean": 0.1, "nonfinite": 0, "wall_time": 2.0 * (g + 1)})  # fmt: skip
        return out

    for mixing, per_gen in (("none", [10, 10, 10, 10]), ("eim", [10, 4, 4, 4])):
        run = tmp_path / "mujoco" / f"snes-Hopper-v5-{mixing}-hidden=linear"
        run.mkdir(parents=True)
        write_run_csv(run / "seed_0.csv", rows("snes", mixing, 0, [10, 200, 600, 700], per_gen))
        write_run_csv(run / "seed_1.csv", rows("snes", mixing, 1, [10, 20, 30, 40], per_gen))
    assert plot_main([f"results_dir={tmp_path}", "experiment=mujoco", "resamples=200"]) == 0
    import pandas as pd

    table = pd.read_csv(tmp_path / "mujoco" / "figures" / "mujoco_table.csv").set_index("run")
    assert table.loc["snes none", "reached"] == "1/2" and table.loc["snes none", "episodes_to_threshold"] == 30
    assert table.loc["snes eim", "episodes_to_threshold"] == 18 and table.loc["snes eim", "wall_time_to_threshold_s"] == 6.0
    assert table.loc["snes eim", "reuse_percent"] == pytest.approx(100 * 18 / 40)
    # Equal episodes: both runs at the smallest budget of any seed (eim's 22): none after 20 episodes, eim after 22.
    assert (table["budget_episodes"] == 22).all()
    assert table.loc["snes none", "return_at_budget"] == (200 + 20) / 2 and table.loc["snes eim", "return_at_budget"] == (700 + 40) / 2
    assert (tmp_path / "mujoco" / "figures" / "mujoco_Hopper-v5.png").exists()
    assert plot_main([f"results_dir={tmp_path}", "experiment=mujoco", "bogus=1"]) == 2
    assert main(["plot", "mujoco", f"results_dir={tmp_path}", "experiment=mujoco", "resamples=200"]) == 0  # imix plot mujoco


def test_resume_mid_warm_up_equals_not_stopping(tmp_path):
    """The normaliser is part of a seed's checkpoint: interrupted during the warm-up (checkpoint
    at generation 2 of 3) and resumed, a run writes the same CSV as one that never stopped."""
    import pandas as pd

    from imix_cli.running.files.checkpoints import checkpoint_path

    common = ["env=gym", "env.id=Pendulum-v1", "algo=snes", "eim=true", "seeds=1", "generations=8", "popsize=6", "policy.hidden=[]",
              "policy.obs_norm=true", "policy.obs_norm_warmup=3", "checkpoint_every=2", "checkpoint_seconds=0", "workers=1", "progress=false"]  # fmt: skip
    assert main(["run", *common, f"results_dir={tmp_path / 'ref'}"]) == 0
    spec = interrupted_run(common, tmp_path / "stop", after=3)
    assert checkpoint_path(spec.run_dir, 0).exists()
    assert main(["run", *common, f"results_dir={tmp_path / 'stop'}"]) == 0
    name = spec.run_dir.relative_to(tmp_path / "stop")
    expected = read_run_csv(tmp_path / "ref" / name / "seed_0.csv").drop(columns="wall_time")
    got = read_run_csv(spec.run_dir / "seed_0.csv").drop(columns="wall_time")
    pd.testing.assert_frame_equal(got, expected)
    assert got["reused"].sum() > 0


def test_policy_files_of_a_normalised_linear_run_are_raw_observation_policies(tmp_path):
    """The written policies have the statistics folded in (the files carry no normaliser) and
    ``imix eval`` rebuilds the run's linear architecture from them."""
    from imix_cli.running.files.policy_files import read_policy

    args = ["env=gym", "env.id=Pendulum-v1", "algo=snes", "seeds=1", "generations=4", "popsize=6", "policy.hidden=[]",
            "policy.obs_norm=true", "policy.obs_norm_warmup=2", "progress=false", "workers=1"]  # fmt: skip
    assert imix(*args, results_dir=tmp_path) == 0
    run = tmp_path / "default" / "snes-Pendulum-v1-none-hidden=linear,obs_norm=2,popsize=6"
    best = read_policy(run / "policy_0_best.npz")
    assert best.header["obs_normalizer"] is None and list(best.header["hidden"]) == []
    assert main(["eval", f"results_dir={tmp_path}", f"run={run.name}", "episodes=2"]) == 0
    assert (run / "eval.csv").exists()
