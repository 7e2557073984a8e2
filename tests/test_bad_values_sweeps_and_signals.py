"""Values the README calls valid, sweeps, sizes, signals, locks: each case a reproduction of a failure once seen.

Values that can never work are refused up front (one line naming the key, exit 2, nothing written); a legal value whose search diverges ends
its seed cleanly, recorded in the CSV (``diverged``) and in the summary.
"""

import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
from conftest import extra_installed
from process_tree import alive, pool_workers

from imix_cli.commands.cli import main
from imix_cli.running.config.compose import ConfigError, validate_overrides
from imix_cli.running.files.results import read_run_csv
from imix_cli.running.run_folder import run_dir_lock

IMIX = str(Path(sys.executable).parent / "imix")
SMALL = ["seeds=1", "generations=3", "popsize=8", "workers=1", "progress=false"]


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


# ------------------------------------------------------------------ 2. refused up front
REFUSED = [
    ("cmaes popsize 2", ["algo=cmaes", "popsize=2"], "popsize=2"),
    ("cem sigma 1e308", ["algo=cem", "sigma=1e308"], "sigma="),
    ("cmaes sigma 1e200", ["algo=cmaes", "sigma=1e200"], "sigma="),
    ("population beyond memory", ["popsize=100000000"], "popsize=100000000"),
    ("FrozenLake (Discrete observations)", ["env=gym", "env.id=FrozenLake-v1"], "FrozenLake-v1"),
    ("Blackjack (no time limit)", ["env=gym", "env.id=Blackjack-v1"], "Blackjack-v1"),
    ("Blackjack (Tuple observations)", ["env=gym", "env.id=Blackjack-v1", "env.max_steps=10"], "observation space"),
    ("seeds=1e9", ["seeds=1e9"], "seeds="),
]


@pytest.mark.parametrize("extra, text", [c[1:] for c in REFUSED], ids=[c[0] for c in REFUSED])
def test_values_that_can_never_work_are_refused_up_front(tmp_path, capsys, extra, text):
    root = tmp_path / "results"
    assert main(["run", *SMALL, *extra, f"results_dir={root}"]) == 2
    assert text in one_line_error(capsys)
    assert not root.exists()  # nothing written


# ------------------------------------------------------------------ 2. divergence is a result
@pytest.mark.parametrize("lr", ["100", "1e6"])
def test_a_diverging_snes_ends_its_seeds_cleanly_and_says_so(tmp_path, capfd, lr):
    # the paper form (fitness - w|theta|^2) turns huge weights into -inf returns; estool stays bounded
    args = ["run", "algo=snes", f"lr={lr}", "weight_decay_form=paper", "seeds=2", "generations=60", "workers=1", "progress=false", f"results_dir={tmp_path}"]
    assert main(args) == 0
    captured = capfd.readouterr()
    assert "Traceback" not in captured.err
    assert captured.err.count("diverged at generation") == 2, captured.err
    frames = [read_run_csv(p) for p in sorted(tmp_path.rglob("seed_*.csv"))]
    assert len(frames) == 2
    for frame in frames:
        assert len(frame) < 60 and frame["diverged"].iloc[-1] == 1 and (frame["diverged"].iloc[:-1] == 0).all()
    summary = captured.out.splitlines()[1].split()
    assert summary[-1] == "2"  # the summary's diverged column
    # A diverged seed counts as finished: a re-run has nothing left to do.
    assert main(args) == 0
    assert "(0 seed(s) run now" in capfd.readouterr().out


def test_huge_weight_decay_does_not_flood_stderr(tmp_path, capfd):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # each overflow would be one more stderr line
        assert main(["run", "weight_decay=1e308", *SMALL, f"results_dir={tmp_path}"]) == 0
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in caught]
    err = capfd.readouterr().err
    assert "RuntimeWarning" not in err and "overflow" not in err, err


# ------------------------------------------------------------------ 3. sweeps over any key
def test_a_sweep_over_env_max_steps_gives_each_point_its_own_folder(tmp_path, capsys):
    assert main(["run", "-m", "env.max_steps=100,200", "algo=cem", *SMALL, f"results_dir={tmp_path}"]) == 0
    folders = sorted(p.parent.name for p in tmp_path.rglob("config.yaml"))
    assert folders == ["cem-cartpole-none-env.max_steps=100,popsize=8", "cem-cartpole-none-popsize=8"], folders


