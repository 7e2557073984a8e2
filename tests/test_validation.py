"""Validation: bad keys and values refused with one line naming them, with a "did you mean" for a mistyped key.

Item 6: the whole composed config -- ``+algo.<key>``, ``+env.<key>``, a ``--config-name`` YAML, ``--config-dir`` in both
forms -- is checked against the keys table before any point runs; a mistyped key is named as typed, with the closest
key of the table; ``hydra.job.chdir=true`` and ``hydra.callbacks`` are refused; ``${hydra:runtime.cwd}`` works end to end;
an experiment name the other commands could not address is refused.
Item 7: a finished seed's CSV that contradicts its run's config is refused by run, plot and eval (one line naming the file
and the mismatch), through one shared check (:func:`imix_cli.running.seed_checks.check_seed_csv`).
Item 8: ``MixingES`` and ``make_es`` check every argument at construction, with the bounds ``imix run`` checks.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from imix_cli.commands.cli import main
from imix_cli.running.config.compose import ConfigError, validate_overrides

TINY = ["algo=snes", "env=cartpole", "seeds=1", "generations=2", "popsize=4", "workers=1", "progress=false"]


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def refused(overrides: list, **kwargs) -> str:
    with pytest.raises(ConfigError) as caught:
        validate_overrides(overrides, **kwargs)
    message = str(caught.value)
    assert "\n" not in message
    return message


# ------------------------------------------------------------------ 6. keys nobody reads
@pytest.mark.parametrize(
    "overrides, named, suggested",
    [
        (["+algo.stlye=x"], "'algo.stlye'", "'algo.style'"),  # snes has no algo.style; the key of the table is suggested
        (["algo=cem", "+algo.stlye=x"], "'algo.stlye'", "'algo.style'"),
        (["+env.max_step=5"], "'env.max_step'", "'env.max_steps'"),  # ran 500-step episodes with the key ignored
        (["algo=ddpg", "env=continuous_cartpole", "+algo.tua=0.1"], "'algo.tua'", "'algo.tau'"),
    ],
)
def test_an_added_key_no_code_reads_is_refused_with_a_suggestion(overrides, named, suggested):
    message = refused([*TINY, *overrides])
    assert f"unknown key {named}" in message and f"did you mean {suggested}?" in message, message


def test_an_option_of_another_algorithm_names_the_one_it_is_for():
    assert "algo.style: applies to algo=cem only, not algo=snes" in refused([*TINY, "+algo.style=cemrl"])


@pytest.mark.parametrize(
    "overrides, named, suggested",
    [
        (["algo=cem", "algo.stlye=x"], "'algo.stlye'", "'algo.style'"),  # named 'algo' before: the first key the message contained
        (["seed=3"], "'seed'", "'seeds'"),
        (["policy.hiden=[4]"], "'policy.hiden'", "'policy.hidden'"),
        (["env=acrobot", "env.max_step=5"], "'env.max_step'", "'env.max_steps'"),
    ],
)
def test_a_mistyped_key_is_named_as_typed_with_the_closest_key(overrides, named, suggested):
    message = refused([*TINY, *overrides])
    assert f"unknown key {named}; did you mean {suggested}?" in message, message


def test_no_suggestion_when_nothing_is_close():
    message = refused([*TINY, "+zzzzqqq=1"])
    assert "unknown key 'zzzzqqq'" in message and "did you mean" not in message


# ------------------------------------------------------------------ 6. --config-name, --config-dir
@pytest.fixture
def config_dir(tmp_path):
    folder = tmp_path / "my configs"  # a space: the folder reaches Hydra's grammar quoted
    folder.mkdir()
    head = "defaults:\n  - config\n  - _self_\nseeds: 1\ngenerations: 2\npopsize: 4\nworkers: 1\nprogress: false\n"
    (folder / "good.yaml").write_text(head)
    (folder / "typo.yaml").write_text(head + "algo:\n  stlye: cemrl\n")
    (folder / "badvalue.yaml").write_text(head + "eim_generations: 0\neim: true\n")
    (folder / "callback.yaml").write_text(head + "hydra:\n  callbacks:\n    x:\n      _target_: builtins.print\n      _args_: [RAN]\n")
    (folder / "chdir.yaml").write_text(head + "hydra:\n  job:\n    chdir: true\n")
    return folder


@pytest.mark.parametrize("form", ["space", "equals"])
def test_config_dir_in_both_forms_runs_the_named_config(tmp_path, capsys, monkeypatch, config_dir, form):
    monkeypatch.chdir(tmp_path)
    flags = ["--config-dir", str(config_dir)] if form == "space" else [f"--config-dir={config_dir}"]
    assert main(["run", *flags, "--config-name", "good", "results_dir=out"]) == 0, capsys.readouterr().err
    csvs = list((tmp_path / "out" / "default").glob("*/seed_0.csv"))
    assert [p.parent.name for p in csvs] == ["snes-cartpole-none-popsize=4"]  # good.yaml's values, not conf/config.yaml's


@pytest.mark.parametrize(
    "name, text",
    [("typo", "unknown key 'algo.stlye'; did you mean 'algo.style'?"), ("badvalue", "eim_generations=0"),
     ("callback", "hydra.callbacks"), ("chdir", "hydra.job.chdir=true")],
)  # fmt: skip
def test_a_config_name_yaml_is_validated_before_any_point_runs(tmp_path, capsys, monkeypatch, config_dir, name, text):
    monkeypatch.chdir(tmp_path)
    status = main(["run", "-m", f"--config-dir={config_dir}", f"--config-name={name}", "results_dir=out", "sigma=0.1,0.2"])
    out = capsys.readouterr()
    assert status == 2 and text in out.err and "Traceback" not in out.err, out.err
    assert "RAN" not in out.out  # the callback never ran
    assert not (tmp_path / "out").exists()  # no point ran


def test_config_dir_flag_errors_are_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "--config-dir"]) == 2
    assert "--config-dir" in one_line_error(capsys)
    assert main(["run", "--config-dir", "nowhere", *TINY]) == 2
    assert "nowhere" in one_line_error(capsys)


def test_a_config_dir_file_that_imix_conf_would_hide_is_refused(tmp_path):
    from imix_cli.running.config.compose import config_dir as imix_conf

    (tmp_path / "algo").mkdir()
    (tmp_path / "algo" / "snes.yaml").write_text("name: snes\ngenerations: 7\n")  # the run would use conf/algo/snes.yaml
    message = refused(TINY, config_dirs=(imix_conf(), str(tmp_path)))
    assert "algo/snes.yaml" in message


# ------------------------------------------------------------------ 6. hydra.job.chdir, ${hydra:...}, experiment names
def test_hydra_job_chdir_is_refused_before_any_point(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "-m", *TINY, "hydra.job.chdir=true", "sigma=0.1,0.2", "results_dir=out"]) == 2
    assert "hydra.job.chdir=true" in one_line_error(capsys)
    assert list(tmp_path.iterdir()) == []


def test_a_hydra_interpolation_in_results_dir_runs_where_the_summary_says_and_resumes(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args = ["run", *TINY, "results_dir=${hydra:runtime.cwd}/out"]
    assert main(args) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    run_dir = tmp_path / "out" / "default" / "snes-cartpole-none-popsize=4"
    assert f"results: {run_dir}/seed_*.csv  (1 seed(s) run now" in out, out
    csv = (run_dir / "seed_0.csv").read_bytes()
    assert main(args) == 0
    assert "(0 seed(s) run now" in capsys.readouterr().out  # resumed: nothing recomputed
    assert (run_dir / "seed_0.csv").read_bytes() == csv


def test_a_plain_run_runs_the_config_its_validation_composed_without_hydra_composing_it_again(tmp_path, capsys, monkeypatch):
    """A plain ``imix run`` (no sweep, flag or ``hydra.*`` override) runs the RunSpec its validation made: Hydra's second
    composition cost ~0.15 s of every run's start-up (imix_cli.commands.cli._runs_without_hydra)."""
    from imix_cli.commands import cli

    def composed_again():
        raise AssertionError("Hydra composed the config a second time")

    monkeypatch.setattr(cli, "_hydra_run", composed_again)
    assert main(["run", *TINY, f"results_dir={tmp_path}"]) == 0, capsys.readouterr().err
    assert "(1 seed(s) run now" in capsys.readouterr().out
    assert (tmp_path / "default" / "snes-cartpole-none-popsize=4" / "seed_0.csv").is_file()


