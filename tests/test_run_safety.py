"""A run folder and the processes of a run: links refused, sweeps checked whole, signals and kills survived.

Each test is one reproduction of what held-out testing found: a symlinked ``.lock`` or run folder
made imix write outside the results folder; a sweep point failed or was locked halfway through a
sweep; a killed continuation locked its run; SIGTERM left a warning instead of a line; ``status``
called a corrupt CSV running; an ES ignored ``total_steps``; the memory check forgot the
gymnasium envs.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from process_tree import alive, descendants

from imix_cli.commands.cli import main
from imix_cli.running.config.compose import ConfigError, validate_overrides
from imix_cli.running.files.results import read_run_csv
from imix_cli.running.run_folder import run_dir_lock

IMIX = str(Path(sys.executable).parent / "imix")
SMALL = ["algo=cem", "seeds=1", "generations=3", "popsize=8", "workers=1", "progress=false"]


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


def files_under(root: Path) -> dict:
    return {p.relative_to(root): (p.read_bytes() if p.is_file() and not p.is_symlink() else None) for p in root.rglob("*")}


# ------------------------------------------------------------------ symlinks in a run folder
def test_a_lock_symlink_is_refused_and_its_target_left_alone(tmp_path, capsys):
    victim = tmp_path / "victim"
    victim.write_text("precious\n")
    (spec,) = validate_overrides([*SMALL, f"results_dir={tmp_path / 'R'}", "experiment=e"])
    spec.run_dir.mkdir(parents=True)
    (spec.run_dir / ".lock").symlink_to(victim)
    assert main(["run", *SMALL, f"results_dir={tmp_path / 'R'}", "experiment=e"]) == 1
    err = one_line_error(capsys)
    assert ".lock" in err and "symbolic link" in err, err
    assert victim.read_text() == "precious\n"
    assert sorted(p.name for p in spec.run_dir.iterdir()) == [".lock"]  # nothing written


def test_a_refused_run_writes_nothing_not_even_its_lock(tmp_path, capsys):
    (spec,) = validate_overrides([*SMALL, f"results_dir={tmp_path}"])
    spec.run_dir.mkdir(parents=True)
    (spec.run_dir / "config.yaml").write_text("- not a mapping\n")
    before = files_under(tmp_path)
    assert main(["run", *SMALL, f"results_dir={tmp_path}"]) == 1
    assert "config.yaml" in one_line_error(capsys)
    assert files_under(tmp_path) == before  # no .lock, no temporary, nothing


def test_the_lock_never_follows_a_link_planted_after_the_folder_was_checked(tmp_path):
    from imix_cli.running.run_folder import RunError

    victim = tmp_path / "victim"
    victim.write_text("precious\n")
    (spec,) = validate_overrides([*SMALL, f"results_dir={tmp_path / 'R'}"])
    spec.run_dir.mkdir(parents=True)
    (spec.run_dir / ".lock").symlink_to(victim)
    with pytest.raises(RunError, match="symbolic link"):
        with run_dir_lock(spec):
            pass
    assert victim.read_text() == "precious\n"


def test_the_library_run_checks_the_folder_before_taking_its_lock(tmp_path):
    from imix_cli.running.run_folder import RunError
    from imix_cli.running.runner import run

    (spec,) = validate_overrides([*SMALL, f"results_dir={tmp_path}"])
    spec.run_dir.mkdir(parents=True)
    (spec.run_dir / "config.yaml").write_text("- not a mapping\n")
    with pytest.raises(RunError, match="config.yaml"):
        run(spec, echo=lambda text: None)
    assert sorted(p.name for p in spec.run_dir.iterdir()) == ["config.yaml"]


@pytest.mark.parametrize("name", ["config.yaml", "seed_0.csv", "seed_0.partial.csv", ".checkpoints"])
def test_a_symlink_among_a_run_folders_files_is_refused(tmp_path, capsys, name):
    outside = tmp_path / "outside"
    outside.mkdir()
    target = outside / "target"
    target.write_text("algo: {name: cem}\n") if name != ".checkpoints" else target.mkdir()
    if name == ".checkpoints":
        (target / ".seed_0.npz.x.tmp").write_bytes(b"someone else's file")
    (spec,) = validate_overrides([*SMALL, f"results_dir={tmp_path / 'R'}"])
    spec.run_dir.mkdir(parents=True)
    (spec.run_dir / name).symlink_to(target)
    before = files_under(outside)
    assert main(["run", *SMALL, f"results_dir={tmp_path / 'R'}"]) == 1
    err = one_line_error(capsys)
    assert name in err and "symbolic link" in err, err
    assert files_under(outside) == before
    assert not (spec.run_dir / ".lock").exists()


@pytest.mark.parametrize("level", ["run folder", "experiment folder"])
def test_a_symlinked_run_or_experiment_folder_is_refused(tmp_path, capsys, level):
    outside = tmp_path / "outside"
    outside.mkdir()
    (spec,) = validate_overrides([*SMALL, f"results_dir={tmp_path / 'R'}"])
    link = spec.run_dir if level == "run folder" else spec.run_dir.parent
    link.parent.mkdir(parents=True)
    link.symlink_to(outside, target_is_directory=True)
    assert main(["run", *SMALL, f"results_dir={tmp_path / 'R'}"]) == 1
    err = one_line_error(capsys)
    assert "symbolic link" in err and link.name in err, err
    assert list(outside.iterdir()) == []


def test_a_symlinked_results_dir_is_the_users_choice_and_works(tmp_path, capsys):
    storage = tmp_path / "scratch"
    storage.mkdir()
    (tmp_path / "results").symlink_to(storage, target_is_directory=True)
    assert main(["run", *SMALL, f"results_dir={tmp_path / 'results'}"]) == 0
    assert len(list(storage.rglob("seed_0.csv"))) == 1


# ------------------------------------------------------------------ the memory check counts gymnasium envs
def _physical_memory() -> int:
    return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


@pytest.mark.mujoco
def test_the_memory_check_counts_one_mujoco_env_per_member():
    if _physical_memory() >= 26 * 2**30:
        pytest.skip("25,000 Hopper envs (~27 GB) fit on this machine")
    with pytest.raises(ConfigError, match=r"popsize=25000.*env") as caught:
        validate_overrides(["env=hopper", "popsize=25000", "generations=1", "policy.hidden=[]", "seeds=1"])
    assert len(str(caught.value).splitlines()) == 1
    if _physical_memory() >= 7 * 2**30:  # 5,000 envs: ~5.5 GB
        validate_overrides(["env=hopper", "popsize=5000", "generations=1", "policy.hidden=[]", "seeds=1"])


@pytest.mark.mujoco
def test_the_memory_check_counts_every_seed_held_at_once():
    if _physical_memory() >= 100 * 2**30:
        pytest.skip("25 seeds x 5,000 Hopper envs fit on this machine")
    with pytest.raises(ConfigError, match=r"popsize=5000.*25 seeds"):
        validate_overrides(["env=hopper", "popsize=5000", "generations=1", "policy.hidden=[]", "seeds=25"])


# ------------------------------------------------------------------ sweeps checked whole
def test_a_sweep_point_whose_folder_name_is_too_long_is_refused_before_any_point_runs(tmp_path, capsys):
    long_policy = "[" + ",".join(["1"] * 130) + "]"
    assert main(["run", "-m", f"policy.hidden=[4],{long_policy}", *SMALL, f"results_dir={tmp_path}"]) == 2
    err = one_line_error(capsys)
    assert "255" in err and "hidden" in err, err
    assert not tmp_path.joinpath("default").exists()


def test_a_locked_sweep_point_is_skipped_and_the_others_run(tmp_path, capsys):
    points = [*SMALL[:3], "workers=1", "progress=false", f"results_dir={tmp_path}"]
    (locked,) = validate_overrides([*points, "popsize=8"])
    (free,) = validate_overrides([*points, "popsize=9"])
    with run_dir_lock(locked):  # another sweep is writing this point
        assert main(["run", "-m", "popsize=8,9", *points]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "in use by another imix run" in err[0] and locked.run_name in err[0], err
    assert (free.run_dir / "seed_0.csv").exists() and not (locked.run_dir / "seed_0.csv").exists()


def test_two_sweeps_started_in_the_same_second_do_not_share_a_multirun_folder(tmp_path, capsys, monkeypatch):
    """Hydra names a sweep's folder by the second it starts (``${now:...}``): two sweeps started
    together wrote one folder. Here both start "at the same second" (Hydra's clock is frozen)."""
    import datetime

    import hydra.core.utils

    frozen = datetime.datetime(2026, 1, 2, 3, 4, 5)
    monkeypatch.setattr(hydra.core.utils, "datetime", type("FrozenClock", (), {"now": staticmethod(lambda: frozen)}))
    base = [*SMALL[:3], "workers=1", "progress=false", f"results_dir={tmp_path}"]
    assert main(["run", "-m", "popsize=8,9", *base]) == 0
    assert main(["run", "-m", "popsize=10,11", *base]) == 0
    sweeps = list((tmp_path / "default" / ".multirun").iterdir())
    assert len(sweeps) == 2, sweeps
    assert all(str(frozen.strftime("%Y-%m-%d_%H-%M-%S")) in p.name for p in sweeps)


# ------------------------------------------------------------------ a killed continuation
def _wait_for_rows(path: Path, rows: int, proc, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            if len(path.read_text().splitlines()) - 1 >= rows:
                return
        except OSError:
            pass
        time.sleep(0.05)
    raise AssertionError(f"{path} never reached {rows} rows")


def test_a_killed_continuation_neither_locks_the_run_nor_hides_its_rows(tmp_path, capsys):
    common = ["algo=cem", "seeds=1", "popsize=8", "workers=1", "progress=false", "checkpoint_every=5", "checkpoint_seconds=0",
              "eval_mean_every=0", f"results_dir={tmp_path}"]  # fmt: skip
    assert main(["run", *common, "generations=10"]) == 0
    (spec,) = validate_overrides([*common, "generations=10"])
    proc = subprocess.Popen([IMIX, "run", *common, "generations=20000"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        _wait_for_rows(spec.run_dir / "seed_0.partial.csv", 40, proc)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    capsys.readouterr()
    # status shows the continuation's rows, not the 10 of the committed CSV
    assert main(["status", f"results_dir={tmp_path}"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith(spec.run_name))
    done, running, stopped, _, last = line.split()[1:6]
    assert (done, running, stopped) == ("0", "0", "1") and int(last.split("/")[0]) >= 40, line  # killed: stopped, not running
    # the committed 10 generations are what the run holds: 10 is done; 20 lies behind the continuation's
    # checkpoint (>= 40), so that seed is computed again; 100 continues from 20's final state
    assert main(["run", *common, "generations=10"]) == 0
    assert len(read_run_csv(spec.run_dir / "seed_0.csv")) == 10
    for generations in (20, 100):
        assert main(["run", *common, f"generations={generations}"]) == 0
        continued = read_run_csv(spec.run_dir / "seed_0.csv")
        assert main(["run", *common[:-1], f"results_dir={tmp_path / 'fresh'}", f"generations={generations}"]) == 0
        fresh = read_run_csv(next((tmp_path / "fresh").rglob("seed_0.csv")))
        assert len(continued) == generations
        assert continued.drop(columns="wall_time").equals(fresh.drop(columns="wall_time"))
    assert "restarts" in capsys.readouterr().err  # the one line that says the checkpoint past 20 was not used


def test_a_run_is_never_shortened_below_a_finished_csv(tmp_path, capsys):
    common = ["algo=cem", "seeds=1", "popsize=8", "workers=1", "progress=false", "checkpoint_every=5", "checkpoint_seconds=0", f"results_dir={tmp_path}"]
    assert main(["run", *common, "generations=10"]) == 0
    capsys.readouterr()
    assert main(["run", *common, "generations=5"]) == 1
    err = one_line_error(capsys)
    assert "shortened" in err, err


# ------------------------------------------------------------------ SIGTERM
def _stop_when_checkpointed(args, tmp_path, checkpoints: int, send, min_workers: int):
    """Start ``imix run args`` in a session of its own, wait for ``checkpoints`` checkpoint files, check it
    has at least ``min_workers`` processes below it, ``send(pid)``; return its exit code, its stderr and
    the processes below it still alive 10 s later."""
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 90
        while len(list(tmp_path.rglob(".checkpoints/seed_*.npz"))) < checkpoints and time.monotonic() < deadline:
            time.sleep(0.1)
        workers = descendants(proc.pid)
        assert len(workers) >= min_workers, workers
        send(proc.pid)
        code = proc.wait(timeout=30)
        deadline = time.monotonic() + 10
        while any(alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        left = [p for p in workers if alive(p)]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    return code, proc.stderr.read().strip(), left


@pytest.mark.parametrize("to", ["main", pytest.param("group", marks=pytest.mark.slow)])
def test_sigterm_stops_the_run_with_one_line_and_no_warning(tmp_path, to):
    args = [IMIX, "run", "algo=snes", "env=acrobot", "seeds=2", "generations=2000", "popsize=20", "checkpoint_every=5", "checkpoint_seconds=0",
            "workers=2", "progress=false",
            f"results_dir={tmp_path}"]  # fmt: skip
    kill = os.kill if to == "main" else os.killpg
    code, err, left = _stop_when_checkpointed(args, tmp_path, 2, lambda pid: kill(pid, signal.SIGTERM), min_workers=1)
    assert code == 143, (code, err)
    assert len(err.splitlines()) == 1 and "terminated" in err and "leaked" not in err, err
    assert not left, left
    assert len(list(tmp_path.rglob(".checkpoints/seed_*.npz"))) == 2


@pytest.mark.parametrize("signum", [signal.SIGINT, pytest.param(signal.SIGTERM, marks=pytest.mark.slow)], ids=["Ctrl-C", "SIGTERM"])
def test_the_evaluation_pool_stops_with_the_run_and_says_nothing(tmp_path, signum):
    """evaluator=pool, the signal sent to the whole process group (a terminal's Ctrl-C, a scheduler):
    the pool's workers printed a line each; now only the main process speaks."""
    args = [IMIX, "run", "algo=cem", "seeds=2", "generations=100000", "popsize=8", "checkpoint_every=5", "checkpoint_seconds=0",
            "evaluator=pool", "evaluator_workers=2",
            "progress=false", f"results_dir={tmp_path}"]  # fmt: skip
    code, err, left = _stop_when_checkpointed(args, tmp_path, 1, lambda pid: os.killpg(pid, signum), min_workers=2)
    assert code == 128 + signum, (code, err)
    assert len(err.splitlines()) == 1 and "Traceback" not in err and "leaked" not in err, err
    assert not left, left


def test_sigterm_during_validation_prints_one_line(tmp_path):
    sweep = "popsize=" + ",".join(map(str, range(8, 400)))
    args = [IMIX, "run", "-m", sweep, *SMALL[:3], "progress=false", f"results_dir={tmp_path}"]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(1.5)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert len(err.strip().splitlines()) == 1 and "terminated" in err, err


# ------------------------------------------------------------------ status, total_steps
def test_status_calls_a_corrupt_csv_corrupt(tmp_path, capsys):
    assert main(["run", *SMALL, "checkpoint_every=1", "checkpoint_seconds=0", f"results_dir={tmp_path}"]) == 0  # keeps its final checkpoint
    (csv,) = tmp_path.rglob("seed_0.csv")
    csv.write_text("algo,env\nthis is not,a run\n")
    capsys.readouterr()
    assert main(["status", f"results_dir={tmp_path}"]) == 0
    out = capsys.readouterr().out
    assert "corrupt" in out and "seed_0.csv" in out, out
    line = next(ln for ln in out.splitlines() if ln.strip().startswith(csv.parent.name))
    assert line.split()[1:5] == ["0", "0", "0", "0"], line  # neither done, nor running, nor stopped, nor not started


@pytest.mark.parametrize("algo", ["snes", "cem"])
def test_total_steps_on_an_evolution_strategy_is_refused(tmp_path, capsys, algo):
    assert main(["run", *SMALL[1:], f"algo={algo}", "total_steps=1000", f"results_dir={tmp_path}"]) == 2
    err = one_line_error(capsys)
    assert "total_steps=1000" in err and "ddpg" in err, err
    assert not any(tmp_path.iterdir())
