"""The direct MuJoCo path (imix_cli/core/envs/mujoco_direct.py) against gymnasium's own v5 envs.

Everything is compared bit for bit (``np.array_equal``, ``==``): the direct path runs the same
engine on the same model with the same inputs, and computes every quantity as gymnasium does,
so there is no rounding difference to allow for.
"""

import importlib.util
import warnings

import numpy as np
import pytest

pytestmark = pytest.mark.mujoco

DIRECT_IDS = ("Swimmer-v5", "Hopper-v5", "HalfCheetah-v5", "Walker2d-v5", "Ant-v5")


def _gym_env(env_id: str, **kwargs):
    import gymnasium as gym

    from imix_cli.core.evaluation import missing_extra_message

    missing_extra_message(env_id)  # routes MuJoCo's warnings (HalfCheetah's model) as imix does
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return gym.make(env_id, **kwargs)


def test_the_direct_ids_are_the_evaluations_own():
    from imix_cli.core.envs.mujoco_direct import DIRECT_ENV_IDS
    from imix_cli.core.registry import MUJOCO_ENVS

    assert DIRECT_ENV_IDS == DIRECT_IDS and set(DIRECT_IDS) == set(MUJOCO_ENVS.values())


#: (env id, compiled step): both paths of the four envs the compiled step covers, Ant's Python path.
STEP_PATHS = [(env_id, compiled) for env_id in DIRECT_IDS for compiled in ((True, False) if env_id != "Ant-v5" else (False,))]


@pytest.mark.parametrize(("env_id", "compiled"), STEP_PATHS)
def test_direct_steps_equal_gymnasium_step_by_step(env_id, compiled):
    """Random float32 actions, several seeds, members ending at different times: reset
    observations (the seeded noise), then every step's observation, reward and termination
    equal gymnasium's, bit for bit; gymnasium truncates exactly at its 1000-step limit. For the
    compiled step (imix_cli/core/envs/mujoco_kernels.py) and the Python one."""
    from imix_cli.core.envs.mujoco_direct import DirectEpisodes

    seeds = [0, 5, 123, 2**40 + 7]
    direct = DirectEpisodes(env_id, compiled=compiled)
    assert direct.compiled == compiled
    envs = [_gym_env(env_id) for _ in seeds]
    obs = direct.reset(seeds)
    expected = np.array([env.reset(seed=s)[0] for env, s in zip(envs, seeds)])
    assert obs.shape == expected.shape == (len(seeds), direct.obs_dim) and obs.dtype == np.float64
    assert np.array_equal(obs, expected)
    assert len({row.tobytes() for row in obs}) == len(seeds)  # the seeds draw different noise
    rng = np.random.default_rng(1)
    alive = np.ones(len(seeds), dtype=bool)
    lengths, terminations = np.zeros(len(seeds), dtype=int), 0
    while alive.any():
        rows = np.flatnonzero(alive)
        actions = rng.uniform(-1.0, 1.0, (len(rows), direct.act_dim)).astype(np.float32)
        obs, rewards, terminated = direct.step(rows, actions)
        for k, i in enumerate(rows):
            o, r, term, trunc, _ = envs[i].step(actions[k])
            lengths[i] += 1
            assert np.array_equal(obs[k], o), f"{env_id} seed {seeds[i]} step {lengths[i]}: observation"
            assert rewards[k] == r, f"{env_id} seed {seeds[i]} step {lengths[i]}: reward {rewards[k]!r} != {r!r}"
            assert bool(terminated[k]) == term, f"{env_id} seed {seeds[i]} step {lengths[i]}: terminated"
            assert trunc == (lengths[i] == 1000 and not term)
            terminations += term
            if term or trunc:
                alive[i] = False
    if env_id in ("Swimmer-v5", "HalfCheetah-v5"):
        assert (lengths == 1000).all()  # never terminate: the time limit ends them
    else:
        assert terminations == len(seeds) and len(set(lengths.tolist())) > 1  # the health checks ended them, at different steps


#: (env id, qpos changes, qvel changes, terminated): states from which one step ends the episode by one check alone, or does not.
HEALTH_CASES = [
    ("Hopper-v5", {}, {5: 150.0}, True),  # |qvel| > 100 after the step, height and angle in range: the state range alone
    ("Hopper-v5", {}, {5: 120.0}, False),
    ("Hopper-v5", {1: 0.6}, {}, True),  # too low
    ("Hopper-v5", {2: 0.3}, {}, True),  # leaning too far
    ("Walker2d-v5", {1: 2.5}, {}, True),  # too high: the upper bound of the height range
    ("Walker2d-v5", {2: -1.2}, {}, True),  # the angle range
    ("Walker2d-v5", {2: 0.9}, {}, False),
    ("Ant-v5", {2: 1.2}, {}, True),  # torso above the range
]


