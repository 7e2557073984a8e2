"""Hostile and careless configs: YAML that cannot be read safely, values of a type no run writes, a command line Hydra's
grammar cannot lex -- each one line naming the file (or the key) and what to do, never a hang or a traceback.

Every YAML imix reads -- a ``--config-dir`` file and what its ``defaults`` pull, a run folder's ``config.yaml`` read back
by run, plot, eval and status -- passes one bounded loader (:mod:`imix_cli.running.files.safe_yaml`) before Hydra,
OmegaConf or a reader builds anything: more than 10,000 values once its aliases are expanded, nesting deeper than 64
levels, an alias inside its own anchor, a Python tag or more than 1 MiB are refused in one line naming the file.

Also issue 47's cases 6 (the library's unknown keyword is the command line's line, "did you mean" included), 9 (a run
folder made read-only mid-run is named with what to do), 10 (seeds set up and run in bounded groups) and 11 (a finished
run's broken policy file rebuilt by the same command).
"""

from __future__ import annotations

import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from imix_cli.commands.cli import main
from imix_cli.running.config.compose import ConfigError, config_dir, validate_overrides

REPO = Path(__file__).resolve().parents[1]
TINY = ["algo=snes", "env=cartpole", "seeds=1", "generations=2", "popsize=4", "workers=1", "progress=false"]
HEAD = "defaults:\n  - config\n  - _self_\nseeds: 1\ngenerations: 2\nworkers: 1\nprogress: false\n"


def alias_bomb(levels: int, key: str = "popsize") -> str:
    """A "billion laughs": anchors a, b, c, ... each a list of nine aliases of the previous one; ``key: *<last>``
    expands to 9**levels strings."""
    names = "abcdefghi"[:levels]
    text = "lols:\n  - &a [" + ", ".join(['"lol"'] * 9) + "]\n"
    text += "".join(f"  - &{name} [" + ", ".join([f"*{prev}"] * 9) + "]\n" for prev, name in zip(names, names[1:]))
    return text + f"{key}: *{names[-1]}\n"


def _limited():
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))  # a bomb that expands fails here, not the machine