def test_a_run_whose_hydra_settings_could_act_still_runs_through_hydra(tmp_path, capsys, monkeypatch):
    """``hydra.job.env_set`` (and any ``hydra.*`` override, flag or sweep) keeps Hydra's job: the variable is set in the run."""
    from imix_cli.commands import cli

    seen = []
    run_point = cli._run_point

    def recording(spec, *args, **kwargs):
        seen.append(os.environ.get("IMIX_TEST_ENV_SET"))
        return run_point(spec, *args, **kwargs)

    monkeypatch.setattr(cli, "_run_point", recording)
    monkeypatch.delenv("IMIX_TEST_ENV_SET", raising=False)
    assert main(["run", *TINY, f"results_dir={tmp_path}", "+hydra.job.env_set.IMIX_TEST_ENV_SET=on"]) == 0, capsys.readouterr().err
    assert seen == ["on"]


@pytest.mark.parametrize(
    "args, plain",
    [
        (["algo=cem", "seeds=2"], True),
        (["-m", "algo=cem"], False),
        (["--config-dir=/x", "algo=cem"], False),
        (["-cd", "/x", "algo=cem"], False),
        (["hydra/launcher=basic"], False),
        (["hydra.run.dir=out"], False),
        (["+hydra.job.env_set.A=1"], False),
        (["hydra=x"], False),
        (["hydrant=1"], True),  # a key named like Hydra is not Hydra's (validation refuses it as unknown)
    ],
)
def test_which_runs_skip_hydras_second_composition(args, plain):
    from imix_cli.commands.cli import _runs_without_hydra

    assert _runs_without_hydra(args, [object()]) is plain
    assert _runs_without_hydra(args, [object(), object()]) is False  # several points: Hydra's sweep


