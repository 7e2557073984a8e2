"""Reliability round 4, validation (issue 36 items 6-8; issue 38 item 9's "did you mean").

Item 6: the whole composed config -- ``+algo.<key>``, ``+env.<key>``, a ``--config-name`` YAML, ``--config-dir`` in both
forms -- is checked against the keys table before any point runs; a mistyped key is named as typed, with the closest
key of the table; ``hydra.job.chdir=true`` and ``hydra.callbacks`` are refused; ``${hydra:runtime.cwd}`` works end to end;
an experiment name the other commands could not address is refused.
Item 7: a finished seed's CSV that contradicts its run's config is refused by run, plot and eval (one line naming the file
and the mismatch), through one shared check (:func:`imix_cli.running.results.check_seed_csv`).
Item 8: ``MixingES`` and ``make_es`` check every argument at construction, with the bounds ``imix run`` checks.
"""

from __future__ import annotations

import pytest

from imix_cli.commands.cli import main
from imix_cli.running.config import ConfigError, validate_overrides

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
    from imix_cli.running.config import config_dir as imix_conf

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


@pytest.mark.parametrize("name", [" x ", "x ", "\tx", "a\nb", "a\x7fb"])
def test_an_experiment_name_the_other_commands_cannot_address_is_refused(name):
    message = refused([*TINY, f"experiment='{name}'"])
    assert message.startswith(f"experiment={name!r}: must be a plain folder name"), message
