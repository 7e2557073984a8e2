"""A grid killed at any moment and re-run with the same command completes with the same CSVs.

The kill test runs the real `imix` console script in its own process group and SIGKILLs it
at random moments -- alternately the whole group (main process and workers) and a single
worker -- then re-runs the same command until it completes. After every kill, every file at a
final name must be a complete, valid CSV; at the end every CSV must equal (but for wall_time)
the CSV of an uninterrupted run.
"""

import io
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from conftest import interrupted_run

from imix_cli.commands.cli import main
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.files.checkpoints import checkpoint_path
from imix_cli.running.files.results import read_run_csv
from imix_cli.running.run_folder import prepare_run_dir
from imix_cli.running.runner import run_seeds

IMIX = str(Path(sys.executable).parent / "imix")
GENERATIONS = 2400  # long enough (~10 s of work here) that the kills below land before the run ends (1200 was, before Acrobot got 1.4x faster)
# Long enough (~10 s of work on 2 cores) that the first kills always land before completion.
ARGS = ["run", "algo=snes", "env=acrobot", "eim=true", "seeds=4", f"generations={GENERATIONS}", "popsize=40", "checkpoint_every=25", "checkpoint_seconds=0",
        "workers=2",
        "progress=false"]  # fmt: skip


def csvs(root: Path) -> dict:
    return {p.relative_to(root): pd.read_csv(p).drop(columns=["wall_time"]) for p in final_csvs(root)}


def worker_pids(main_pid: int) -> list[int]:
    """Pool workers of the main process (spawned, or forked from its fork server)."""
    from process_tree import pool_workers

    return pool_workers(main_pid)


def final_csvs(root: Path) -> list:
    """The seeds' CSVs (not the live-view seed_<k>.partial.csv written at checkpoints)."""
    return [p for p in sorted(root.rglob("seed_*.csv")) if not p.name.endswith(".partial.csv")]


def assert_final_files_valid(root: Path) -> None:
    for path in final_csvs(root):
        assert len(read_run_csv(path)) == GENERATIONS, path  # complete, never partial


def wait_for_a_new_checkpoint(root: Path, started: float, proc, limit: float = 60.0) -> None:
    """Until a checkpoint written after ``started`` exists (or ``proc`` ended, or ``limit`` seconds)."""
    deadline = time.monotonic() + limit
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            if any(p.stat().st_mtime >= started for p in root.rglob(".checkpoints/seed_*.npz")):
                return
        except FileNotFoundError:  # replaced or removed while we looked
            pass
        time.sleep(0.05)


@pytest.mark.slow
def test_kill_minus_9_at_random_points_then_resume_gives_identical_csvs(tmp_path):
    """Kills at random moments: two attempts in three shortly after a fresh checkpoint (so that
    resuming is exercised however slow the machine), the third anywhere, start-up included."""
    reference, target = tmp_path / "reference", tmp_path / "killed"
    # the reference writes no checkpoint (a key that does not change results: the same folder and CSVs): 480
    # checkpoints a seed (each an fsynced .npz and the partial CSV) doubled its time (39 s against 19 s here)
    no_checkpoints = [a if not a.startswith("checkpoint_every=") else "checkpoint_every=0" for a in ARGS]
    subprocess.run([IMIX, *no_checkpoints, f"results_dir={reference}"], check=True, capture_output=True)
    rng = random.Random(20261122)
    kills = {"group": 0, "worker": 0}
    stderr_logs = []
    for attempt in range(4):  # each kill kind: after a checkpoint (group, worker), anywhere (group) (12 attempts took 466 s at load ~20)
        stderr_logs.append(tmp_path / f"stderr_{attempt}.txt")
        attempt_started = time.time()
        with open(stderr_logs[-1], "w") as log:
            proc = subprocess.Popen([IMIX, *ARGS, f"results_dir={target}"], start_new_session=True, stdout=subprocess.DEVNULL, stderr=log)
        if attempt % 3 != 2:  # mostly after this attempt wrote a checkpoint, so the next must resume from it
            wait_for_a_new_checkpoint(target, started=attempt_started, proc=proc)
        try:
            proc.wait(timeout=rng.uniform(0.0, 1.5) if attempt % 3 != 2 else rng.uniform(0.5, 3.0))
            break  # this attempt ran to completion
        except subprocess.TimeoutExpired:
            workers = worker_pids(proc.pid)
            if attempt % 2 == 1 and workers:
                os.kill(rng.choice(workers), signal.SIGKILL)
                kills["worker"] += 1
            else:
                os.killpg(proc.pid, signal.SIGKILL)
                kills["group"] += 1
            proc.wait(timeout=60)
        time.sleep(0.3)  # let orphans notice and stop
        assert_final_files_valid(target)
    final = subprocess.run([IMIX, *ARGS, f"results_dir={target}"], capture_output=True, text=True)
    assert final.returncode == 0, final.stderr
    print(f"kills: {kills}")
    assert kills["group"] >= 2 and kills["worker"] >= 1, kills
    # The re-runs really continued from checkpoints (a restart from scratch writes the same CSVs).
    errors = "".join(p.read_text() for p in stderr_logs) + final.stderr
    resumed = [int(g) for g in re.findall(r"resuming seeds? \S+ of \S+ at generation (\d+)", errors)]
    # a periodic checkpoint (every 25) or the one a seed writes when the run stops it (a worker's death stops the others)
    assert resumed and all(g > 0 for g in resumed), errors
    assert "warning" not in errors, errors
    expected, got = csvs(reference), csvs(target)
    assert sorted(got) == sorted(expected) and len(got) == 4
    for name in expected:
        pd.testing.assert_frame_equal(got[name], expected[name])
    assert not list(target.rglob("*.tmp"))


