"""algo=ddpg (stable-baselines3), the deep-RL baseline of the paper's section 4.3: the paper's
settings reach SB3's networks and optimisers and survive training steps; config validation;
a short run through `imix run` writes a valid CSV."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import extra_installed

from imix_cli.commands.cli import main
from imix_cli.core.envs import CONTINUOUS_CARTPOLE_HARD_ID, CONTINUOUS_CARTPOLE_ID
from imix_cli.running.config.compose import DDPG_DEFAULTS, ConfigError, config_dir, validate_overrides
from imix_cli.running.files.results import COLUMNS, read_run_csv

pytestmark = pytest.mark.ddpg  # the whole module: its imports need torch and stable-baselines3

if extra_installed("ddpg"):  # collected, and skipped by the marker, without them
    import torch as th
    from stable_baselines3.common.noise import OrnsteinUhlenbeckActionNoise

    from imix_cli.core.ddpg.agent import PAPER_SETTINGS, TwoRateDDPG, make_ddpg, train_ddpg


def layer_sizes(sequential) -> list[tuple[int, int]]:
    return [(m.in_features, m.out_features) for m in sequential if isinstance(m, th.nn.Linear)]


def lrs(model) -> tuple[float, float]:
    return model.actor.optimizer.param_groups[0]["lr"], model.critic.optimizer.param_groups[0]["lr"]


# --------------------------------------------------------------------------- settings reach SB3
def test_shipped_config_holds_the_paper_settings():
    shipped = yaml.safe_load((Path(config_dir()) / "algo" / "ddpg.yaml").read_text())
    assert {k: shipped[k] for k in DDPG_DEFAULTS} == DDPG_DEFAULTS == PAPER_SETTINGS
    assert (shipped["actor_lr"], shipped["critic_lr"], shipped["tau"], shipped["gamma"]) == (0.005, 0.01, 0.001, 0.99)
    assert shipped["actor_arch"] == [8, 8] and shipped["critic_arch"] == [16, 16]
    assert shipped["default_total_steps"] == {"continuous_cartpole": 200_000, "continuous_cartpole_hard": 1_000_000}


def test_paper_settings_reach_sb3_and_survive_training_steps():
    model = make_ddpg(CONTINUOUS_CARTPOLE_ID, seed=0)
    assert isinstance(model, TwoRateDDPG)
    assert lrs(model) == (0.005, 0.01)  # already before the first update
    assert (model.tau, model.gamma, model.batch_size, model.learning_starts) == (0.001, 0.99, 64, 100)
    assert model.buffer_size == 1_000_000 and model.train_freq.frequency == 1 and model.gradient_steps == 1
    # plain DDPG: one critic, no policy delay, no target-policy smoothing
    assert model.policy_delay == 1 and model.target_noise_clip == 0.0 and len(model.critic.q_networks) == 1
    assert layer_sizes(model.actor.mu) == [(4, 8), (8, 8), (8, 1)]
    assert isinstance(model.actor.mu[-1], th.nn.Tanh)
    assert layer_sizes(model.critic.q_networks[0]) == [(5, 16), (16, 16), (16, 1)]  # obs + action in
    assert layer_sizes(model.actor_target.mu) == [(4, 8), (8, 8), (8, 1)]
    noise = model.action_noise
    assert isinstance(noise, OrnsteinUhlenbeckActionNoise)
    assert (noise._theta, noise._dt) == (0.15, 0.01) and np.array_equal(noise._sigma, [0.2]) and np.array_equal(noise._mu, [0.0])

    actor_before = [p.detach().clone() for p in model.actor.parameters()]
    target_before = [p.detach().clone() for p in model.critic_target.parameters()]
    episodes = []
    train_ddpg(model, 400, episodes.append)  # 300 gradient steps (learning_starts 100)
    assert model._n_updates == 300
    assert lrs(model) == (0.005, 0.01)  # SB3's _update_learning_rate ran 300 times
    assert th.get_num_threads() == 1
    assert any(not th.equal(a, b) for a, b in zip(actor_before, model.actor.parameters()))
    assert any(not th.equal(a, b) for a, b in zip(target_before, model.critic_target.parameters()))
    assert episodes and [e.index for e in episodes] == list(range(len(episodes)))
    assert all(e.ret == e.length for e in episodes) and episodes[-1].env_steps <= 400


def test_two_rates_follow_their_own_schedules():
    model = TwoRateDDPG("MlpPolicy", CONTINUOUS_CARTPOLE_ID, learning_rate=lambda p: 0.004 * p, critic_learning_rate=lambda p: 0.02 * p,
                        learning_starts=10, batch_size=8, buffer_size=1000, seed=0, device="cpu")  # fmt: skip
    model.learn(100)
    actor_lr, critic_lr = lrs(model)
    remaining = model._current_progress_remaining
    assert actor_lr == pytest.approx(0.004 * remaining) and critic_lr == pytest.approx(0.02 * remaining)
    assert critic_lr == pytest.approx(5 * actor_lr)


def test_seed_reproduces_the_episodes():
    runs = []
    for _ in range(2):
        episodes = []
        train_ddpg(make_ddpg(CONTINUOUS_CARTPOLE_HARD_ID, seed=3), 300, episodes.append)
        runs.append([(e.ret, e.length, e.env_steps) for e in episodes])
    assert runs[0] == runs[1]
    assert all(ret == length for ret, length, _ in runs[0])  # Hard: the sparse sum is the episode's total


# --------------------------------------------------------------------------- config
@pytest.mark.parametrize(
    "overrides,message",
    [
        (["env=cartpole"], "continuous"),
        (["env=acrobot"], "continuous"),
        (["env=gym", "env.id=MountainCar-v0", "total_steps=1000"], "Box"),
        (["env=continuous_cartpole", "total_steps=0"], "total_steps"),
        (["env=continuous_cartpole", "total_steps=1.5"], "total_steps"),
        (["env=continuous_cartpole", "total_steps=150"], "episode cap"),
        (["env=gym", "env.id=Pendulum-v1"], "no default budget"),
        (["env=continuous_cartpole", "algo.critic_lr=-1"], "algo.critic_lr"),
        (["env=continuous_cartpole", "algo.actor_arch=[]"], "algo.actor_arch"),
    ],
)
def test_bad_ddpg_configs_give_one_line(overrides, message):
    with pytest.raises(ConfigError, match=message) as err:
        validate_overrides(["algo=ddpg", *overrides])
    assert "\n" not in str(err.value)


def test_budget_defaults_and_ignored_es_keys():
    (cp,) = validate_overrides(["algo=ddpg", "env=continuous_cartpole"])
    (hard,) = validate_overrides(["algo=ddpg", "env=continuous_cartpole_hard"])
    assert (cp.total_steps, hard.total_steps) == (200_000, 1_000_000)
    (ignored,) = validate_overrides(["algo=ddpg", "env=continuous_cartpole", "popsize=3", "eim=true", "sigma=-1", "lr=0.1"])
    assert ignored.run_name == cp.run_name == "ddpg-continuous_cartpole-none" and ignored.identity() == cp.identity()
    assert "popsize" not in ignored.config and ignored.config["total_steps"] == 200_000
    (tuned,) = validate_overrides(["algo=ddpg", "env=continuous_cartpole", "algo.critic_lr=0.001", "total_steps=5000"])
    assert tuned.run_name == "ddpg-continuous_cartpole-none-critic_lr=0.001" and tuned.ddpg["critic_lr"] == 0.001
    (pendulum,) = validate_overrides(["algo=ddpg", "env=gym", "env.id=Pendulum-v1", "total_steps=400"])
    assert pendulum.total_steps == 400


# --------------------------------------------------------------------------- imix run algo=ddpg
def test_short_run_writes_the_csv_contract_and_skips_finished_seeds(tmp_path, capsys):
    args = ["run", "algo=ddpg", "env=continuous_cartpole", "seeds=1", "total_steps=600", "progress=false", f"results_dir={tmp_path}"]
    assert main(args) == 0
    run_dir = tmp_path / "default" / "ddpg-continuous_cartpole-none"
    frame = read_run_csv(run_dir / "seed_0.csv")
    assert list(frame.columns) == list(COLUMNS) and len(frame) >= 3
    assert (frame["algo"] == "ddpg").all() and (frame["env"] == "continuous_cartpole").all() and (frame["mixing"] == "none").all()
    assert (frame["evaluations"] == frame["generation"] + 1).all()
    assert frame["env_steps"].is_monotonic_increasing and frame["env_steps"].iloc[-1] <= 600
    assert (frame["mean_score"] == frame["env_steps"].diff().fillna(frame["env_steps"].iloc[0])).all()  # return == length
    assert (frame["popsize"] == 1).all() and (frame[["reused", "reused_im", "reused_eim", "nonfinite"]] == 0).all().all()
    assert (frame["sigma_mean"] == 0.2).all()
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert config["algo"]["name"] == "ddpg" and config["total_steps"] == 600 and "generations" not in config
    capsys.readouterr()
    assert main(args) == 0  # finished: skipped
    assert "0 seed(s) run now" in capsys.readouterr().out