def test_a_sweep_whose_points_would_share_a_folder_is_refused_before_anything_runs(tmp_path, capsys):
    assert main(["run", "-m", "generations=3,4", "algo=cem", *SMALL[:1], *SMALL[2:], f"results_dir={tmp_path}"]) == 2
    assert "generations=3 / 4" in one_line_error(capsys)
    assert not tmp_path.joinpath("default").exists()


# ------------------------------------------------------------------ 5. signals
@pytest.mark.slow
def test_sigint_to_the_main_process_alone_stops_the_workers_and_keeps_checkpoints(tmp_path):
    args = [IMIX, "run", "algo=snes", "env=acrobot", "seeds=2", "generations=2000", "popsize=20", "checkpoint_every=5", "checkpoint_seconds=0",
            "workers=2", "progress=false",
            f"results_dir={tmp_path}"]  # fmt: skip
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while len(list(tmp_path.rglob(".checkpoints/seed_*.npz"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        workers = pool_workers(proc.pid)
        assert len(workers) == 2, workers
        os.kill(proc.pid, signal.SIGINT)  # the main process only, as kill -INT or a scheduler does
        sent = time.monotonic()
        while any(alive(p) for p in workers) and time.monotonic() - sent < 10:
            time.sleep(0.05)
        stopped_after = time.monotonic() - sent
        assert proc.wait(timeout=10) == 130
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    # Before: the workers ran every seed to completion (15 s in the trial).
    assert stopped_after < 2.0, stopped_after
    err = proc.stderr.read().strip()
    assert len(err.splitlines()) == 1 and "interrupted" in err, err
    assert len(list(tmp_path.rglob(".checkpoints/seed_*.npz"))) == 2 and not [p for p in tmp_path.rglob("seed_*.csv") if not p.name.endswith(".partial.csv")]


@pytest.mark.parametrize("delay", [0.8, pytest.param(1.5, marks=pytest.mark.slow), pytest.param(2.2, marks=pytest.mark.slow)])
def test_ctrl_c_during_validation_prints_one_line(tmp_path, delay):
    """SIGINT a second or two after start: validation or Hydra's start-up is still running (a Ctrl-C in Hydra's
    config loading, after validation, left omegaconf half-updated and printed a traceback: at 1.5 s here)."""
    sweep = "popsize=" + ",".join(map(str, range(8, 400)))
    args = [IMIX, "run", "-m", sweep, *SMALL[:2], *SMALL[3:], f"results_dir={tmp_path}"]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert len(err.strip().splitlines()) == 1 and "interrupted" in err and "Traceback" not in err, err


# ------------------------------------------------------------------ 6. two runs on one folder
def test_a_second_run_on_a_locked_folder_is_refused_and_touches_nothing(tmp_path, capsys):
    (spec,) = validate_overrides(["algo=cem", *SMALL, f"results_dir={tmp_path}"])
    with run_dir_lock(spec):  # "run A", alive
        temporary = spec.run_dir / ".checkpoints" / ".seed_0.npz.abc.tmp"
        temporary.parent.mkdir()
        temporary.write_bytes(b"run A writing")
        assert main(["run", "algo=cem", *SMALL, f"results_dir={tmp_path}"]) == 1
        err = one_line_error(capsys)
        assert "in use by another imix run" in err and f"pid {os.getpid()}" in err, err
        assert temporary.exists()  # run B's start-up clean-up never ran
        assert not (spec.run_dir / "seed_0.csv").exists()
    # The lock goes with its holder: the folder is free again, the stale temporary is cleared.
    assert main(["run", "algo=cem", *SMALL, f"results_dir={tmp_path}"]) == 0
    assert (spec.run_dir / "seed_0.csv").exists() and not temporary.exists()


def test_a_lock_file_left_by_a_killed_run_does_not_block(tmp_path, capsys):
    common = ["run", "algo=cem", "seeds=200", "generations=3", "popsize=8", "workers=1", "progress=false", f"results_dir={tmp_path}"]
    proc = subprocess.Popen([IMIX, *common], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 60
    while not any(p.read_text().strip() for p in tmp_path.rglob(".lock")) and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)
    (lock,) = tmp_path.rglob(".lock")
    assert lock.read_text().strip() == str(proc.pid)  # the dead run's lock file is still there
    assert main(common) == 0
    assert "in use" not in capsys.readouterr().err
    assert len(list(tmp_path.rglob("seed_*.csv"))) == 200


# ------------------------------------------------------------------ 7. small ones
def test_glob_sweeps_over_config_groups_work(tmp_path, capsys):
    assert main(["run", "-m", "algo=glob(c*)", *SMALL, f"results_dir={tmp_path}"]) == 0
    assert sorted(p.parent.name.split("-")[0] for p in tmp_path.rglob("config.yaml")) == ["cem", "cmaes"]


def test_glob_on_a_value_key_is_refused_by_name(tmp_path, capsys):
    assert main(["run", "-m", "popsize=glob(*)", *SMALL[:2], *SMALL[3:], f"results_dir={tmp_path}"]) == 2
    assert "glob" in one_line_error(capsys)


def test_the_disk_full_message_names_the_file(tmp_path, capsys, csv_disk_full):
    assert main(["run", "algo=cem", *SMALL, f"results_dir={tmp_path}"]) == 1
    err = one_line_error(capsys)
    assert "seed_0.csv" in err and "No space left on device" in err, err


def test_plot_refuses_an_absolute_experiment_path(tmp_path, capsys):
    """An experiment with results, named by its absolute path: figures would land outside results_dir."""
    from imix_cli.plotting import main as plot_main

    assert main(["run", "algo=cem", *SMALL, f"results_dir={tmp_path / 'elsewhere'}", "experiment=exp"]) == 0
    outside = tmp_path / "elsewhere" / "exp"
    capsys.readouterr()
    code = plot_main([f"results_dir={tmp_path / 'results'}", f"experiment={outside}"])
    err = capsys.readouterr().err.strip()
    assert code != 0 and "experiment" in err and len(err.splitlines()) == 1, err
    assert not (outside / "figures").exists()


def test_fast_validation_composes_what_hydra_composes(tmp_path):
    """Points validated by applying value overrides to a composed config equal a full compose."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from omegaconf import OmegaConf, open_dict

    from imix_cli.running.config.compose import config_dir, spec_from_config

    points = [
        ["algo=cem", "popsize=12", "sigma=0.5", "env.max_steps=50", "generations=4"],
        ["algo=openes", "env=acrobot", "im=true", "im_variant=sun2009", "im_alpha=0.3", "lr=0.02"],
        ["algo=cmaes", "eim=true", "eim_generations=5", "weight_decay=0", "weight_decay_form=estool", "algo.generations=7"],
        ["env=gym", "env.id=MountainCar-v0", "seeds=3", "checkpoint_every=0", "experiment=x"],
    ]
    if extra_installed("cluster"):  # a launcher config group option, where the cluster extra is installed
        points.append(["hydra/launcher=joblib", "workers=1", "progress=false"])
    for point in points:
        (fast,) = validate_overrides(point)
        GlobalHydra.instance().clear()
        with initialize_config_dir(config_dir=config_dir(), version_base="1.3"):
            cfg = compose("config", overrides=point, return_hydra_config=True)
            launcher = OmegaConf.select(cfg, "hydra.launcher._target_")
            with open_dict(cfg):
                del cfg["hydra"]
            full = spec_from_config(OmegaConf.to_container(cfg, resolve=True), launcher)
        GlobalHydra.instance().clear()
        assert fast == full and fast.config == full.config, point


def test_no_private_hydra_api_in_the_tree():
    """imix calls Hydra through its public API only (Hydra's private package may change in any
    release): no Python file of the package, the tests, the benchmarks or the tools names it (the
    name is built here from parts, so that this file does not name it either)."""
    root = Path(__file__).resolve().parents[1]
    needle = "hydra." + "_internal"
    private = [
        f"{p.relative_to(root)}:{n}"
        for folder in ("imix_cli", "tests", "benchmarks", "tools")
        for p in sorted((root / folder).rglob("*.py"))
        for n, line in enumerate(p.read_text().splitlines(), 1)
        if needle in line
    ]
    assert private == []


@pytest.mark.parametrize(
    "override, text",
    [("algo.popsiz=3", "unknown key 'algo.popsiz'"), ("env.id.x=1", "unknown key 'env.id.x'"), ("policy.hidden={a:1}", "policy.hidden={a:1}")],
)
def test_a_bad_value_override_of_a_nested_key_is_named(override, text):
    """The fast path sets value overrides on a composed config itself: a key the config lacks, or a value that
    cannot be merged, is still one ConfigError naming it."""
    with pytest.raises(ConfigError) as err:
        validate_overrides([override])
    assert text in str(err.value) and len(str(err.value).splitlines()) == 1, err.value


@pytest.mark.slow
def test_every_sweep_point_is_validated_beyond_2000(tmp_path, capsys):
    """The bad points come after the 2,000th (the old cap stopped checking there)."""
    with pytest.raises(ConfigError, match="sigma=-1"):
        validate_overrides(["sigma=0.5,-1", "popsize=range(8,2009)"])