@pytest.mark.parametrize("algo", ["openes", "snes", "cem", "cmaes"])
def test_resume_from_checkpoint_equals_not_stopping(tmp_path, algo, capfd, monkeypatch):
    """In-process: interrupt after 7 generations (checkpoint at 6), resume, compare. The Python loop, which reports
    every generation (the compiled loop reports a chunk at a time: its resume is tests/test_compiled_loop.py's)."""
    monkeypatch.setenv("IMIX_COMPILED_LOOP", "0")
    common = [f"algo={algo}", "env=acrobot", "eim=true", "seeds=2", "generations=10", "popsize=10", "checkpoint_every=3", "checkpoint_seconds=0",
              "workers=1", "progress=false"]  # fmt: skip
    assert main(["run", *common, f"results_dir={tmp_path / 'ref'}"]) == 0
    (spec,) = validate_overrides([*common, f"results_dir={tmp_path / 'stop'}"])
    todo = prepare_run_dir(spec)
    done = {"n": 0}

    def interrupt_after_seven_generations(n):
        done["n"] += 1
        if done["n"] == 7:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_seeds(spec, todo, progress=interrupt_after_seven_generations)
    assert checkpoint_path(spec.run_dir, 0).exists() and not (spec.run_dir / "seed_0.csv").exists()
    capfd.readouterr()
    assert main(["run", *common, f"results_dir={tmp_path / 'stop'}"]) == 0
    err = capfd.readouterr().err
    # Both seeds really restart from their checkpoint (a run from scratch writes the same CSVs).
    assert re.search(r"^imix: resuming seeds 0-1 of \S+ at generation 6 from their checkpoints$", err, re.M), err  # one line for both
    assert "warning" not in err
    assert checkpoint_path(spec.run_dir, 0).exists()  # the final state, kept so the run can be continued
    expected, got = csvs(tmp_path / "ref"), csvs(tmp_path / "stop")
    assert len(got) == 2
    for name in expected:
        pd.testing.assert_frame_equal(got[name], expected[name])


def test_a_real_checkpoint_of_another_config_is_refused(tmp_path, capfd):
    """A checkpoint of weight_decay=0.05 copied into the folder of weight_decay=0.1: same shapes,
    so only the identity check stands between it and a wrong CSV."""
    common = ["algo=cem", "seeds=1", "generations=6", "popsize=8", "checkpoint_every=2", "checkpoint_seconds=0", "workers=1", "progress=false"]
    other = interrupted_run([*common, "weight_decay=0.05"], tmp_path / "other", after=3)
    assert checkpoint_path(other.run_dir, 0).exists()
    assert main(["run", *common, "weight_decay=0.1", f"results_dir={tmp_path / 'ref'}"]) == 0
    (spec,) = validate_overrides([*common, "weight_decay=0.1", f"results_dir={tmp_path / 'target'}"])
    prepare_run_dir(spec)
    checkpoint_path(spec.run_dir, 0).parent.mkdir()
    checkpoint_path(spec.run_dir, 0).write_bytes(checkpoint_path(other.run_dir, 0).read_bytes())
    capfd.readouterr()
    assert main(["run", *common, "weight_decay=0.1", f"results_dir={tmp_path / 'target'}"]) == 0
    err = capfd.readouterr().err
    warnings = [line for line in err.splitlines() if "warning" in line]
    assert len(warnings) == 1 and "another config" in warnings[0] and str(checkpoint_path(spec.run_dir, 0)) in warnings[0], err
    assert "resumes" not in err
    expected, got = csvs(tmp_path / "ref"), csvs(tmp_path / "target")
    assert len(got) == 1
    for name in expected:
        pd.testing.assert_frame_equal(got[name], expected[name])