@pytest.mark.parametrize(("env_id", "qpos_changes", "qvel_changes", "terminates"), HEALTH_CASES)
def test_health_checks_at_chosen_states(env_id, qpos_changes, qvel_changes, terminates):
    """Each health check, and its bounds, decides as gymnasium's: one zero-action step from a
    state set by hand (as ``set_state``) gives the same observation, reward and termination on
    every path."""
    from imix_cli.core.envs.mujoco_direct import DirectEpisodes

    env = _gym_env(env_id)
    env.reset(seed=1)
    sim = env.unwrapped
    qpos, qvel = sim.data.qpos.copy(), sim.data.qvel.copy()
    for index, value in qpos_changes.items():
        qpos[index] = value
    for index, value in qvel_changes.items():
        qvel[index] = value
    sim.set_state(qpos, qvel)
    action = np.zeros((1, sim.model.nu), dtype=np.float32)
    expected_obs, expected_reward, expected_terminated, _, _ = env.step(action[0])
    assert expected_terminated == terminates  # the case is what its comment says
    for compiled in (True, False) if env_id != "Ant-v5" else (False,):
        direct = DirectEpisodes(env_id, compiled=compiled)
        direct.reset([1])
        direct.set_state(0, qpos, qvel)
        obs, reward, terminated = direct.step(np.array([0]), action)
        assert np.array_equal(obs[0], expected_obs) and reward[0] == expected_reward and bool(terminated[0]) == expected_terminated


@pytest.mark.parametrize(
    ("env_id", "hidden", "max_steps"),
    [("Hopper-v5", (), None), ("Walker2d-v5", (8, 8), None), ("HalfCheetah-v5", (), 120), ("Swimmer-v5", (4,), 80), ("Ant-v5", (), 15)],
)
def test_direct_evaluator_equals_the_gymnasium_evaluator(env_id, hidden, max_steps):
    """Returns, episode lengths and the observation statistics of MujocoDirectEvaluator equal
    GymEvaluator's (gymnasium's env) bit for bit, in a batch and alone; a given cap truncates both alike."""
    from imix_cli.core.evaluation import GymEvaluator, MujocoDirectEvaluator, make_evaluator

    direct, gym_ev = make_evaluator(env_id, max_steps, hidden), make_evaluator(env_id, max_steps, hidden, backend="gymnasium")
    assert type(direct) is MujocoDirectEvaluator and type(gym_ev) is GymEvaluator
    assert direct._episodes.compiled == (env_id != "Ant-v5")  # the evaluator takes the compiled step where there is one
    assert (direct.obs_dim, direct.out_dim, direct.num_params, direct.max_steps) == (gym_ev.obs_dim, gym_ev.out_dim, gym_ev.num_params, gym_ev.max_steps)
    params = 0.5 * np.random.default_rng(2).standard_normal((6, direct.num_params))
    seeds = np.array([3, 0, 17, 40, 8, 99])
    returns, steps = direct.evaluate(params, seeds)
    expected_returns, expected_steps = gym_ev.evaluate(params, seeds)
    assert np.array_equal(steps, expected_steps) and np.array_equal(returns, expected_returns)
    for mine, theirs in zip(direct.last_obs_stats, gym_ev.last_obs_stats):
        assert np.array_equal(mine, theirs)
    alone = direct.evaluate(params[2:3], seeds[2:3])
    assert (alone[0][0], alone[1][0]) == (returns[2], steps[2])
    if max_steps is not None:
        assert steps.max() == max_steps  # (Ant: some episodes also end earlier, by termination)


def test_the_backend_is_chosen_by_argument_or_environment_variable(monkeypatch):
    from imix_cli.core.evaluation import GymEvaluator, MujocoDirectEvaluator, make_evaluator

    assert type(make_evaluator("Hopper-v5", hidden=())) is MujocoDirectEvaluator
    assert type(make_evaluator("Hopper-v5", hidden=(), backend="gymnasium")) is GymEvaluator
    assert type(make_evaluator("InvertedPendulum-v5", hidden=())) is GymEvaluator  # any other id: gymnasium
    monkeypatch.setenv("IMIX_MUJOCO_BACKEND", "gymnasium")
    assert type(make_evaluator("Hopper-v5", hidden=())) is GymEvaluator
    assert type(make_evaluator("Hopper-v5", hidden=(), backend="direct")) is MujocoDirectEvaluator
    monkeypatch.setenv("IMIX_MUJOCO_BACKEND", "fast")
    with pytest.raises(ValueError, match=r"^IMIX_MUJOCO_BACKEND='fast': the MuJoCo backend is one of direct, gymnasium$"):
        make_evaluator("Hopper-v5")
    with pytest.raises(ValueError, match=r"^backend='jax'"):
        make_evaluator("Hopper-v5", backend="jax")


