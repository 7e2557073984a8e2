"""The experiment runner through its real entry point, `imix run` (imix_cli.commands.cli.main).

Runs are tiny (a few generations, small populations) so the whole file stays fast; what is
checked is the contract: validation before any work, the CSV schema and folder layout,
determinism across repeats and worker counts, and one end-to-end run per algorithm and env.
"""

import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from imix_cli.commands.cli import main
from imix_cli.running.config.compose import config_dir, validate_overrides
from imix_cli.running.files.results import COLUMNS, read_run_csv

TINY = ["generations=4", "seeds=2", "popsize=8", "progress=false", "workers=1"]


def imix(*args, results_dir):
    return main(["run", *args, f"results_dir={results_dir}"])


def all_files(root: Path):
    return sorted(p for p in Path(root).rglob("*") if p.is_file()) if Path(root).exists() else []


@pytest.mark.parametrize("algo", ["openes", "snes", "cem", "cmaes"])
@pytest.mark.parametrize("env", ["cartpole", "acrobot"])
def test_end_to_end_every_algo_and_env(tmp_path, algo, env):
    # checkpoint_every=1: every generation but the last writes a checkpoint that must be gone at the end
    assert imix(f"algo={algo}", f"env={env}", "eim=true", "checkpoint_every=1", "checkpoint_seconds=0", *TINY, results_dir=tmp_path) == 0
    run_dir = tmp_path / "default" / f"{algo}-{env}-eim-popsize=8"
    for seed in range(2):
        frame = read_run_csv(run_dir / f"seed_{seed}.csv")
        assert list(frame.columns) == list(COLUMNS)
        assert len(frame) == 4
        assert (frame["algo"] == algo).all() and (frame["env"] == env).all() and (frame["mixing"] == "eim").all()
        assert (frame["seed"] == seed).all()
        assert frame["evaluations"].is_monotonic_increasing and frame["env_steps"].is_monotonic_increasing
        assert frame["evaluations"].iloc[0] == 8  # generation 0: everything is fresh
        assert (frame["reused"] == frame["reused_im"] + frame["reused_eim"]).all()
        # evaluations grow by exactly the fresh members of each generation (and CMA-ES's two TPA points)
        fresh = frame["popsize"] - frame["reused"] + (2 if algo == "cmaes" else 0)
        assert (frame["evaluations"].diff().iloc[1:] == fresh.iloc[1:]).all()
        assert frame["reused"].iloc[1:].sum() > 0
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert config["algo"]["name"] == algo and config["popsize"] == 8 and config["mixing"] == "eim"
    # a finished run leaves no temporaries (.*.tmp) or partial CSVs behind, hidden files included:
    # only its config, lock file (free once the run ends), policies, CSVs and each seed's final
    # state (from which a larger generations= continues it)
    policies = [f"policy_{k}_{which}.npz" for k in (0, 1) for which in ("best", "mean")]
    finals = [f".checkpoints/seed_{k}.npz" for k in (0, 1)]
    expected = sorted([".lock", "config.yaml", *policies, *finals, "seed_0.csv", "seed_1.csv"])
    assert sorted(p.relative_to(run_dir).as_posix() for p in all_files(run_dir)) == expected


def read_without_wall_time(path):
    return pd.read_csv(path).drop(columns=["wall_time"])


def test_same_seed_same_csv_across_repeats_and_worker_counts(tmp_path):
    args = ["algo=snes", "env=cartpole", "eim=true", "generations=6", "seeds=3", "popsize=10", "progress=false"]
    assert main(["run", *args, "workers=1", f"results_dir={tmp_path / 'a'}"]) == 0
    assert main(["run", *args, "workers=1", f"results_dir={tmp_path / 'b'}"]) == 0
    assert main(["run", *args, "workers=2", f"results_dir={tmp_path / 'c'}"]) == 0
    for seed in range(3):
        name = f"default/snes-cartpole-eim-popsize=10/seed_{seed}.csv"
        a = read_without_wall_time(tmp_path / "a" / name)
        pd.testing.assert_frame_equal(a, read_without_wall_time(tmp_path / "b" / name))
        pd.testing.assert_frame_equal(a, read_without_wall_time(tmp_path / "c" / name))
    # and different seeds really differ
    s0 = read_without_wall_time(tmp_path / "a/default/snes-cartpole-eim-popsize=10/seed_0.csv")
    s1 = read_without_wall_time(tmp_path / "a/default/snes-cartpole-eim-popsize=10/seed_1.csv")
    assert not s0["mean_score"].equals(s1["mean_score"])