@pytest.mark.parametrize("name", [" x ", "x ", "\tx", "a\nb", "a\x7fb"])
def test_an_experiment_name_the_other_commands_cannot_address_is_refused(name):
    message = refused([*TINY, f"experiment='{name}'"])
    assert message.startswith(f"experiment={name!r}: must be a plain folder name"), message


# ------------------------------------------------------------------ 7. a finished seed's CSV against its run's config
SCHEDULED = ["seeds=1", "generations=4", "popsize=4", "workers=1", "progress=false", "eval_mean_every=2", "eval_mean_episodes=2",
             "checkpoint_every=2", "checkpoint_seconds=0"]  # fmt: skip


def finished_run(root: Path, *extra: str) -> Path:
    assert main(["run", *SCHEDULED, *extra, f"results_dir={root}"]) == 0
    (spec,) = validate_overrides([*SCHEDULED, *extra, f"results_dir={root}"])
    return spec.run_dir


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two finished runs of the same shape (cartpole, acrobot) and one of another algorithm, to copy CSVs between."""
    root = tmp_path_factory.mktemp("item7")
    return {
        "cartpole": finished_run(root / "a"),
        "acrobot": finished_run(root / "b", "env=acrobot"),
        "cem": finished_run(root / "c", "algo=cem"),
    }


@pytest.fixture
def run_dir(runs, tmp_path):
    """A fresh copy of the cartpole run, results_dir ``tmp_path``: each test damages its own."""
    import shutil

    target = tmp_path / "default" / runs["cartpole"].name
    shutil.copytree(runs["cartpole"], target)
    return target


def rewrite_csv(path: Path, change) -> None:
    import pandas as pd

    frame = pd.read_csv(path)
    frame = change(frame)
    path.write_text(frame.to_csv(index=False, float_format="%.10g", lineterminator="\n"))


NAN = float("nan")
CONTRADICTIONS = {
    "another env's CSV": (lambda runs, csv: csv.write_bytes((runs["acrobot"] / "seed_0.csv").read_bytes()), "env=acrobot"),
    "another algo's CSV": (lambda runs, csv: csv.write_bytes((runs["cem"] / "seed_0.csv").read_bytes()), "algo=cem"),
    "another popsize": (lambda runs, csv: rewrite_csv(csv, lambda f: f.assign(popsize=6)), "popsize 6"),
    "an extra column": (lambda runs, csv: rewrite_csv(csv, lambda f: f.assign(note="x")), "extra column(s) ['note']"),
    "columns reordered": (lambda runs, csv: rewrite_csv(csv, lambda f: f[list(f.columns[::-1])]), "another order"),
    "another schedule": (
        lambda runs, csv: rewrite_csv(csv, lambda f: f.assign(mean_policy_episodes=[0, 0, 2, 2], mean_policy_score=[NAN, NAN, 1.0, NAN])),
        "eval_mean_every=2",
    ),
}


@pytest.mark.parametrize("name", list(CONTRADICTIONS))
def test_imix_run_refuses_a_finished_csv_that_contradicts_its_config(runs, run_dir, tmp_path, capsys, name):
    damage, text = CONTRADICTIONS[name]
    csv = run_dir / "seed_0.csv"
    damage(runs, csv)
    capsys.readouterr()
    assert main(["run", *SCHEDULED, f"results_dir={tmp_path}"]) == 1
    out = capsys.readouterr()
    err = out.err.strip()
    assert len(err.splitlines()) == 1 and str(csv) in err and text in err, err
    assert "reuse" not in out.out  # no summary made of it


@pytest.mark.parametrize("name", list(CONTRADICTIONS))
def test_imix_plot_skips_a_csv_that_contradicts_its_config(runs, run_dir, tmp_path, name):
    from imix_cli.plotting.data import load_experiment

    damage, text = CONTRADICTIONS[name]
    csv = run_dir / "seed_0.csv"
    damage(runs, csv)
    warnings = []
    experiment = load_experiment(tmp_path, "default", warn=warnings.append)
    assert experiment.groups == [] and any(str(csv) in w and text in w for w in warnings), warnings


@pytest.mark.parametrize("name", ["another env's CSV", "another popsize", "another schedule"])
def test_imix_eval_refuses_a_run_whose_csv_contradicts_its_config(runs, run_dir, tmp_path, capsys, name):
    damage, text = CONTRADICTIONS[name]
    csv = run_dir / "seed_0.csv"
    damage(runs, csv)
    assert main(["eval", f"results_dir={tmp_path}", "episodes=2"]) == 1
    err = one_line_error(capsys)
    assert str(csv) in err and text in err, err
    assert not (run_dir / "eval.csv").exists()


def test_the_readers_accept_the_runs_own_csvs(runs, run_dir, tmp_path, capsys):
    """The other side of the tests above: the untouched run passes every reader's check."""
    from imix_cli.plotting.data import load_experiment

    assert main(["run", *SCHEDULED, f"results_dir={tmp_path}"]) == 0
    assert "(0 seed(s) run now" in capsys.readouterr().out
    assert [g.n_seeds for g in load_experiment(tmp_path, "default", warn=pytest.fail).groups] == [1]
    assert main(["eval", f"results_dir={tmp_path}", "episodes=2"]) == 0