def imix(args, cwd, timeout=120):
    """``imix ARGS`` in a subprocess (this worktree's imix), under a 3 GiB address-space limit; (result, seconds)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    started = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "imix_cli.commands.cli", *args], cwd=cwd, env=env, capture_output=True, text=True,
                            timeout=timeout, preexec_fn=_limited)  # fmt: skip
    return result, time.perf_counter() - started


def refused(overrides: list, **kwargs) -> str:
    with pytest.raises(ConfigError) as caught:
        validate_overrides(overrides, **kwargs)
    message = str(caught.value)
    assert "\n" not in message and len(message) < 400, message
    return message


# ------------------------------------------------------------------ 1. a billion laughs in a --config-dir
@pytest.mark.parametrize("levels", [9, 5])
@pytest.mark.parametrize("where", ["primary", "defaults"])
def test_an_alias_bomb_in_a_config_dir_is_refused_in_one_line_within_seconds(tmp_path, levels, where):
    """Before: nine levels ran Hydra's composition for minutes into gigabytes (killed at 120 s, 549 MB), five levels
    gave one line after 37 s at 330 MB. Now the file is refused before Hydra builds it, naming the file: in the
    primary config, or in a group option its ``defaults`` pull (``algo/bomb.yaml``)."""
    folder = tmp_path / "cfg"
    (folder / "algo").mkdir(parents=True)
    if where == "primary":
        (folder / "mycfg.yaml").write_text(HEAD + alias_bomb(levels))
        bad = folder / "mycfg.yaml"
    else:
        (folder / "mycfg.yaml").write_text("defaults:\n  - config\n  - override algo: bomb\n  - _self_\nseeds: 1\n")
        (folder / "algo" / "bomb.yaml").write_text("name: snes\n" + alias_bomb(levels, key="generations"))
        bad = folder / "algo" / "bomb.yaml"
    result, seconds = imix(["run", "--config-dir", str(folder), "--config-name", "mycfg", "results_dir=out"], tmp_path, timeout=60)
    err = result.stderr.strip()
    assert result.returncode == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err[:2000]
    assert str(bad) in err and "aliases are expanded" in err and len(err) < 400, err[:2000]
    assert seconds < 20, seconds  # ~1 s on a quiet machine: an interpreter's start-up and imports
    assert not (tmp_path / "out").exists()


HOSTILE_FILES = {
    "nested 100 deep": (HEAD + "popsize: " + "[" * 100 + "]" * 100 + "\n", "nested more than 64 levels deep"),
    "nested 100,000 deep": (HEAD + "popsize: " + "[" * 100_000 + "\n", "nested more than 64 levels deep"),  # a RecursionError before
    "an alias chain 100 deep": (
        HEAD + "chain:\n  - &a0 [1]\n" + "".join(f"  - &a{k} [*a{k - 1}]\n" for k in range(1, 100)) + "popsize: *a99\n",
        "levels deep once its aliases are expanded",
    ),
    "a recursive alias": (HEAD + "popsize: &a [*a]\n", "an alias inside its own anchor"),
    "a huge file": (HEAD + "note: '" + "x" * (2 << 20) + "'\n", "more than the 1,048,576 bytes a config may have"),
    "not YAML": (HEAD + "popsize: [1, 2\n", "not valid YAML (line"),
    "an undefined alias": (HEAD + "popsize: *nope\n", "found undefined alias"),
}


@pytest.mark.parametrize("name", list(HOSTILE_FILES))
def test_a_hostile_config_dir_file_is_one_line_naming_the_file(tmp_path, name):
    text, says = HOSTILE_FILES[name]
    (tmp_path / "mycfg.yaml").write_text(text)
    message = refused(["results_dir=out"], config_name="mycfg", config_dirs=(config_dir(), str(tmp_path)))
    assert message.startswith(f"{tmp_path / 'mycfg.yaml'}: ") and says in message, message


# ------------------------------------------------------------------ 5. a Python tag in a --config-dir file
def test_a_python_tag_in_a_config_dir_file_names_the_file_and_line_not_an_override(tmp_path, capsys, monkeypatch):
    """Before: exit 2, but "bad override (algo=cem, results_dir=out): could not determine a constructor for the tag ...":
    the overrides blamed, the file not named. The tag is never constructed either way."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cfg").mkdir()
    (tmp_path / "cfg" / "mycfg.yaml").write_text(HEAD + 'popsize: !!python/object/apply:os.system ["echo hi"]\n')
    assert main(["run", "--config-dir", "cfg", "--config-name", "mycfg", "algo=cem", "results_dir=out"]) == 2
    out = capsys.readouterr()
    err = out.err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"{tmp_path / 'cfg' / 'mycfg.yaml'}: line 8: the tag !!python/object/apply:os.system is not allowed" in err, err
    assert "bad override" not in err and "hi" not in out.out
    assert not (tmp_path / "out").exists()


def test_the_configs_imix_writes_and_ships_pass_the_bounded_loader(tmp_path):
    """The other side: conf/ (every file) and a run's own config.yaml are read as before."""
    from imix_cli.running.files.safe_yaml import check_yaml_file, load_yaml_file

    for path in Path(config_dir()).rglob("*.yaml"):
        check_yaml_file(path)
    assert main(["run", *TINY, f"results_dir={tmp_path}"]) == 0
    (config,) = tmp_path.glob("default/*/config.yaml")
    assert load_yaml_file(config)["popsize"] == 4


# ------------------------------------------------------------------ 2. the bomb in a run folder's config.yaml
def _finished_run(tmp_path_factory, name: str, args) -> Path:
    """The run folder of ``imix run args`` in a new folder ``name``."""
    root = tmp_path_factory.mktemp(name) / "results"
    assert main(["run", *args, f"results_dir={root}"]) == 0
    (run_dir,) = root.glob("default/*")
    return run_dir


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    return _finished_run(tmp_path_factory, "hostile", TINY)


@pytest.fixture
def run_dir(finished, tmp_path):
    """A private copy of the finished run (results_dir ``tmp_path/results``)."""
    return Path(shutil.copytree(finished, tmp_path / "results" / "default" / finished.name))


def set_config(run_dir: Path, old: str, new: str) -> Path:
    path = run_dir / "config.yaml"
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    return path


