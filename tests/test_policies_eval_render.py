"""A tiny run saves its policies; `imix eval` evaluates them on fresh episodes; `imix render` draws one."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pandas as pd
import pytest

from imix_cli.commands.cli import main
from imix_cli.commands.eval_command import EVAL_STREAM, eval_episode_seeds
from imix_cli.core.evaluation import make_evaluator
from imix_cli.running.files.policy_files import HEADER_FIELDS, PolicyFileError, policy_path, read_policy
from imix_cli.running.files.results import read_run_csv

RUN = "snes-cartpole-eim-popsize=8"
TINY = ["algo=snes", "env=cartpole", "eim=true", "generations=5", "seeds=2", "popsize=8", "progress=false", "workers=1"]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("results")
    assert main(["run", *TINY, f"results_dir={root}", "experiment=pol"]) == 0
    return root, root / "pol" / RUN


def test_each_seed_writes_mean_and_best_policy_files(trained):
    _, run_dir = trained
    for seed in range(2):
        frame = read_run_csv(run_dir / f"seed_{seed}.csv")
        for which in ("mean", "best"):
            path = policy_path(run_dir, seed, which)
            with np.load(path, allow_pickle=False) as data:  # data, not a pickle
                assert set(data.files) == {"params", "header"}
            policy = read_policy(path)
            h = policy.header
            assert list(h) == list(HEADER_FIELDS)
            assert (h["env_id"], h["env_name"], h["obs_dim"], h["out_dim"], h["hidden"], h["discrete"]) == ("CartPole-v0", "cartpole", 4, 2, [8, 8], True)
            assert (h["seed"], h["which"], h["generation"], h["max_steps"], h["obs_normalizer"]) == (seed, which, 5, 200, None)
            assert policy.params.shape == (130,) and np.all(np.isfinite(policy.params))
        # the best-ever member is the best of every generation, so its return is the CSV's highest best_score
        best = read_policy(policy_path(run_dir, seed, "best"))
        assert best.header["train_return"] == frame["best_score"].max()


def test_eval_writes_rows_deterministically_on_fresh_episodes(trained, capsys):
    root, run_dir = trained
    args = ["eval", f"results_dir={root}", "experiment=pol", "episodes=7"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert RUN in out and "95% CI" in out
    first = (run_dir / "eval.csv").read_text()
    frame = pd.read_csv(run_dir / "eval.csv")
    assert list(frame["seed"]) == [0, 1] and set(frame["which"]) == {"mean"} and set(frame["episodes"]) == {7}
    # the numbers are those of the saved parameters on the eval stream's episode seeds
    ev = make_evaluator("cartpole")
    for seed in range(2):
        params = read_policy(policy_path(run_dir, seed, "mean")).params
        returns, _ = ev.evaluate(np.repeat(params[None], 7, axis=0), eval_episode_seeds(seed, 7))
        assert frame.loc[frame["seed"] == seed, "mean_return"].item() == pytest.approx(returns.mean(), abs=1e-9)
    assert main(args) == 0
    assert (run_dir / "eval.csv").read_text() == first  # deterministic by seed
    # which=best adds its rows, keeping the mean ones
    assert main([*args, "which=best"]) == 0
    frame = pd.read_csv(run_dir / "eval.csv")
    assert sorted(zip(frame["which"], frame["seed"])) == [("best", 0), ("best", 1), ("mean", 0), ("mean", 1)]


def test_eval_episode_seeds_are_not_training_episode_seeds():
    # training: episode seeds are drawn from SeedSequence(k).spawn(2)[1] (lockstep.new_seed_state)
    for seed in range(3):
        training = np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[1]).integers(0, np.iinfo(np.int64).max, size=5000, dtype=np.int64)
        evaluation = eval_episode_seeds(seed, 5000)
        assert not set(training.tolist()) & set(evaluation.tolist())
    assert EVAL_STREAM not in (0, 1)


def test_render_writes_a_gif_of_n_frames(trained, tmp_path):
    from PIL import Image

    root, _ = trained
    out = tmp_path / "policy.gif"
    assert main(["render", f"results_dir={root}", "experiment=pol", f"run={RUN}", "seed=1", "frames=6", "scale=0.5", "fps=50", f"out={out}"]) == 0
    with Image.open(out) as gif:
        assert gif.size == (300, 200)
        durations = []
        for i in range(gif.n_frames):
            gif.seek(i)
            durations.append(gif.info["duration"])
    # Pillow merges identical consecutive frames into one longer frame: count display time in frames of 20 ms
    assert sum(durations) == 6 * 20 and gif.n_frames <= 6


def test_render_and_eval_bad_input_is_one_line(trained, tmp_path, capsys):
    root, _ = trained
    base = [f"results_dir={root}", "experiment=pol"]
    assert main(["eval", *base, "episodes=0"]) == 2
    assert main(["render", *base, f"run={RUN}", f"out={tmp_path / 'x.png'}"]) == 2
    assert main(["render", *base, "run=nope"]) == 1
    assert main(["render", *base, f"run={RUN}", "seed=9"]) == 1  # no such policy file
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("imix ") for line in err)
    assert "episodes" in err[0] and "out" in err[1] and "nope" in err[2] and "policy_9_mean.npz" in err[3]


def test_a_pickled_policy_file_is_refused(tmp_path):
    path = tmp_path / "policy_0_mean.npz"
    buffer = io.BytesIO()
    np.savez(buffer, params=np.zeros(130), header=np.array([{"format": "imix-policy/1"}], dtype=object))
    path.write_bytes(buffer.getvalue())
    with pytest.raises(PolicyFileError, match="not a readable"):
        read_policy(path)
    with zipfile.ZipFile(path) as z:
        assert "header.npy" in z.namelist()
    path.write_text(json.dumps({"not": "npz"}))
    with pytest.raises(PolicyFileError):
        read_policy(path)


@pytest.mark.parametrize("env_id", ["imix/ContinuousCartPole-v0", "imix/ContinuousCartPoleHard-v0"])
def test_continuous_cartpole_passes_check_env_with_render(env_id):
    import os

    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    env = gym.make(env_id, render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (400, 600, 3) and frame.dtype == np.uint8
    env.close()


class _DecliningEvaluator:
    """Returns sum(params) - 100 * call: the best member is in the first generation, never the last."""

    obs_dim, out_dim, hidden, num_params = 4, 2, (8, 8), 130  # CartPole's policy

    def __init__(self):
        self.calls, self.seen = 0, []

    def evaluate(self, params, seeds):
        returns = params.sum(axis=1) - 100.0 * self.calls
        self.calls += 1
        self.seen += list(zip(params, returns))
        return returns, np.ones(len(params), dtype=np.int64)


def test_runner_tracks_the_best_ever_member_not_the_last_generations():
    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.loop.lockstep import advance_lockstep, loop_settings, new_seed_state

    spec = validate_overrides(["algo=snes", "env=cartpole", "popsize=6", "seeds=1", "generations=4", "workers=1"])[0]
    evaluator = _DecliningEvaluator()
    settings = loop_settings(spec, evaluator)
    st = new_seed_state(settings, 0)
    for _ in range(4):
        advance_lockstep([st], settings, evaluator)
    params, ret = max(evaluator.seen, key=lambda pr: pr[1])
    assert st.best_return == ret and np.array_equal(st.best_params, params)
    assert isinstance(st.best_params, np.ndarray) and st.best_params.dtype == np.float64 and isinstance(st.best_return, float)


def test_render_without_out_writes_into_the_run_folder_and_never_overwrites_it(trained, tmp_path, monkeypatch, capsys):
    """A GIF goes into the run folder it shows, not the current directory."""
    root, run_dir = trained
    monkeypatch.chdir(tmp_path)
    args = ["render", f"results_dir={root}", "experiment=pol", f"run={RUN}", "seed=1", "frames=3"]
    assert main(args) == 0
    made = run_dir / "render-seed1-mean.gif"
    assert made.exists() and not list(tmp_path.iterdir())  # nothing in the current directory
    before = made.read_bytes()
    made.write_bytes(b"mine")  # a file the user cares about
    capsys.readouterr()
    assert main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0] and "out=" in err[0]
    assert made.read_bytes() == b"mine"
    assert main([*args, f"out={made}"]) == 0 and made.read_bytes() == before  # out= given: overwritten as asked
    made.unlink()


def test_a_relative_out_goes_into_the_run_folder_and_an_absolute_one_where_it_says(trained, tmp_path, monkeypatch, capsys):
    """`imix render ... out=reach.gif` wrote into the current folder, away from the run it shows: a relative out= is a
    file of the run folder (as the default), an absolute one is written where it says, and --help says so.
    Made to fail (issue 48, friction 9): on the code before, reach.gif appeared in the current folder."""
    root, run_dir = trained
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    args = ["render", f"results_dir={root}", "experiment=pol", f"run={RUN}", "seed=1", "frames=3"]
    assert main([*args, "out=reach.gif"]) == 0
    assert (run_dir / "reach.gif").is_file() and not list(work.iterdir()), list(work.iterdir())
    assert f"wrote {run_dir / 'reach.gif'}" in capsys.readouterr().out
    assert main([*args, f"out={work / 'here.gif'}"]) == 0  # the current folder, named absolutely
    assert (work / "here.gif").is_file() and not (run_dir / "here.gif").exists()
    assert main([*args, "out=no_such_folder/x.gif"]) == 2
    assert str(run_dir / "no_such_folder") in capsys.readouterr().err
    (run_dir / "reach.gif").unlink()
    assert main(["render", "--help"]) == 0
    assert "a relative\n                     name is in the run folder" in capsys.readouterr().out