def test_a_changed_schedule_does_not_continue_a_csv_on_another_one(run_dir, tmp_path, capsys):
    """eval_mean_every changed between a run and its continuation (a changed default looks the same): refused with one
    line; continued with the recorded schedule, the CSV follows one schedule to the end."""
    from imix_cli.running.files.results import read_run_csv
    from imix_cli.running.seed_checks import check_seed_csv

    csv = run_dir / "seed_0.csv"
    before = csv.read_bytes()
    assert main(["run", *SCHEDULED, "generations=6", "eval_mean_every=3", f"results_dir={tmp_path}"]) == 1
    err = one_line_error(capsys)
    assert "eval_mean_every=2" in err and "eval_mean_every=3" in err, err
    assert csv.read_bytes() == before
    assert main(["run", *SCHEDULED, "generations=6", f"results_dir={tmp_path}"]) == 0
    frame = read_run_csv(csv)
    assert len(frame) == 6 and frame["mean_policy_episodes"].tolist() == [0, 2, 2, 4, 4, 6]
    check_seed_csv(frame, csv, {"algo": {"name": "snes"}, "eval_mean_every": 2, "eval_mean_episodes": 2})


def test_a_finished_run_is_still_summarised_under_another_schedule(run_dir, tmp_path, capsys):
    """Nothing to continue: the finished CSVs keep the schedule config.yaml records, and the run says so by reusing them."""
    assert main(["run", *SCHEDULED, "eval_mean_every=3", f"results_dir={tmp_path}"]) == 0
    assert "(0 seed(s) run now" in capsys.readouterr().out