@pytest.mark.parametrize("levels", [9, 5])
def test_an_alias_bomb_in_a_run_folders_config_yaml_is_a_short_line_naming_it(run_dir, tmp_path, levels):
    """Before: ``imix run`` printed one line of 1,254,392 bytes (the value's repr, ~46,656 elements per key); plot, eval
    and status read the bomb as a config. Now each command says, in a line of < 400 characters, that the file is refused."""
    config = set_config(run_dir, "popsize: 4\n", alias_bomb(levels))
    root = tmp_path / "results"
    result, _ = imix(["run", *TINY, f"results_dir={root}"], tmp_path)
    err = result.stderr.strip()
    assert result.returncode == 1 and len(err.splitlines()) == 1 and len(err) < 400, err[:2000]
    assert str(config) in err and "aliases are expanded" in err, err
    for command in (["plot", "only=iqm"], ["eval", "episodes=2"], ["status"]):
        result, _ = imix([*command, f"results_dir={root}"], tmp_path)
        lines = result.stderr.splitlines()
        assert "Traceback" not in result.stderr and all(len(line) < 400 for line in lines), (command, result.stderr[:2000])
        assert all(len(line) < 400 for line in result.stdout.splitlines()), (command, result.stdout[:2000])
        if command[0] != "status":  # plot and eval say why they go on without it; status lists the seeds found
            assert any(str(config) in line and "aliases are expanded" in line for line in lines), (command, result.stderr)