def test_folder_names_carry_non_paper_hyperparameters(tmp_path):
    assert imix("algo=openes", "im=true", "im_variant=sun2009", "im_alpha=0.1", "sigma=0.1", *TINY, results_dir=tmp_path) == 0
    assert (tmp_path / "default" / "openes-cartpole-im-im_alpha=0.1,im_variant=sun2009,popsize=8,sigma=0.1" / "seed_0.csv").exists()
    assert imix("algo=cem", "popsize=50", "generations=2", "seeds=1", "progress=false", "workers=1", results_dir=tmp_path) == 0
    assert (tmp_path / "default" / "cem-cartpole-none" / "seed_0.csv").exists()


def test_finished_seeds_are_skipped_and_more_seeds_extend_the_run(tmp_path):
    assert imix("algo=cem", *TINY, results_dir=tmp_path) == 0
    run_dir = tmp_path / "default" / "cem-cartpole-none-popsize=8"
    before = (run_dir / "seed_0.csv").stat().st_mtime_ns
    args = [a for a in TINY if not a.startswith("seeds")]
    assert imix("algo=cem", "seeds=3", *args, results_dir=tmp_path) == 0
    assert (run_dir / "seed_0.csv").stat().st_mtime_ns == before  # not recomputed
    assert read_run_csv(run_dir / "seed_2.csv").shape[0] == 4


def test_unknown_group_option_lists_the_valid_choices(tmp_path, capsys):
    assert imix("algo=ppo", results_dir=tmp_path) == 2
    err = capsys.readouterr().err
    for name in ("openes", "snes", "cem", "cmaes"):
        assert name in err


def test_a_bad_point_anywhere_in_a_sweep_stops_before_the_first_runs(tmp_path, capsys):
    assert main(["run", "-m", "algo=cem", "popsize=8,1", *TINY[:2], "progress=false", f"results_dir={tmp_path}"]) == 2
    assert "popsize" in capsys.readouterr().err
    assert all_files(tmp_path) == []


# The paper's setting, section 4.1 (and its generation counts: 1000 for OpenES/SNES, 400 for CEM/CMA-ES).
PAPER_SETTING = {"popsize": 50, "sigma": 0.25, "lr": 0.01, "weight_decay": 0.05, "weight_decay_form": "estool", "im_alpha": 0.0, "eim_generations": 3}
PAPER_GENERATIONS = {"openes": 1000, "snes": 1000, "cem": 400, "cmaes": 400}


def test_each_point_of_imix_run_is_validated_once(tmp_path, monkeypatch):
    """`imix run` validates every point up front (before any runs); the Hydra task then runs the point's
    RunSpec from that validation instead of validating its config again."""
    import imix_cli.running.config.compose

    validated = []
    real = imix_cli.running.config.compose.spec_from_config

    def counting(cfg, launcher=None):
        validated.append(cfg["sigma"])
        return real(cfg, launcher)

    monkeypatch.setattr(imix_cli.running.config.compose, "spec_from_config", counting)
    assert imix("-m", "algo=cem", "sigma=0.25,0.5", *TINY, results_dir=tmp_path) == 0
    assert sorted(validated) == [0.25, 0.5]
    assert len(list(tmp_path.glob("default/cem-cartpole-none-popsize=8*/seed_*.csv"))) == 4


@pytest.mark.parametrize("algo", sorted(PAPER_GENERATIONS))
def test_a_run_without_overrides_is_the_paper_setting_in_a_bare_folder(algo):
    """The shipped defaults are the paper's, and the folder-name baseline agrees with them:
    a run without hyper-parameter overrides, with or without mixing, gets no ``-key=value`` suffix."""
    for mixing in ("none", "im", "eim"):
        flags = {"none": [], "im": ["im=true"], "eim": ["eim=true"]}[mixing]
        (spec,) = validate_overrides([f"algo={algo}", *flags])
        assert {key: getattr(spec, key) for key in PAPER_SETTING} == PAPER_SETTING
        assert spec.generations == PAPER_GENERATIONS[algo]
        assert spec.run_name == f"{algo}-cartpole-{mixing}"


def test_run_help_documents_every_key_with_its_shipped_default(capsys):
    """Each top-level key of the shipped config.yaml has a ``key=default`` line under "Keys:" in
    ``imix run --help``, and that default is the shipped one. (The help also dumps the current
    config, so a plain ``key in out`` would pass for undocumented keys.)"""
    shipped = yaml.safe_load((Path(config_dir()) / "config.yaml").read_text())
    keys = [k for k in shipped if k not in ("defaults", "hydra")]
    assert main(["run", "--help"]) == 0
    out = capsys.readouterr().out
    section = out[out.index("\nKeys:\n") : out.index("\nOutput:")]
    documented = dict(re.findall(r"^  ([\w.]+)=(\S+)", section, flags=re.MULTILINE))
    # a mapping key (policy) is documented by its sub-keys: policy.hidden=..., policy.obs_norm=...
    flat = {}
    for key in keys:
        if isinstance(shipped[key], dict):
            flat.update({f"{key}.{sub}": value for sub, value in shipped[key].items()})
        else:
            flat[key] = shipped[key]
    assert sorted(documented) == sorted(flat)
    for key, value in flat.items():
        if key != "generations":  # shipped as ${algo.generations}, documented per algorithm
            assert yaml.safe_load(documented[key]) == value, key