def test_a_bad_backend_variable_stops_imix_run_in_one_line(tmp_path, capsys, monkeypatch):
    from imix_cli.commands.cli import main

    monkeypatch.setenv("IMIX_MUJOCO_BACKEND", "fast")
    monkeypatch.setattr("imix_cli.running.config.es_config._EVALUATOR_SHAPES", {})  # the config check caches its probe's error per process
    code = main(["run", "algo=snes", "env=hopper", "policy.hidden=[]", "generations=1", "popsize=4", "seeds=1", "workers=1", "progress=false",
                 f"results_dir={tmp_path}"])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0 and "IMIX_MUJOCO_BACKEND='fast'" in err
    assert not tmp_path.exists() or not any(tmp_path.rglob("*.csv"))


def test_an_imix_run_on_hopper_is_the_same_on_both_backends(tmp_path, monkeypatch):
    """End to end: SNES + EIM on Hopper with a linear policy and frozen observation
    normalisation: every CSV column but the wall time is identical whichever backend ran the
    episodes (the direct one in the pool evaluator's worker process)."""
    from imix_cli.commands.cli import main
    from imix_cli.running.files.results import read_run_csv

    common = ["algo=snes", "env=hopper", "eim=true", "policy.hidden=[]", "policy.obs_norm=true", "policy.obs_norm_warmup=1", "generations=4",
              "popsize=8", "seeds=1", "progress=false", "checkpoint_every=0"]  # fmt: skip
    frames = {}
    for backend, where in (("gymnasium", ["workers=1"]), ("direct", ["evaluator=pool", "evaluator_workers=1"])):
        monkeypatch.setenv("IMIX_MUJOCO_BACKEND", backend)
        assert main(["run", *common, *where, f"results_dir={tmp_path / backend}"]) == 0
        (csv,) = (tmp_path / backend).rglob("seed_0.csv")
        frames[backend] = read_run_csv(csv).drop(columns=["wall_time"])
    gymnasium, direct = frames["gymnasium"], frames["direct"]
    assert len(direct) == 4 and direct["reused"].iloc[1:].sum() > 0  # mixing reused members after the warm-up
    assert direct.equals(gymnasium), f"\n{direct}\n{gymnasium}"


@pytest.mark.slow
def test_bench_mujoco_prints_its_table(capsys):
    """`imix bench mujoco` on a tiny size: one row per env, every cost positive (no timing is asserted)."""
    from imix_cli.bench import main

    assert main(["mujoco", "mujoco_envs=hopper", "popsize=3", "repeats=1", "generations=1"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("|") and not line.startswith("|---")]
    header, *rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
    assert header == ["env", "mean episode (loop / run)", "gymnasium loop (µs/step)", "physics (µs/step)", "imix evaluator (µs/step)",
                      "imix run (µs/step)", "imix on gymnasium's env (µs/step)", "evaluator / loop", "run / loop", "on gymnasium's env / loop",
                      "physics / loop (floor)"]  # fmt: skip
    assert len(rows) == 1 and rows[0][0] == "Hopper-v5" and len(rows[0]) == len(header)
    assert all(float(cell) > 0 for cell in rows[0][2:])


def test_the_compiled_step_refuses_rows_and_actions_it_would_read_past():
    """The kernel reads MjData buffers by address: an index past the reset batch or actions of
    the wrong shape are refused in Python rather than read from other memory."""
    from imix_cli.core.envs.mujoco_direct import DirectEpisodes

    direct = DirectEpisodes("Hopper-v5", compiled=True)
    direct.reset([0, 1])
    with pytest.raises(ValueError, match="rows among the 2 reset members"):
        direct.step(np.array([2]), np.zeros((1, 3), dtype=np.float32))
    with pytest.raises(ValueError, match=r"actions \(1, 3\)"):
        direct.step(np.array([1]), np.zeros((1, 2), dtype=np.float32))
    obs, _, _ = direct.step(np.array([1]), np.zeros((1, 3), dtype=np.float32))
    assert obs.shape == (1, 11)


def test_bench_mujoco_without_the_extra_says_how_to_install_and_exits_0(capsys, monkeypatch):

    from imix_cli.bench import main

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *args: None if name == "mujoco" else find_spec(name, *args))
    assert main(["mujoco"]) == 0
    out = capsys.readouterr().out
    assert 'mujoco: skipped, the mujoco package is not installed: pip install ".[mujoco]" from the imix clone' in out and "|---" not in out
