"""Ctrl-C and SIGTERM keep every seed's current generation: the run stops between two
generations, checkpoints each seed there, and the re-run resumes there -- not at the last periodic
checkpoint -- saying so in one line, with CSVs equal to an uninterrupted run's."""

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pytest

from imix_cli.commands.cli import main
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.files.results import read_run_csv
from imix_cli.running.run_folder import prepare_run_dir
from imix_cli.running.runner import resume_lines, run_seeds

IMIX = str(Path(sys.executable).parent / "imix")
# No periodic checkpoint falls due during these runs (checkpoint_every far beyond generations): any checkpoint
# of an unfinished seed is the one the interruption wrote.
COMMON = ["algo=snes", "env=cartpole", "eim=true", "seeds=2", "generations=120", "popsize=10", "checkpoint_every=100000", "checkpoint_seconds=0",
          "eval_mean_every=10", "workers=1", "progress=false"]  # fmt: skip


def csvs(root: Path) -> dict:
    return {p.name: read_run_csv(p).drop(columns="wall_time") for p in sorted(root.rglob("seed_*.csv")) if ".partial" not in p.name}


@pytest.mark.parametrize("loop", ["compiled", "python"])
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_mid_run_keeps_the_generation_it_landed_in_and_the_resumed_csvs_equal_an_uninterrupted_run(tmp_path, capfd, monkeypatch, loop, signum):
    monkeypatch.setenv("IMIX_COMPILED_LOOP", "1" if loop == "compiled" else "0")
    assert main(["run", *COMMON, f"results_dir={tmp_path / 'ref'}"]) == 0
    (spec,) = validate_overrides([*COMMON, f"results_dir={tmp_path / 'run'}"])
    todo = prepare_run_dir(spec)
    made = {"generations": 0}

    def signal_mid_run(n):  # the signal arrives while the loop runs, as a Ctrl-C does
        made["generations"] += n
        if made["generations"] >= 2 * 37 and "at" not in made:
            made["at"] = made["generations"]
            os.kill(os.getpid(), signum)

    class Stopped(Exception):
        pass

    def raise_stopped(signum, frame):
        raise Stopped()

    previous = signal.signal(signum, raise_stopped)  # stands for the imix command's handler (one line, exit 130 / 143)
    try:
        with pytest.raises(Stopped):
            run_seeds(spec, todo, progress=signal_mid_run)
    finally:
        signal.signal(signum, previous)
    # both seeds (in lockstep) were at made["at"] / 2 generations when the signal came: that is what is on disk
    kept = made["at"] // 2
    assert 37 <= kept < 120
    for seed in (0, 1):
        assert len(read_run_csv(spec.run_dir / f"seed_{seed}.partial.csv")) == kept
        assert not (spec.run_dir / f"seed_{seed}.csv").exists()
    capfd.readouterr()
    assert main(["run", *COMMON, f"results_dir={tmp_path / 'run'}"]) == 0
    err = capfd.readouterr().err
    assert re.search(rf"^imix: resuming seeds 0-1 of \S+ at generation {kept} from their checkpoints$", err, re.M), err
    assert err.count("resum") == 1, err  # one line for the group, not one per seed
    expected, got = csvs(tmp_path / "ref"), csvs(tmp_path / "run")
    assert sorted(got) == sorted(expected) == ["seed_0.csv", "seed_1.csv"]
    for name in expected:
        pd.testing.assert_frame_equal(got[name], expected[name])


def test_the_resume_lines_say_which_seeds_resume_where():
    """One line per group of seeds resuming at one generation, naming the seeds (issue 48, friction 8: the one line
    gave a range of generations over all seeds, e.g. "resuming 25 seeds of r at generations 370-375", not which
    seed resumed where). Made to fail: on the code before, resume_lines did not exist (resume_line gave one line)."""
    assert resume_lines("r", {0: 370, 1: 375, 2: 370}) == [
        "imix: resuming seeds 0,2 of r at generation 370 from their checkpoints",
        "imix: resuming seed 1 of r at generation 375 from its checkpoint",
    ]
    assert resume_lines("r", {3: 120}) == ["imix: resuming seed 3 of r at generation 120 from its checkpoint"]
    assert resume_lines("r", {0: 8, 1: 0, 2: 0}) == [
        "imix: resuming seed 0 of r at generation 8 from its checkpoint",
        "imix: seeds 1-2 of r start from generation 0",
    ]
    assert resume_lines("r", {0: 0, 1: 0}) == []  # nothing resumed, nothing started: nothing to say
    # killed before its first checkpoint: its live view is on disk, and its generations are run again
    assert resume_lines("r", {0: 0, 1: 0}, started={1}) == ["imix: seeds 0-1 of r start from generation 0 (no checkpoint: seed 1 stopped before its first one)"]