def test_top_level_help_and_unknown_command(capsys):
    assert main(["--help"]) == 0
    assert "imix run" in capsys.readouterr().out
    assert main(["frobnicate"]) == 2
    assert "frobnicate" in capsys.readouterr().err


def test_generic_gymnasium_id_runs(tmp_path):
    args = ["generations=2", "seeds=1", "popsize=4", "progress=false", "workers=1"]
    assert imix("env=gym", "env.id=MountainCar-v0", "algo=openes", *args, results_dir=tmp_path) == 0
    frame = read_run_csv(tmp_path / "default" / "openes-MountainCar-v0-none-popsize=4" / "seed_0.csv")
    assert (frame["env"] == "MountainCar-v0").all()
    assert frame["mean_score"].iloc[0] == -200.0  # an untrained policy never reaches the flag


@pytest.mark.slow
def test_wheel_ships_the_configs(tmp_path):
    """`conf/` is packaged as imix_cli.conf so that `imix run` works from any directory after `pip install .`;
    the build warns about nothing (setuptools' deprecations, sub-folders of conf/ that "would be ignored")."""
    repo = Path(__file__).resolve().parent.parent
    build = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-v", "-w", str(tmp_path), str(repo)]
    proc = subprocess.run(build, capture_output=True, text=True)  # -v: pip shows setuptools' own output
    assert proc.returncode == 0, proc.stderr[-3000:]
    warnings = [line.strip() for line in proc.stdout.splitlines() + proc.stderr.splitlines() if "Warning:" in line or "would be ignored" in line]
    assert not warnings, "\n".join(warnings)
    wheel = next(tmp_path.glob("imix_cli-*.whl"))
    names = set(zipfile.ZipFile(wheel).namelist())
    for conf in sorted((repo / "conf").rglob("*.yaml")) + [repo / "conf" / "__init__.py"]:
        assert f"imix_cli/conf/{conf.relative_to(repo / 'conf').as_posix()}" in names, conf
    # ... and every module of the source tree (a subpackage missing from pyproject's list is not installed)
    for module in sorted((repo / "imix_cli").rglob("*.py")) + sorted((repo / "hydra_plugins").rglob("*.py")):  # with the Optuna sweeper plugin
        assert module.relative_to(repo).as_posix() in names, module


@pytest.mark.slow
def test_installed_console_script_runs_from_any_directory(tmp_path):
    """The `imix` on PATH (in CI: the non-editable install) runs from a directory without conf/."""
    script = Path(sys.executable).parent / "imix"
    assert script.exists()
    env = {**os.environ, "PYTHONPATH": ""}
    proc = subprocess.run(
        [str(script), "run", "algo=openes", "generations=2", "seeds=1", "popsize=4", "progress=false", "workers=1"],
        cwd=tmp_path, capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "results" / "default" / "openes-cartpole-none-popsize=4" / "seed_0.csv").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]  # no Hydra litter in the working directory


def test_the_distribution_mean_is_measured_apart_from_training(tmp_path):
    """eval_mean_every=3: the return of the distribution mean on 2 fresh episodes after generations
    3 and 6 (rows 2 and 5), its episodes counted in mean_policy_episodes only; training -- every
    other column -- is exactly that of a run that never measures it (its own random stream)."""
    args = ["algo=cem", "env=cartpole", "eim=true", "seeds=1", "popsize=8", "generations=7", "eval_mean_episodes=2"]
    assert imix(*args, "eval_mean_every=3", results_dir=tmp_path / "on") == 0
    assert imix(*args, "eval_mean_every=0", results_dir=tmp_path / "off") == 0
    on, off = (read_run_csv(next((tmp_path / d).rglob("seed_0.csv"))) for d in ("on", "off"))
    measured = np.flatnonzero(np.isfinite(on["mean_policy_score"].to_numpy()))
    assert measured.tolist() == [2, 5]
    assert on["mean_policy_episodes"].tolist() == [0, 0, 2, 2, 2, 4, 4]
    assert (on["mean_policy_score"].iloc[measured] > 0).all()  # CartPole returns are positive
    assert off["mean_policy_score"].isna().all() and (off["mean_policy_episodes"] == 0).all()
    training = [c for c in on.columns if c not in ("mean_policy_score", "mean_policy_episodes", "wall_time")]
    pd.testing.assert_frame_equal(on[training], off[training])