def test_an_unreadable_checkpoint_is_recomputed(tmp_path, capfd):
    common = ["algo=cem", "seeds=1", "generations=6", "popsize=8", "checkpoint_every=2", "checkpoint_seconds=0", "workers=1", "progress=false"]
    (spec,) = validate_overrides([*common, f"results_dir={tmp_path}"])
    todo = prepare_run_dir(spec)
    path = checkpoint_path(spec.run_dir, 0)
    path.parent.mkdir(parents=True)
    path.write_bytes(b"not a checkpoint")  # unreadable: recomputed, never trusted
    run_seeds(spec, todo, progress=lambda n: None)
    assert len(read_run_csv(spec.run_dir / "seed_0.csv")) == 6
    assert "checkpoint ignored" in capfd.readouterr().err


def test_a_finished_run_continues_to_more_generations_as_if_run_at_once(tmp_path, capfd):
    """generations=6 then generations=11 in the same experiment continues each seed from its final
    state: the CSVs equal those of generations=11 run at once (but for wall_time). Fewer
    generations than done are refused in one line, and nothing is rewritten."""
    common = ["algo=snes", "env=cartpole", "eim=true", "seeds=2", "popsize=10", "checkpoint_every=4", "checkpoint_seconds=0", "workers=1", "progress=false"]
    assert main(["run", *common, "generations=11", f"results_dir={tmp_path / 'once'}"]) == 0
    assert main(["run", *common, "generations=6", f"results_dir={tmp_path / 'twice'}"]) == 0
    capfd.readouterr()
    assert main(["run", *common, "generations=11", f"results_dir={tmp_path / 'twice'}"]) == 0
    err = capfd.readouterr().err
    assert re.search(r"^imix: resuming seeds 0-1 of \S+ at generation 6 from their checkpoints$", err, re.M), err  # one line for both
    once, twice = csvs(tmp_path / "once"), csvs(tmp_path / "twice")
    assert len(twice) == 2 and all(len(frame) == 11 for frame in twice.values())
    for name in once:
        pd.testing.assert_frame_equal(twice[name], once[name])
    (run_dir,) = [p.parent for p in (tmp_path / "twice").rglob("config.yaml")]
    assert "generations: 11" in (run_dir / "config.yaml").read_text()
    before = {p: p.read_bytes() for p in run_dir.glob("seed_*.csv")}
    assert main(["run", *common, "generations=5", f"results_dir={tmp_path / 'twice'}"]) == 1
    assert "not shortened" in capfd.readouterr().err
    assert {p: p.read_bytes() for p in run_dir.glob("seed_*.csv")} == before


def test_a_kill_between_a_seeds_final_state_and_its_csv_writes_only_its_files(tmp_path, capfd):
    """The writer saves a finished seed's final state before its CSV: a run killed in between resumes
    the seed at its last generation and writes its policy files and CSV, as the run would have."""
    common = ["algo=snes", "env=cartpole", "eim=true", "seeds=2", "generations=6", "popsize=10", "checkpoint_every=4", "checkpoint_seconds=0",
              "workers=1", "progress=false"]  # fmt: skip
    assert main(["run", *common, f"results_dir={tmp_path}"]) == 0
    (run_dir,) = [p.parent for p in tmp_path.rglob("config.yaml")]
    files = ("seed_0.csv", "policy_0_mean.npz", "policy_0_best.npz")
    before = {name: (run_dir / name).read_bytes() for name in files}
    for name in files:
        (run_dir / name).unlink()
    capfd.readouterr()
    assert main(["run", *common, f"results_dir={tmp_path}"]) == 0
    assert re.search(r"^imix: resuming seed 0 of \S+ at generation 6 from its checkpoint$", capfd.readouterr().err, re.M)
    assert {name: (run_dir / name).read_bytes() for name in files[1:]} == {name: before[name] for name in files[1:]}
    csv_now, csv_before = (pd.read_csv(source).drop(columns=["wall_time"]) for source in (run_dir / files[0], io.BytesIO(before[files[0]])))
    pd.testing.assert_frame_equal(csv_now, csv_before)