class _Stderr:
    """A process's stderr read as it comes (a progress bar rewrites its line with carriage returns)."""

    def __init__(self, stream):
        self.text, self._stream = "", stream
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self):
        for chunk in iter(lambda: self._stream.read(1), ""):
            self.text += chunk

    def done(self) -> int:
        """Seed-generations done as the progress bar last said (0 before it says anything)."""
        counts = re.findall(r"(\d+)/\d+ \[", self.text)
        return int(counts[-1]) if counts else 0


@pytest.mark.slow
def test_ctrl_c_to_the_whole_group_with_two_workers_keeps_each_seeds_current_generation(tmp_path):
    """What a terminal does: SIGINT to every process of the run (the workers ignore it; the main process stops
    them with SIGTERM, and each checkpoints its seeds). Sent once the progress bar shows a third of the work. A seed's
    generations take ~0.2 ms and the bar is redrawn every 0.5 s: at 3000 the run could finish between two redraws."""
    generations = 10000
    args = [IMIX, "run", "algo=snes", "env=cartpole", "eim=true", "seeds=2", f"generations={generations}", "workers=2", "checkpoint_every=100000",
            "checkpoint_seconds=0", "progress=true"]  # fmt: skip
    subprocess.run([*args[:-1], "progress=false", f"results_dir={tmp_path / 'ref'}"], check=True, capture_output=True)
    proc = subprocess.Popen([*args, f"results_dir={tmp_path / 'run'}"], stderr=subprocess.PIPE, text=True, start_new_session=True)
    stderr = _Stderr(proc.stderr)
    try:
        deadline = time.monotonic() + 300
        while stderr.done() < 2 * generations // 3 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        shown = stderr.done()
        assert proc.poll() is None and 0 < shown < 2 * generations, (shown, stderr.text[-300:])
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=60) == 130
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    time.sleep(0.2)
    assert "Traceback" not in stderr.text, stderr.text
    run_dir = next((tmp_path / "run").rglob("config.yaml")).parent
    # a seed whose worker had not finished a generation yet (a worker starved on a loaded machine) keeps nothing
    partial = [run_dir / f"seed_{seed}.partial.csv" for seed in (0, 1)]
    kept = [len(read_run_csv(path)) if path.exists() else 0 for path in partial]
    assert sum(kept) >= shown, (kept, shown)  # at least what the bar showed when the signal came (it lags the workers)
    done = subprocess.run([*args[:-1], "progress=false", f"results_dir={tmp_path / 'run'}"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    for seed in (s for s in (0, 1) if kept[s]):  # two workers: a line per generation the seeds resume at, naming them
        group = [s for s in (0, 1) if kept[s] == kept[seed]]
        said = "seeds 0-1" if len(group) == 2 else f"seed {seed}"
        assert f"imix: resuming {said} of {run_dir.name} at generation {kept[seed]} from" in done.stderr, done.stderr
    expected, got = csvs(tmp_path / "ref"), csvs(tmp_path / "run")
    assert sorted(got) == sorted(expected) and len(got) == 2
    for name in expected:
        pd.testing.assert_frame_equal(got[name], expected[name])


def test_in_process_a_step_that_does_not_end_is_given_up_after_the_grace_period(tmp_path, monkeypatch):
    """In-process nobody else bounds the wait: a step that outlasts STOP_GRACE_SECONDS (a first run compiling its
    kernels takes minutes) is cut, as a second Ctrl-C would cut it; the seeds keep what was saved before."""
    from imix_cli.running.loop import stopping

    monkeypatch.setattr(stopping, "STOP_GRACE_SECONDS", 0.5)
    (spec,) = validate_overrides([*COMMON, f"results_dir={tmp_path}"])
    todo = prepare_run_dir(spec)
    reached = {}

    def a_step_that_hangs(n):
        os.kill(os.getpid(), signal.SIGINT)
        started = time.monotonic()
        try:
            time.sleep(30)  # the step goes on (a compilation, a long generation; here a system call)
        finally:
            reached["cut after"] = time.monotonic() - started

    class Stopped(Exception):
        pass

    def raise_stopped(signum, frame):
        raise Stopped()

    previous = signal.signal(signal.SIGINT, raise_stopped)
    try:
        with pytest.raises(Stopped):
            run_seeds(spec, todo, progress=a_step_that_hangs)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert reached["cut after"] < 20, reached  # cut in its system call, not when it ended (30 s)
    assert not list(spec.run_dir.glob("seed_*.partial.csv"))  # given up: nothing new saved
