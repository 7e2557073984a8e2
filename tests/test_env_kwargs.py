"""A gymnasium env's constructor arguments (``+env.kwargs.<name>=<value>``): checked against the env's constructor before
any seed runs, passed to ``gym.make``, recorded in the run's config.yaml and its identity (and folder name), used again
by ``imix eval``.

Made to fail: on the code before (main at 9420f97) ``+env.kwargs.g=2.0`` was refused as an unknown key, so every test
here failed; with the kwargs left out of the folder name (RunSpec.overrides_suffix), the two runs shared a folder and the
second was refused; with GymEvaluator ignoring env_kwargs, the evaluator's env had g = 10.
"""

import pytest
import yaml

from imix_cli.commands.cli import main
from imix_cli.core.evaluation.parallel import build_evaluator
from imix_cli.running.config.compose import validate_overrides

TINY = ["env=gym", "env.id=Pendulum-v1", "seeds=1", "generations=2", "popsize=4", "progress=false", "workers=1", "eval_mean_every=0"]


def test_constructor_arguments_reach_gym_make_and_name_the_run(tmp_path, capsys):
    (spec,) = validate_overrides([*TINY, "+env.kwargs.g=2.0"])
    assert spec.env_kwargs == (("g", 2.0),) and "env.g=2.0" in spec.run_name
    evaluator = build_evaluator(spec)
    assert evaluator._envs[0].unwrapped.g == 2.0  # the env the seeds run in
    (plain,) = validate_overrides(TINY)
    assert plain.run_dir != spec.run_dir and plain.identity() != spec.identity()

    assert main(["run", *TINY, "+env.kwargs.g=2.0", f"results_dir={tmp_path}"]) == 0
    assert main(["run", *TINY, f"results_dir={tmp_path}"]) == 0  # the same run without: its own folder, not a resume of the other
    runs = sorted(p.name for p in (tmp_path / "default").iterdir())
    assert runs == ["snes-Pendulum-v1-none-env.g=2.0,popsize=4", "snes-Pendulum-v1-none-popsize=4"], runs
    config = yaml.safe_load((tmp_path / "default" / runs[0] / "config.yaml").read_text())
    assert config["env"]["kwargs"] == {"g": 2.0}
    assert "kwargs" not in yaml.safe_load((tmp_path / "default" / runs[1] / "config.yaml").read_text())["env"]  # runs without stay as they were
    capsys.readouterr()
    # imix eval evaluates the policy in the env it was trained in
    from imix_cli.commands.eval_command import evaluator_for
    from imix_cli.running.files.policy_files import policy_path, read_policy

    run_dir = tmp_path / "default" / runs[0]
    policy = read_policy(policy_path(run_dir, 0, "mean"))
    assert evaluator_for(policy.header, run_dir=run_dir)._envs[0].unwrapped.g == 2.0


@pytest.mark.parametrize(
    ("args", "said"),
    [
        ([*TINY, "+env.kwargs.gravity=2.0"], "env.kwargs.gravity: Pendulum-v1's constructor takes no argument 'gravity'; it takes: g"),
        ([*TINY, "+env.kwargs.max_episode_steps=5"], "env.kwargs.max_episode_steps: gym.make's own keyword"),
        (["env=cartpole", "+env.kwargs.x=1", "seeds=1", "generations=2"], "env=cartpole is imix's compiled episode and takes no constructor arguments"),
        (["algo=ddpg", "env=continuous_cartpole", "+env.kwargs.x=1"], "env.kwargs: an evolution strategy's key"),
    ],
)
def test_a_bad_constructor_argument_is_one_line_and_exit_2_before_any_seed(args, said, tmp_path, capsys):
    assert main(["run", *args, f"results_dir={tmp_path}"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and said in err, err
    assert not any(tmp_path.iterdir())
