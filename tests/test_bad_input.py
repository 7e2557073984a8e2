"""Malformed invocations: one line naming the problem, exit != 0, no traceback, nothing overwritten.

Each case runs `imix run` in-process (imix_cli.commands.cli.main) against a results folder that already
holds a finished run; the folder's bytes must be identical afterwards. The finished run is made
once per module and shared by the cases that must leave it alone; the cases that plant a bad
file in it first work on a copy of their own.
"""

import hashlib
import shutil
from pathlib import Path

import pytest

from imix_cli.commands.cli import main

BASE = ["algo=cem", "seeds=1", "generations=3", "popsize=8", "workers=1", "progress=false"]
RUN_DIR = "default/cem-cartpole-none-popsize=8"


def snapshot(root: Path) -> dict:
    return {p.relative_to(root): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    """A results folder with one finished run in it (what must never be overwritten), and its snapshot."""
    root = tmp_path_factory.mktemp("bad_input") / "results"
    assert main(["run", *BASE, f"results_dir={root}"]) == 0
    return root, snapshot(root)


@pytest.fixture
def results(finished_run, tmp_path):
    """A private copy of the finished run, for the cases that plant a bad file in it first."""
    root, _ = finished_run
    return Path(shutil.copytree(root, tmp_path / "results"))


# (id, extra overrides, expected exit code, text the one-line message must contain)
CASES = [
    ("unknown algo", ["algo=ppo"], 2, "algo=ppo"),
    ("unknown env", ["env=pong"], 2, "env=pong"),
    ("unknown key", ["popsiz=10"], 2, "popsiz"),
    ("popsize not a number", ["popsize=abc"], 2, "popsize"),
    ("popsize fractional", ["popsize=2.5"], 2, "popsize"),
    ("popsize too small", ["popsize=1"], 2, "popsize"),
    ("sigma zero", ["sigma=0"], 2, "sigma"),
    ("sigma negative", ["sigma=-1"], 2, "sigma"),
    ("sigma a list", ["sigma=[1,2]"], 2, "sigma"),
    ("lr zero", ["lr=0"], 2, "lr"),
    ("lr negative", ["lr=-0.1"], 2, "lr"),
    ("seeds zero", ["seeds=0"], 2, "seeds"),
    ("generations zero", ["generations=0"], 2, "generations"),
    ("workers zero", ["workers=0"], 2, "workers"),
    ("weight_decay negative", ["weight_decay=-1"], 2, "weight_decay"),
    ("eim_generations zero", ["eim_generations=0"], 2, "eim_generations"),
    ("checkpoint_every negative", ["checkpoint_every=-1"], 2, "checkpoint_every"),
    ("im not a bool", ["im=maybe"], 2, "im"),
    ("unknown im_variant", ["im_variant=magic"], 2, "im_variant"),
    ("contradictory eim + sun2009", ["eim=true", "im_variant=sun2009"], 2, "im_variant"),
    ("alpha without sun2009", ["im=true", "im_alpha=0.2"], 2, "im_alpha"),
    ("alpha out of range", ["im=true", "im_variant=sun2009", "im_alpha=1.5"], 2, "im_alpha"),
    ("unknown gymnasium id", ["env=gym", "env.id=NoSuchEnv-v0"], 2, "NoSuchEnv-v0"),
    ("gym without id", ["env=gym"], 2, "env.id"),
    ("env.max_steps zero", ["env.max_steps=0"], 2, "env.max_steps"),
    ("experiment with a path", ["experiment=../elsewhere"], 2, "experiment"),
    ("unknown launcher", ["hydra/launcher=nope"], 2, "hydra/launcher=nope"),
    ("workers>1 under joblib", ["-m", "hydra/launcher=joblib", "workers=2"], 2, "workers"),
    ("bad point in a sweep", ["-m", "popsize=8,0"], 2, "popsize"),
]


# the joblib launcher plugin comes with the cluster extra (make install-all)
CLUSTER = pytest.mark.cluster


@pytest.mark.parametrize("extra, code, text", [pytest.param(*c[1:], id=c[0], marks=CLUSTER if "hydra/launcher=joblib" in c[1] else ()) for c in CASES])
def test_malformed_invocation(finished_run, capsys, extra, code, text):
    results, written = finished_run
    flags = [a for a in extra if a.startswith("-")]
    overrides = [a for a in extra if not a.startswith("-")]
    assert main(["run", *flags, *BASE, *overrides, f"results_dir={results}"]) == code
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert text in err and "Traceback" not in err, err
    assert snapshot(results) == written


def test_unwritable_results_dir(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    assert main(["run", *BASE, f"results_dir={blocker / 'results'}"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "results_dir" in err, err
    assert blocker.read_text() == "not a folder"


def test_corrupt_csv_already_in_the_folder(results, capsys):
    bad = results / RUN_DIR / "seed_1.csv"
    bad.write_text("algo,env\ncem,cartpole,extra,fields\n")
    before = snapshot(results)
    assert main(["run", *[a for a in BASE if not a.startswith("seeds")], "seeds=2", f"results_dir={results}"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "seed_1.csv" in err, err
    assert snapshot(results) == before


@pytest.mark.parametrize("column", ["reevaluated", "diverged", "mean_policy_score"])
def test_a_csv_without_a_column_of_the_contract_is_refused_by_name(results, capsys, column):
    """Every column of the CSV contract is required: a seed CSV without one is refused (one line naming the
    file and the column) by the run that would extend the folder, which leaves it untouched."""
    import pandas as pd

    bad = results / RUN_DIR / "seed_0.csv"
    pd.read_csv(bad).drop(columns=column).to_csv(bad, index=False)
    before = snapshot(results)
    assert main(["run", *[a for a in BASE if not a.startswith("seeds")], "seeds=2", f"results_dir={results}"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "seed_0.csv" in err and column in err, err
    assert snapshot(results) == before


def test_config_yaml_of_a_different_config_in_the_target_folder(results, capsys):
    config = results / RUN_DIR / "config.yaml"
    text = config.read_text()
    assert "\nsigma: 0.25\n" in text
    config.write_text(text.replace("\nsigma: 0.25\n", "\nsigma: 0.5\n"))
    before = snapshot(results)
    assert main(["run", *BASE, f"results_dir={results}"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "config.yaml" in err, err
    assert "(sigma=0.5 there, 0.25 now)" in err, err  # names exactly the key that differs
    assert snapshot(results) == before


def test_full_disk_while_writing(results, capsys, csv_disk_full):
    """ENOSPC while a seed's CSV is written: one line, and no partial file at any final name."""
    before = snapshot(results)
    assert main(["run", *[a for a in BASE if not a.startswith("seeds")], "seeds=2", f"results_dir={results}"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "No space left on device" in err, err
    after = snapshot(results)
    assert {k: v for k, v in after.items() if k in before} == before  # nothing existing changed
    # nothing partial; the seed's final state, saved before its CSV, may wait in its checkpoint for a re-run to write its CSV from
    assert not [p for p in after if (p.name.startswith("seed_1") and ".checkpoints" not in p.parts) or p.suffix == ".tmp"]
