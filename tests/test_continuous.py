"""ContinuousCartPole(Hard) (paper section 4.3): registration, env checker, force scale, sparse
reward, batched ES evaluator == registered envs, configs, and a two-point grid-search multirun."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from test_envs import reference_outputs

import imix_cli.core.envs  # noqa: F401  (registers the ids)
from imix_cli.commands.cli import main
from imix_cli.core.envs import CONTINUOUS_CARTPOLE_HARD_ID, CONTINUOUS_CARTPOLE_ID
from imix_cli.core.evaluation import make_evaluator
from imix_cli.core.evaluation.policies import BatchPolicy
from imix_cli.running.config.compose import BUILTIN_ENVS, ConfigError, config_dir, validate_overrides
from imix_cli.running.files.results import read_run_csv

IDS = [CONTINUOUS_CARTPOLE_ID, CONTINUOUS_CARTPOLE_HARD_ID]
NAMES = {"continuous_cartpole": CONTINUOUS_CARTPOLE_ID, "continuous_cartpole_hard": CONTINUOUS_CARTPOLE_HARD_ID}


def balancer(rng, n, noise=0.05):
    """Params of 1-output MLPs pushing along theta + theta_dot (mostly full 200-step episodes)."""
    W1 = np.zeros((4, 8))
    W1[:, 0] = [0.1, 0.5, 3.0, 1.0]
    W2 = np.zeros((8, 8))
    W2[0, 0] = 1.0
    W3 = np.zeros((8, 1))
    W3[0] = 5.0
    base = np.concatenate([W1.ravel(), np.zeros(8), W2.ravel(), np.zeros(8), W3.ravel(), np.zeros(1)])
    return base + noise * rng.standard_normal((n, base.size))


def population(seed=0, n_random=12, n_good=12):
    rng = np.random.default_rng(seed)
    params = np.vstack([rng.standard_normal((n_random, 121)), balancer(rng, n_good)])
    return params, rng.integers(0, 2**62, n_random + n_good)


def rollout(env_id, action_fn, seed):
    """One episode of the registered env: (rewards, observations, final terminated, final truncated)."""
    env = gym.make(env_id)
    obs, _ = env.reset(seed=int(seed))
    rewards, observations = [], [obs]
    while True:
        obs, reward, terminated, truncated, _ = env.step(action_fn(obs))
        rewards.append(reward)
        observations.append(obs)
        if terminated or truncated:
            env.close()
            return np.array(rewards), np.array(observations), terminated, truncated


def replay(actions):
    """An action function for :func:`rollout` that plays ``actions`` in order, whatever it observes."""
    remaining = iter(actions)
    return lambda obs: next(remaining)


def member_policy(params):
    """An action function for :func:`rollout`: one member's MLP acting on a single env's observation."""
    policy = BatchPolicy(params[None], 4, 1, discrete=False)
    return lambda obs: policy(obs[None])[0]


# --------------------------------------------------------------------------- registration
@pytest.mark.parametrize("env_id", IDS)
def test_registered_and_passes_the_env_checker(env_id):
    env = gym.make(env_id)
    assert env.spec.max_episode_steps == 200 and env.spec.reward_threshold == 195.0
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    assert env.observation_space == gym.make("CartPole-v1").observation_space
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*infinity.*")  # CartPole's own unbounded velocities
        warnings.filterwarnings("ignore", message=".*different from the unwrapped.*")  # the Hard wrapper
        check_env(env.unwrapped, skip_render_check=True)
        check_env(env, skip_render_check=True)  # what gym.make gives, the Hard one's sparse wrapper included


def test_full_pushes_are_discrete_cartpoles_pushes():
    """force = 10 N x a: a = +-1 reproduces CartPole-v1 bit for bit (and a = 0.5 is a weaker push)."""
    rng = np.random.default_rng(3)
    for seed in range(5):
        actions = rng.integers(0, 2, 200)
        discrete = gym.make("CartPole-v1")
        continuous = gym.make(CONTINUOUS_CARTPOLE_ID)
        o1, _ = discrete.reset(seed=seed)
        o2, _ = continuous.reset(seed=seed)
        np.testing.assert_array_equal(o1, o2)
        for a in actions:
            o1, r1, d1, _, _ = discrete.step(int(a))
            o2, r2, d2, tr2, _ = continuous.step(np.array([2.0 * a - 1.0], np.float32))
            np.testing.assert_array_equal(o1, o2)
            assert (r1, d1) == (r2, d2)
            if d1:
                break
    half = gym.make(CONTINUOUS_CARTPOLE_ID).unwrapped
    half.reset(seed=0)
    x_dot0 = half.state[1]
    half.step(np.array([0.5], np.float32))
    full = gym.make(CONTINUOUS_CARTPOLE_ID).unwrapped
    full.reset(seed=0)
    full.step(np.array([1.0], np.float32))
    assert 0 < half.state[1] - x_dot0 < full.state[1] - x_dot0


def test_actions_are_clipped_and_nan_pushes_nothing():
    def first_state(action):
        env = gym.make(CONTINUOUS_CARTPOLE_ID).unwrapped
        env.reset(seed=1)
        env.step(np.array([action], np.float64))
        return env.state.copy()

    np.testing.assert_array_equal(first_state(5.0), first_state(1.0))
    np.testing.assert_array_equal(first_state(np.nan), first_state(0.0))


def test_hard_reward_is_sparse_and_sums_to_the_dense_return():
    rng = np.random.default_rng(0)
    lengths = set()
    for seed in range(8):
        actions = rng.uniform(-1, 1, (200, 1)).astype(np.float32) * rng.uniform(0, 0.3)  # some long episodes
        dense, obs_d, term_d, trunc_d = rollout(CONTINUOUS_CARTPOLE_ID, replay(actions), seed)
        sparse, obs_s, term_s, trunc_s = rollout(CONTINUOUS_CARTPOLE_HARD_ID, replay(actions), seed)
        np.testing.assert_array_equal(obs_d, obs_s)  # same seed, same actions: same dynamics
        assert (term_d, trunc_d) == (term_s, trunc_s)
        assert (dense == 1.0).all()
        assert (sparse[:-1] == 0.0).all() and sparse[-1] == sparse.sum() == dense.sum() == len(dense)
        lengths.add(len(dense))
    assert len(lengths) > 1


def test_hard_pays_at_truncation_whatever_the_time_limit():
    # a balancer survives the whole episode: the total comes with the truncation
    params = balancer(np.random.default_rng(0), 1, noise=0.0)
    policy = BatchPolicy(params, 4, 1, discrete=False)
    for limit in (200, 57):
        env = gym.make(CONTINUOUS_CARTPOLE_HARD_ID, max_episode_steps=limit)
        obs, _ = env.reset(seed=0)
        rewards = []
        while True:
            obs, reward, terminated, truncated, info = env.step(policy(obs[None])[0])
            rewards.append(reward)
            if terminated or truncated:
                break
        assert truncated and not terminated and len(rewards) == limit
        assert rewards[-1] == limit and sum(rewards[:-1]) == 0.0


# --------------------------------------------------------------------------- batched == registered
@pytest.mark.parametrize("name", sorted(NAMES))
def test_batched_evaluator_equals_the_registered_env(name):
    params, seeds = population()
    ev = make_evaluator(name)
    assert ev.num_params == 121 and not ev.discrete and ev.out_dim == 1
    returns, steps = ev.evaluate(params, seeds)
    assert 0 < (returns == 200).sum() < len(returns)  # both short and full episodes
    for p, s, ret, n in zip(params, seeds, returns, steps):
        rewards, _, _, _ = rollout(NAMES[name], member_policy(p), s)
        assert rewards.sum() == ret and len(rewards) == n == ret


@pytest.mark.parametrize("name", sorted(NAMES))
def test_compiled_trajectories_are_bit_identical(name):
    """Every state of the compiled episodes == the registered env's, from reset(seed=s) on, with
    the policy evaluated in plain Python (math.tanh, as the kernel; numpy's tanh differs by ulps)."""
    params, seeds = population(seed=1, n_random=4, n_good=4)
    returns, steps, trace = make_evaluator(name).trajectories(params, seeds)
    for i, (p, s) in enumerate(zip(params, seeds)):

        def single(obs, p=p):
            return np.array([math.tanh(reference_outputs(p, obs[0], (4, 8, 8, 1))[0])])[None]

        env = gym.make(NAMES[name])
        env.reset(seed=int(s))
        states, rewards, done = [env.unwrapped.state.copy()], [], False
        while not done:
            _, reward, terminated, truncated, _ = env.step(single(np.array(env.unwrapped.state, np.float32)[None])[0])
            states.append(env.unwrapped.state.copy())
            rewards.append(reward)
            done = terminated or truncated
        np.testing.assert_array_equal(trace[i, : len(states)], np.array(states))
        assert np.isnan(trace[i, len(states) :]).all() and steps[i] == len(rewards) and returns[i] == sum(rewards)


@pytest.mark.parametrize("name", sorted(NAMES))
def test_member_result_is_independent_of_its_batch(name):
    params, seeds = population(seed=2)
    ev = make_evaluator(name)
    together = ev.evaluate(params, seeds)
    alone = np.array([ev.evaluate(p[None], s[None]) for p, s in zip(params, seeds)])[:, :, 0]
    shuffled = np.random.default_rng(0).permutation(len(seeds))
    perm = ev.evaluate(params[shuffled], seeds[shuffled])
    np.testing.assert_array_equal(alone[:, 0], together[0])
    np.testing.assert_array_equal(alone[:, 1], together[1])
    np.testing.assert_array_equal(perm[0], together[0][shuffled])


def test_env_max_steps_caps_both_variants_alike():
    params, seeds = population(seed=3)
    dense = make_evaluator("continuous_cartpole", max_steps=50).evaluate(params, seeds)
    hard = make_evaluator("continuous_cartpole_hard", max_steps=50).evaluate(params, seeds)
    np.testing.assert_array_equal(dense[0], hard[0])
    assert dense[0].max() == 50


# --------------------------------------------------------------------------- configs and the grid search
def test_configs_name_the_registered_ids():
    for name, env_id in NAMES.items():
        (spec,) = validate_overrides(["algo=snes", f"env={name}", "eim=true"])
        assert (spec.env_name, spec.env_id, spec.env_max_steps, spec.evaluator_key) == (name, env_id, 200, name)
    with pytest.raises(ConfigError, match="continuous"):
        validate_overrides(["algo=ddpg", "env=cartpole"])


def test_default_plot_thresholds_are_the_registered_reward_thresholds():
    """`imix plot`'s default threshold for every built-in env (conf/env/, the generic gym aside) is
    the reward_threshold its gymnasium id is registered with: 195 for the CartPoles, -100 for Acrobot."""
    from imix_cli.plotting import parse_args

    thresholds = parse_args([])["thresholds"]
    # built-in configs: conf/env/ less the generic gym and the MuJoCo configs (gymnasium ids, own table)
    names = sorted(p.stem for p in (Path(config_dir()) / "env").glob("*.yaml") if p.stem in BUILTIN_ENVS)
    assert set(NAMES) < set(names)
    for name in names:
        (spec,) = validate_overrides(["algo=snes", f"env={name}"])
        assert thresholds[name] == gym.spec(spec.env_id).reward_threshold, name


def test_two_point_multirun_writes_two_run_folders_and_plots_the_ranking(tmp_path):
    args = ["run", "-m", "algo=snes", "env=continuous_cartpole", "popsize=10,12", "generations=3", "seeds=1", "workers=1", "progress=false"]
    assert main([*args, f"results_dir={tmp_path}"]) == 0
    runs = sorted(p.name for p in (tmp_path / "default").iterdir() if p.is_dir() and not p.name.startswith("."))
    assert runs == ["snes-continuous_cartpole-none-popsize=10", "snes-continuous_cartpole-none-popsize=12"]
    for run in runs:
        frame = read_run_csv(tmp_path / "default" / run / "seed_0.csv")
        assert len(frame) == 3 and (frame["env"] == "continuous_cartpole").all()
    assert main(["plot", f"results_dir={tmp_path}", "only=gridsearch", "formats=png"]) == 0
    ranking = (tmp_path / "default" / "figures" / "gridsearch_ranking.csv").read_text()
    assert "continuous_cartpole" in ranking and "popsize=10" in ranking and "popsize=12" in ranking
    assert (tmp_path / "default" / "figures" / "gridsearch_snes_continuous_cartpole_none_popsize.png").exists()