def test_a_long_value_in_a_run_folders_config_yaml_is_shown_shortened(run_dir, tmp_path, capsys):
    """Any value a message shows from a file is shortened: lists of six lists five levels deep (9,331 values, within the
    loader's bounds) made a line of ~50 kB (reprlib shortens each level to six items, not the whole)."""
    import json

    def nested(levels):
        return 123456 if levels == 0 else [nested(levels - 1)] * 6

    config = set_config(run_dir, "popsize: 4\n", f"popsize: {json.dumps(nested(5))}\n")
    assert main(["run", *TINY, f"results_dir={tmp_path / 'results'}"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and len(err) < 600 and str(config) in err and "popsize=" in err, err[:2000]


# ------------------------------------------------------------------ 3. a value of a type no run writes in config.yaml
WRONG_TYPES = {
    "popsize a list": ("popsize: 4\n", "popsize: [1, 2]\n", "popsize=[1, 2]"),
    "popsize a string": ("popsize: 4\n", "popsize: '4'\n", "popsize='4'"),
    "popsize a float": ("popsize: 4\n", "popsize: 4.0\n", "popsize=4.0"),
    "popsize a bool": ("popsize: 4\n", "popsize: true\n", "popsize=True"),
    "generations a list": ("generations: 2\n", "generations: [2]\n", "generations=[2]"),
    "eval_mean_every a mapping": ("eval_mean_every: 10\n", "eval_mean_every: {a: 1}\n", "eval_mean_every={'a': 1}"),
}


@pytest.mark.parametrize("name", list(WRONG_TYPES))
def test_plot_and_eval_refuse_a_config_yaml_value_of_a_type_no_run_writes(run_dir, tmp_path, capsys, name):
    """Before: ``popsize: [1,2]`` (unlike ``popsize: 7``) was "not compared": plot and eval used the CSVs without a word."""
    from imix_cli.plotting.data import load_experiment

    old, new, says = WRONG_TYPES[name]
    config = set_config(run_dir, old, new)
    warnings = []
    experiment = load_experiment(tmp_path / "results", "default", warn=warnings.append)
    assert experiment.groups == [] and any(str(config) in w and says in w for w in warnings), warnings
    capsys.readouterr()
    assert main(["eval", f"results_dir={tmp_path / 'results'}", "episodes=2"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(config) in err and says in err, err
    assert not (run_dir / "eval.csv").exists()


# ------------------------------------------------------------------ 12. a value Hydra's grammar cannot read unquoted
@pytest.mark.parametrize(
    "override, key, value",
    [("experiment=é", "experiment", "é"), ("experiment=résumé", "experiment", "résumé"), ("experiment=a)b", "experiment", "a)b"),
     ("env.id=müenv:Reach-v0", "env.id", "müenv:Reach-v0")],
)  # fmt: skip
def test_a_value_the_override_grammar_cannot_read_unquoted_gets_a_hint_to_quote_it(tmp_path, capsys, monkeypatch, override, key, value):
    """Before: "cannot parse overrides: LexerNoViableAltException: experiment=é" -- Hydra's lexer, no word of what to do.
    Now one line naming the override and the quoted form to type; that form runs (test_a_quoted_unicode_value_runs)."""
    monkeypatch.chdir(tmp_path)
    assert main(["run", *TINY, "results_dir=out", override]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert "LexerNoViableAltException" not in err and f"{override}: " in err and f"\"{key}='{value}'\"" in err, err
    assert not (tmp_path / "out").exists()


def test_a_value_that_cannot_be_read_in_a_sweep_names_it_too():
    message = refused([*TINY, "sigma=0.1,é"])
    assert "sigma=0.1,é: " in message and "quote" in message and "LexerNoViableAltException" not in message, message


def test_a_quoted_unicode_value_runs(tmp_path):
    (spec,) = validate_overrides([*TINY, f"results_dir={tmp_path}", "experiment='é'"])
    assert spec.experiment == "é"


# ------------------------------------------------------------------ 4. values that cannot be in a seed CSV
MEASURED = [*TINY, "eval_mean_every=1", "eval_mean_episodes=2"]  # the distribution mean measured on every row


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    return _finished_run(tmp_path_factory, "values", MEASURED)


def set_cells(csv: Path, **cells) -> None:
    """Set the last row's ``cells`` (column -> text as written in the CSV)."""
    lines = csv.read_text().splitlines()
    header = lines[0].split(",")
    last = lines[-1].split(",")
    for column, text in cells.items():
        last[header.index(column)] = text
    csv.write_text("\n".join([*lines[:-1], ",".join(last)]) + "\n")


IMPOSSIBLE = {  # cells of the last row -> what the line says
    "scores 1e308": ({"mean_score": "1e308", "best_score": "1e308"}, "not a return of cartpole"),
    "best_score 201 (CartPole's most is 200)": ({"best_score": "201"}, "not a return of cartpole"),
    "mean_score -1 (CartPole's least is 0)": ({"mean_score": "-1"}, "not a return of cartpole"),
    "best_score inf": ({"best_score": "inf"}, "best_score"),
    "mean_score -inf": ({"mean_score": "-inf"}, "mean_score"),
    "mean_score NaN with every member finite": ({"mean_score": "nan"}, "mean_score"),
    "mean_policy_score 1e308": ({"mean_policy_score": "1e308"}, "not a return of cartpole"),
    "mean_policy_score inf": ({"mean_policy_score": "inf"}, "mean_policy_score"),
    "mean_score above best_score": ({"mean_score": "150", "best_score": "100"}, "above best_score"),
    "mean_score a word": ({"mean_score": "lots"}, "mean_score"),
}


@pytest.mark.parametrize("name", list(IMPOSSIBLE))
def test_a_seed_csv_value_that_cannot_be_is_refused_by_run_plot_eval_and_status(measured, tmp_path, capsys, name):
    """Before: 1e308, inf and NaN scores were accepted -- plot's iqm table counted a CartPole seed scoring 1e308 as
    reaching 195, status printed a 309-digit number. Checkpoints were checked against the env's possible returns; CSVs
    now are too, with the same bounds (imix_cli.running.loop.resume.env_return_bounds), by every reader."""
    from imix_cli.plotting.data import load_experiment

    cells, says = IMPOSSIBLE[name]
    root = tmp_path / "results"
    run_dir = Path(shutil.copytree(measured, root / "default" / measured.name))
    csv = run_dir / "seed_0.csv"
    set_cells(csv, **cells)
    warnings = []
    assert load_experiment(root, "default", warn=warnings.append).groups == []  # no seed for the iqm table
    assert any(str(csv) in w and says in w for w in warnings), warnings
    capsys.readouterr()
    assert main(["run", *MEASURED, f"results_dir={root}"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(csv) in err and says in err, err
    assert main(["eval", f"results_dir={root}", "episodes=2"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(csv) in err and says in err, err
    assert main(["status", f"results_dir={root}"]) == 0
    out = capsys.readouterr().out
    assert "seed_0.csv" in out and says in out and not re.search(r"\d{20}", out), out  # named as a file to move away


def test_status_shows_a_partial_csvs_impossible_score_as_a_problem_not_309_digits(measured, tmp_path, capsys):
    """A stopped seed's partial CSV is read by status alone: the same check, and numbers printed in a bounded form."""
    root = tmp_path / "results"
    run_dir = Path(shutil.copytree(measured, root / "default" / measured.name))
    (run_dir / "seed_0.csv").rename(run_dir / "seed_0.partial.csv")
    set_cells(run_dir / "seed_0.partial.csv", mean_score="1e308", best_score="1e308")
    assert main(["status", f"results_dir={root}"]) == 0
    out = capsys.readouterr().out
    assert "not a return of cartpole" in out and not re.search(r"\d{20}", out), out


@pytest.mark.parametrize("line, says", [("algo: !!str 4", "algo='4': must be a config of the algo group"), ("algo: 4", "algo=4: must be"),
                                        ("env: 3", "env=3: must be a config of the env group")])  # fmt: skip
def test_what_the_config_fuzzer_found_is_one_line(tmp_path, line, says):
    """A value where a config group goes (``algo: '4'``) was an AttributeError ('str' object has no attribute 'get')."""
    (tmp_path / "mycfg.yaml").write_text(HEAD + line + "\n")
    assert says in refused(["results_dir=out"], config_name="mycfg", config_dirs=(config_dir(), str(tmp_path)))


# ------------------------------------------------------------------ 6. the library's keyword errors are the command line's
@pytest.mark.parametrize(
    "keywords, override, suggested",
    [({"popsze": 10}, ["popsze=10"], "'popsize'"), ({"sigmaa": 0.1}, ["sigmaa=0.1"], "'sigma'"),
     ({"policy": {"hiden": [4]}}, ["policy.hiden=[4]"], "'policy.hidden'"),
     ({"algo": "cem", "algo.stlye": "x"}, ["algo=cem", "algo.stlye=x"], "'algo.style'"), ({"zzzzqqq": 1}, ["zzzzqqq=1"], None)],
)  # fmt: skip
def test_the_librarys_unknown_keyword_is_the_command_lines_one_line(tmp_path, capsys, monkeypatch, keywords, override, suggested):
    """Before: ``imix_cli.run(popsze=10)`` and ``Experiment(sigmaa=...)`` said "unknown key 'popsze'; valid keys: ..."
    without the command line's "did you mean". Now one function words both (``compose.unknown_key_message``)."""
    import imix_cli

    monkeypatch.chdir(tmp_path)
    with pytest.raises(imix_cli.ConfigError) as caught:
        imix_cli.run(**keywords, results_dir="out", experiment="lib")
    assert main(["run", *override, "results_dir=out"]) == 2
    cli = capsys.readouterr().err.strip().removeprefix("imix run: error: ")
    assert str(caught.value) == cli, (str(caught.value), cli)
    assert ("did you mean" not in cli) if suggested is None else f"did you mean {suggested}?" in cli, cli
    with pytest.raises(imix_cli.ConfigError, match=re.escape(cli)):
        imix_cli.Experiment(**keywords)
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------ 9. a run folder made read-only mid-run
@pytest.mark.parametrize("how", ["rename", "create", "mkdir"])
def test_a_run_folder_made_read_only_mid_run_is_named_with_what_to_do(tmp_path, capsys, monkeypatch, how):
    """Before: ``chattr +i`` on the run folder mid-run ended with "cannot write .seed_1.partial.csv.3d89911e.tmp:
    Operation not permitted" (or ".checkpoints"): a bare temporary, no folder, nothing to do. Now the line names the run
    folder, the file and what to do, and a re-run once the folder is writable resumes and finishes. Simulated (root
    writes through ``chmod a-w``): the writer's rename, its create of the temporary, or the checkpoints' folder's
    ``mkdir`` refused with EPERM / EROFS after the run started, as ``chattr +i`` or a read-only remount refuse them."""
    import errno

    monkeypatch.chdir(tmp_path)
    args = ["run", *TINY, "generations=30", "checkpoint_every=5", "checkpoint_seconds=0", "results_dir=out"]
    real = {"rename": os.replace, "create": os.open, "mkdir": os.mkdir}[how]
    calls = {"n": 0}

    def refused_after_a_while(*a, **k):
        name = str(a[0])
        ours = name.endswith(".tmp") and ".partial.csv" in name if how != "mkdir" else name == ".checkpoints"
        if ours:
            calls["n"] += 1
            if calls["n"] > (1 if how != "mkdir" else 0):
                code = errno.EROFS if how == "create" else errno.EPERM
                raise OSError(code, os.strerror(code), name)
        return real(*a, **k)

    monkeypatch.setattr(os, {"rename": "replace", "create": "open", "mkdir": "mkdir"}[how], refused_after_a_while)
    assert main(args) == 1
    err = capsys.readouterr().err.strip()
    (run_dir,) = (tmp_path / "out" / "default").iterdir()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"cannot write in the run folder out/default/{run_dir.name} (" in err, err
    assert "make it writable" in err and "re-run the same command: the run resumes from its checkpoints" in err, err
    assert ".tmp" not in err, err
    monkeypatch.undo()  # the folder writable again: the same command resumes and finishes
    monkeypatch.chdir(tmp_path)
    assert main(args) == 0, capsys.readouterr().err
    assert (run_dir / "seed_0.csv").exists() and not list(run_dir.glob(".*.tmp"))


# ------------------------------------------------------------------ 11. a finished run's broken policy file
@pytest.mark.parametrize("checkpoints", ["final state", "checkpoint_every=0"])
def test_a_broken_policy_file_of_a_finished_run_is_rebuilt_by_the_same_command(tmp_path, capsys, monkeypatch, checkpoints):
    """Before: a truncated ``policy_0_mean.npz`` in a finished run: re-running the command exited 0 with "0 seed(s) run
    now" and left the broken file (``imix eval`` then refused it). Now the re-run reads every finished seed's policy
    files back, says in one line which one is broken, and writes it again: from the seed's final checkpoint (the same
    params and header, the CSV untouched), or, with none (``checkpoint_every=0``), by running the seed again."""
    import pandas as pd

    from imix_cli.running.files.policy_files import read_policy

    monkeypatch.chdir(tmp_path)
    args = ["run", *TINY, "seeds=2", "generations=6", "results_dir=out"] + (["checkpoint_every=0"] if checkpoints != "final state" else [])
    assert main(args) == 0
    capsys.readouterr()
    (run_dir,) = (tmp_path / "out" / "default").iterdir()
    good = {which: read_policy(run_dir / f"policy_0_{which}.npz") for which in ("mean", "best")}
    csv = (run_dir / "seed_0.csv").read_bytes()
    broken = run_dir / "policy_0_mean.npz"
    broken.write_bytes(broken.read_bytes()[:300])  # truncated
    assert main(args) == 0
    out = capsys.readouterr()
    lines = out.err.strip().splitlines()
    assert len(lines) == 1 and "policy_0_mean.npz: not a readable imix policy file" in lines[0], out.err
    if checkpoints == "final state":
        assert "rebuilding it from seed 0's final checkpoint" in lines[0], lines
        assert (run_dir / "seed_0.csv").read_bytes() == csv  # only the policy files are written again
    else:
        assert "no final state to rebuild it from (checkpoint_every=0): running it again from generation 0" in lines[0], lines
        again = pd.read_csv(run_dir / "seed_0.csv").drop(columns="wall_time")
        pd.testing.assert_frame_equal(again, pd.read_csv(pd.io.common.BytesIO(csv)).drop(columns="wall_time"))
    assert "1 seed(s) run now" in out.out, out.out
    for which, policy in good.items():
        rebuilt = read_policy(run_dir / f"policy_0_{which}.npz")
        assert (rebuilt.params == policy.params).all() and rebuilt.header == policy.header
    assert main(args) == 0  # and then the run is whole again
    out = capsys.readouterr()
    assert "0 seed(s) run now" in out.out and not out.err.strip(), out


# ------------------------------------------------------------------ 10. seeds streamed, not all set up first
def test_a_workers_seeds_are_set_up_and_run_in_bounded_groups_with_the_same_results(tmp_path, capsys, monkeypatch):
    """Before: a worker set up every seed of its share (``seeds=100000``: 50,000 states) before running any, and ran
    them all in one lockstep: memory grew with ``seeds`` and the first CSV came only when every seed had finished. Now
    a worker holds at most :data:`~imix_cli.running.trainers.SEED_GROUP` seeds at once, the first group's CSVs written
    before the next group is set up -- and the CSVs and policy files are those of one lockstep over every seed."""
    import pandas as pd

    import imix_cli.running.loop.es_seeds as es_seeds
    from imix_cli.running.files import run_writer
    from imix_cli.running.files.results import read_run_csv
    from imix_cli.running.trainers import SEED_GROUP

    monkeypatch.chdir(tmp_path)
    seeds = SEED_GROUP + 6
    args = ["run", *TINY, f"seeds={seeds}", "generations=3"]
    held, set_up, at_first_csv = [], [0], []
    real_loop, real_setup, real_csv = es_seeds._run_loop, es_seeds.new_seed_state, run_writer.write_run_csv

    def counting_loop(settings, states, *a, **k):
        held.append(len(states))
        return real_loop(settings, states, *a, **k)

    def counting_setup(*a, **k):
        set_up[0] += 1
        return real_setup(*a, **k)

    def first_csv(*a, **k):
        at_first_csv.append(set_up[0])
        return real_csv(*a, **k)

    monkeypatch.setattr(es_seeds, "_run_loop", counting_loop)
    monkeypatch.setattr(es_seeds, "new_seed_state", counting_setup)
    monkeypatch.setattr(run_writer, "write_run_csv", first_csv)
    assert main([*args, "results_dir=grouped"]) == 0
    assert max(held) <= SEED_GROUP and sum(held) == seeds, held  # before: [70]
    assert at_first_csv[0] <= SEED_GROUP, at_first_csv[0]  # before: 70 seeds set up before the first CSV
    monkeypatch.setattr(es_seeds, "SEED_GROUP", 10**9)  # one lockstep over every seed: the results as they were
    assert main([*args, "results_dir=whole"]) == 0
    grouped, whole = (next((tmp_path / root / "default").iterdir()) for root in ("grouped", "whole"))
    for seed in range(seeds):
        a, b = (read_run_csv(folder / f"seed_{seed}.csv").drop(columns="wall_time") for folder in (grouped, whole))
        pd.testing.assert_frame_equal(a, b)
        assert (grouped / f"policy_{seed}_mean.npz").read_bytes() == (whole / f"policy_{seed}_mean.npz").read_bytes()


@pytest.mark.slow
def test_a_hundred_thousand_seeds_write_csvs_within_seconds_and_sigterm_keeps_them(tmp_path):
    """Before: ``seeds=100000``: no CSV after 60 s, memory growing ~5 MB/s a worker, and a SIGTERM saved nothing (the
    worker was still setting seeds up). Now the first group's CSVs come within seconds (measured: 15 s with two workers on
    the loaded 2-core VM, most of it start-up), and a SIGTERM keeps them: exit 143, the finished seeds' CSVs on disk."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    args = ["run", "algo=snes", "env=cartpole", "seeds=100000", "generations=3", "popsize=4", "workers=1", "progress=false", "results_dir=out"]
    proc = subprocess.Popen([sys.executable, "-m", "imix_cli.commands.cli", *args], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_limited)  # fmt: skip
    try:
        deadline, first = time.monotonic() + 60, None
        while first is None and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)
            first = next((p for p in tmp_path.glob("out/default/*/seed_*.csv") if ".partial" not in p.name), None)
        assert first is not None, f"no seed CSV after 60 s ({proc.poll()=})"
        rss_kb = int(re.search(r"VmRSS:\s+(\d+)", Path(f"/proc/{proc.pid}/status").read_text()).group(1))
        assert rss_kb < 1_000_000, rss_kb
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 143 and "terminated (SIGTERM)" in err, err
    kept = [p for p in first.parent.glob("seed_*.csv") if ".partial" not in p.name]
    assert len(kept) >= 64, len(kept)


# ------------------------------------------------------------------ the fuzzer: 1,000 hostile --config-dir files
TAGS = ["!!python/object/apply:os.system [x]", "!!python/name:os.system", "!!python/object:os.system {}", "!!binary aGk=", "!!set {a: null}",
        "!!timestamp 2001-12-14", "!custom x", "!!omap [{a: 1}]", "!!str 4", "!!int '4'", "!!float 4"]  # fmt: skip


def random_config(rng) -> tuple[str, dict]:
    """A ``--config-dir``'s primary config (and maybe a group option its defaults pull): a valid head, then one hostile
    part -- anchors and aliases of random fan-out and depth, a tag, deep nesting, a huge scalar, broken bytes."""
    key = rng.choice(["popsize", "seeds", "sigma", "note", "algo"])
    kind = rng.choice(["aliases", "aliases", "tag", "nesting", "scalar", "broken", "merge"])
    if kind == "aliases":
        fan, levels = rng.randint(1, 12), rng.randint(1, 10)
        body = "lols:\n  - &l0 [" + ", ".join(["x"] * fan) + "]\n"
        body += "".join(f"  - &l{k} [" + ", ".join([f"*l{k - 1}"] * fan) + "]\n" for k in range(1, levels))
        part = body + f"{key}: *l{levels - 1}\n"
    elif kind == "merge":
        part = "base: &b {popsize: 4, sigma: 0.1}\n" + f"{key}:\n  <<: *b\n"
    elif kind == "tag":
        part = f"{key}: {rng.choice(TAGS)}\n"
    elif kind == "nesting":
        n = rng.choice([1, 10, 63, 64, 65, 200, 5000])
        part = f"{key}: " + rng.choice(["[" * n + "1" + "]" * n, "{a: " * n + "1" + "}" * n, "[" * n]) + "\n"
    elif kind == "scalar":
        part = f"{key}: '" + "x" * rng.choice([10, 1000, 100_000, 1_100_000]) + "'\n"
    else:
        part = f"{key}: [1, 2\n" if rng.random() < 0.5 else f"{key}: " + "".join(rng.choice("\x00\x07\t\n:-[]{}&*!|>'\"%@`#,? aé漢") for _ in range(40)) + "\n"
    if rng.random() < 0.3:  # the hostile part in a group option the defaults pull
        option = "name: snes\n" + part.replace(f"{key}:", "generations:")
        return HEAD.replace("  - _self_", "  - override algo: hostile\n  - _self_"), {"algo/hostile.yaml": option}
    return HEAD + part, {}


@pytest.mark.slow
def test_fuzz_config_dir_files(tmp_path):
    """1,000 random hostile ``--config-dir`` files through validation (in-process, each under a 20 s alarm): accepted, or
    refused with one line of < 1,000 characters -- never another exception, never a hang."""
    import signal

    def alarm(signum, frame):
        raise TimeoutError

    rng = random.Random(20261129)
    previous = signal.signal(signal.SIGALRM, alarm)
    tally = {"accepted": 0, "refused": 0}
    try:
        for k in range(1000):
            folder = tmp_path / f"case{k}"
            (folder / "algo").mkdir(parents=True)
            primary, others = random_config(rng)
            (folder / "mycfg.yaml").write_text(primary)
            for name, text in others.items():
                (folder / name).write_text(text)
            signal.alarm(20)
            try:
                validate_overrides(["results_dir=out"], config_name="mycfg", config_dirs=(config_dir(), str(folder)))
                tally["accepted"] += 1
            except ConfigError as err:
                assert "\n" not in str(err) and len(str(err)) < 1000, f"case {k}: {str(err)[:3000]!r}"
                tally["refused"] += 1
            except TimeoutError:
                pytest.fail(f"case {k}: validation hangs on {primary[:300]!r} {str(others)[:300]}")
            except Exception as err:  # noqa: BLE001 - a traceback a user would see
                pytest.fail(f"case {k}: {type(err).__name__}: {str(err)[:300]} on {primary[:300]!r} {str(others)[:300]}")
            finally:
                signal.alarm(0)
            shutil.rmtree(folder)
    finally:
        signal.signal(signal.SIGALRM, previous)
    print(tally)
    assert tally["accepted"] > 20 and tally["refused"] > 500