# ------------------------------------------------------------------ 8. the library checks its arguments with the CLI's bounds
@pytest.mark.parametrize(
    "kwargs, error, named",
    [
        ({"eim_generations": 0}, ValueError, "eim_generations"),
        ({"eim_generations": -3}, ValueError, "eim_generations"),
        ({"eim_generations": 2.5}, TypeError, "eim_generations"),  # was a TypeError deep inside the first ask
        ({"reeval_prob": 5}, ValueError, "reeval_prob"),
        ({"reeval_age": 0}, ValueError, "reeval_age"),
        ({"alpha": 1.0, "variant": "sun2009"}, ValueError, "alpha"),
        ({"variant": "nope"}, ValueError, "variant 'nope'"),  # was an error at the first ask
        ({"rng": "x"}, TypeError, "rng"),
    ],
)
def test_mixing_es_refuses_a_bad_argument_at_construction(kwargs, error, named):
    from imix_cli.core.algorithms import make_es
    from imix_cli.core.mixing.ask_tell import MixingES

    with pytest.raises(error, match=named):
        MixingES(make_es("snes", 3, popsize=6), **kwargs)


@pytest.mark.parametrize(
    "kwargs, error, named",
    [({"popsize": 2.5}, TypeError, "popsize"), ({"popsize": True}, TypeError, "popsize"), ({"sigma": 1e300}, ValueError, "sigma"),
     ({"sigma": float("nan")}, ValueError, "sigma"), ({"lr": 0}, ValueError, "lr")],
)  # fmt: skip
def test_make_es_refuses_rather_than_truncates(kwargs, error, named):
    from imix_cli.core.algorithms import make_es

    with pytest.raises(error, match=named):
        make_es("snes", 3, **kwargs)


# (config key, library argument, a value inside the bound, values outside it): both sides must agree on each
SHARED_BOUNDS = [
    ("popsize", "popsize", 2, [1, 2.5]),
    ("sigma", "sigma", 1e153, [0, -1, 1e154, 1e300]),
    ("lr", "lr", 1e-9, [0, -0.1]),
    ("weight_decay", "weight_decay", 0, [-0.1]),
    ("eim_generations", "eim_generations", 1, [0, -3, 2.5]),
    ("reeval_prob", "reeval_prob", 0.5, [1, 5, -0.1]),
    ("reeval_age", "reeval_age", 1, [0, 1.5]),
    ("reeval_count", "reeval_count", 0, [-1, 0.5]),
]


@pytest.mark.parametrize("key, argument, good, bad", SHARED_BOUNDS, ids=[c[0] for c in SHARED_BOUNDS])
def test_the_library_and_the_cli_refuse_the_same_values(key, argument, good, bad):
    from imix_cli.core.algorithms import make_es
    from imix_cli.core.mixing.ask_tell import MixingES

    def library(value):
        if argument in ("popsize", "sigma", "lr", "weight_decay"):
            return make_es("snes", 3, **{argument: value})
        if argument == "reeval_count":  # MixingES does not take it; the runner's MixingSettings does
            from imix_cli.core.mixing.generation import MixingSettings

            return MixingSettings("exact", reeval_count=value)
        return MixingES(make_es("snes", 3, popsize=6), "exact", **{argument: value})

    def cli(value):
        return validate_overrides([*TINY, "eim=true", f"{key}={value!r}"])

    library(good)
    cli(good)
    for value in bad:
        with pytest.raises((TypeError, ValueError), match=argument):
            library(value)
        assert f"{key}=" in refused([*TINY, "eim=true", f"{key}={value!r}"])


# ------------------------------------------------------------------ what the command-line fuzzer found
FOUND_BY_THE_FUZZER = [
    (["-m", "sigma=interval(0,1)"], "interval"),  # HydraException
    (["~env"], "~env"),  # IndexError
    (["~algo"], "~algo"),
    (["env.name=[a]"], "env.name=['a']"),  # TypeError: unhashable list
    (["+env='a\nb'"], "unknown env"),  # a message of two lines
    (["algo.gamma='a\nb'", "algo=ddpg", "env=continuous_cartpole", "+algo.x=1"], "algo.x"),
    (["--config-name", "x" * 5000], "--config-name 'xxx"),  # OSError: File name too long
    (["--config-path", "/"], "--config-name config: no such config in / "),  # walked the whole file system (OSError in /proc)
]


@pytest.mark.parametrize("args, text", FOUND_BY_THE_FUZZER, ids=[f"case{k}" for k in range(len(FOUND_BY_THE_FUZZER))])
def test_what_the_fuzzer_found_is_one_line(tmp_path, args, text):
    from imix_cli.commands.cli import validate_run_args
    from imix_cli.running.run_folder import RunError

    with pytest.raises((ConfigError, RunError)) as caught:
        validate_run_args([*TINY, f"results_dir={tmp_path}", *args])
    message = str(caught.value)
    assert "\n" not in message and text in message and len(message) < 2000, message
