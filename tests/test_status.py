"""`imix status` on a run folder with a finished, a partial, a checkpoint-only and a missing seed."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from imix_cli.commands.cli import main
from imix_cli.commands.status import run_status
from imix_cli.running.files.results import partial_csv_path, read_run_csv, rows_to_frame, seed_csv_path, write_run_csv

IMIX = str(Path(sys.executable).parent / "imix")


def rows(seed, scores, popsize=10):
    return rows_to_frame(
        dict(algo="snes", env="cartpole", mixing="eim", seed=seed, generation=g, evaluations=popsize * (g + 1),
             env_steps=100 * (g + 1), mean_score=float(s), best_score=float(s) + 5.0, reused=0, reused_im=0,
             reused_eim=0, popsize=popsize, sigma_mean=0.25, nonfinite=0, wall_time=float(g))
        for g, s in enumerate(scores)
    )  # fmt: skip


def make_run(root):
    run_dir = root / "exp" / "snes-cartpole-eim"
    (run_dir / ".checkpoints").mkdir(parents=True)
    (run_dir / "config.yaml").write_text(yaml.safe_dump({"algo": {"name": "snes"}, "seeds": 5, "generations": 10}))
    write_run_csv(seed_csv_path(run_dir, 0), rows(0, np.linspace(10, 190, 10)))  # finished: best 195, last 190
    write_run_csv(partial_csv_path(run_dir, 1), rows(1, [20, 40, 60, 80, 100]))  # running, checkpointed at gen 5
    (run_dir / ".checkpoints" / "seed_1.npz").write_bytes(b"being rewritten")  # unreadable: tolerated
    buffer = io.BytesIO()  # running, only a checkpoint (npz + JSON header) at generation 7
    np.savez(buffer, header=np.array(json.dumps({"generation": 7})))
    (run_dir / ".checkpoints" / "seed_2.npz").write_bytes(buffer.getvalue())
    (run_dir / ".checkpoints" / "seed_3.npz").write_bytes(b"")  # running, a checkpoint cut short: tolerated
    # seed 4: nothing yet
    return run_dir


def test_status_counts_finished_partial_and_missing_seeds(tmp_path):
    run_dir = make_run(tmp_path)
    s = run_status(run_dir)
    assert (s["done"], s["running"], s["stopped"], s["not_started"]) == ([0], [], [1, 2, 3], [4])  # no live run holds it
    assert s["generations"] == {0: 10, 1: 5, 2: 7}
    assert s["last_generation"] == 10 and s["target"] == 10
    assert s["best_score"] == 195.0
    assert s["current_score"] == (190.0 + 100.0) / 2  # last rows of the seeds that have rows


def test_status_command_prints_one_line_per_run_and_writes_nothing(tmp_path, capsys):
    run_dir = make_run(tmp_path)
    before = {p: p.read_bytes() for p in run_dir.rglob("*") if p.is_file()}
    assert main(["status", f"results_dir={tmp_path}"]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.strip().startswith("snes-cartpole-eim"))
    assert line.split() == ["snes-cartpole-eim", "1", "0", "3", "1", "5-10/10", "195.00", "145.00"]
    assert "stopped seeds: 1-3 (re-run the same command to resume them)" in out
    assert {p: p.read_bytes() for p in run_dir.rglob("*") if p.is_file()} == before


def test_status_checkpoint_generation_beyond_the_rows(tmp_path):
    run_dir = make_run(tmp_path)
    seed_csv_path(run_dir, 0).unlink()  # now the most advanced is seed 2's checkpoint header (7)
    assert run_status(run_dir)["last_generation"] == 7


def test_status_bad_experiment_is_one_line(tmp_path, capsys):
    assert main(["status", f"results_dir={tmp_path}", "experiment=nope"]) == 1
    assert main(["status", "colour=red"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "nope" in err[0] and "colour" in err[1]


def test_a_live_run_holding_the_lock_makes_every_unfinished_seed_running(tmp_path, capsys):
    """The lock's holder is what tells running from stopped: every unfinished seed of a folder a live run holds is
    being run (those with nothing on disk yet included); the same files without it are a stopped run's."""
    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.run_folder import run_dir_lock

    run_dir = make_run(tmp_path)
    (spec,) = validate_overrides(["seeds=5", f"results_dir={tmp_path}", "experiment=exp", "popsize=50", "algo=snes", "eim=true"])
    assert spec.run_dir == run_dir
    with run_dir_lock(spec):  # this process is the live run
        s = run_status(run_dir)
        assert (s["done"], s["running"], s["stopped"], s["not_started"], s["pid"]) == ([0], [1, 2, 3, 4], [], [], os.getpid())
        assert main(["status", f"results_dir={tmp_path}"]) == 0
        assert f"running seeds: 1-4 (imix run, pid {os.getpid()})" in capsys.readouterr().out
    s = run_status(run_dir)  # the lock released (its file and pid stay): stopped
    assert (s["running"], s["stopped"], s["not_started"], s["pid"]) == ([], [1, 2, 3], [4], None)


def test_a_csv_short_of_the_configs_generations_is_not_done_as_imix_run_refuses_it(tmp_path, capsys):
    """A 1-of-30-row CSV without a final state to continue from: imix run refuses the folder,
    and status says so instead of counting it done."""
    from imix_cli.running.files.results import read_run_csv

    args = ["algo=cem", "seeds=2", "generations=30", "popsize=8", "workers=1", "progress=false", "checkpoint_every=0", f"results_dir={tmp_path}"]
    assert main(["run", *args]) == 0
    (csv,) = tmp_path.rglob("seed_1.csv")
    write_run_csv(csv, read_run_csv(csv).iloc[:1])
    capsys.readouterr()
    assert main(["run", *args]) == 1
    assert "1 of 30 generations" in capsys.readouterr().err
    s = run_status(csv.parent)
    assert s["done"] == [0] and 1 not in s["stopped"] + s["running"] + s["not_started"]
    assert s["corrupt"] == {"seed_1.csv": "1 of 30 generations and no final state to continue from"}
    assert main(["status", f"results_dir={tmp_path}"]) == 0
    out = capsys.readouterr().out
    assert "corrupt: seed_1.csv (1 of 30 generations and no final state to continue from); imix run refuses it" in out, out


def _truth(run_dir, seeds: int, generations: int, live: bool = True) -> tuple[list, list, dict]:
    """What the files say, read apart from status: finished seeds, unfinished ones, and each seed's generations on
    disk (its CSV's rows, or its partial CSV's, or its checkpoint's header; with no live run, a checkpoint behind the
    partial CSV's rows -- a kill -9 after a live view -- is where a re-run resumes, and what is shown)."""
    from imix_cli.commands.status import _checkpoint_generation
    from imix_cli.running.files.results import read_run_csv

    done, unfinished, gens = [], [], {}
    for seed in range(seeds):
        csv, partial = seed_csv_path(run_dir, seed), partial_csv_path(run_dir, seed)
        if csv.exists() and len(read_run_csv(csv)) == generations:
            done.append(seed)
            gens[seed] = generations
            continue
        unfinished.append(seed)
        ckpt = _checkpoint_generation(run_dir, seed)
        rows = len(read_run_csv(partial)) if partial.exists() else None
        if ckpt is not None or rows is not None:
            gens[seed] = max(g for g in (ckpt, rows) if g is not None) if live or ckpt is None else ckpt
    return done, unfinished, gens


@pytest.mark.slow
def test_status_agrees_with_the_files_at_every_stop_of_a_run(tmp_path):
    """A run of 3 seeds over 2 workers, frozen (SIGSTOP to its whole group) at several moments and compared with
    what its files say; then after Ctrl-C, SIGTERM and kill -9 of re-runs, and at the end."""
    seeds, generations = 3, 6000
    args = [IMIX, "run", "algo=snes", "env=cartpole", "eim=true", f"seeds={seeds}", f"generations={generations}", "workers=2", "checkpoint_every=25",
            "checkpoint_seconds=0", "progress=false", f"results_dir={tmp_path}"]  # fmt: skip

    def check(run_dir, live_pid):
        s = run_status(run_dir)
        done, unfinished, gens = _truth(run_dir, seeds, generations, live=live_pid is not None)
        assert s["done"] == done and s["generations"] == gens, (s, done, gens)
        if live_pid is None:
            # each list is sorted, their union is not: seeds 0-1 in one worker's lockstep, 2 in the other's, one may be
            # stopped before the other has saved anything (seen under load: stopped [2], not started [0, 1])
            assert (s["running"], s["pid"]) == ([], None) and sorted(s["stopped"] + s["not_started"]) == unfinished, s
            assert s["stopped"] == sorted(gens.keys() - set(done)), s
        else:
            assert (s["running"], s["stopped"], s["not_started"], s["pid"]) == (unfinished, [], [], live_pid), s
        return gens

    def start():
        proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        deadline = time.monotonic() + 120
        while not list(tmp_path.rglob("config.yaml")) and time.monotonic() < deadline:  # written under the lock: a live run
            time.sleep(0.05)
        return proc

    proc = start()
    try:
        run_dir = next(tmp_path.rglob("config.yaml")).parent
        seen = []
        for moment in ("started", "first checkpoint", "a second later"):  # frozen at a few moments
            if moment == "first checkpoint":
                deadline = time.monotonic() + 120
                while not list(run_dir.glob(".checkpoints/*.npz")) and time.monotonic() < deadline:
                    time.sleep(0.02)
            time.sleep(1.0 if moment == "a second later" else 0.0)
            os.killpg(proc.pid, signal.SIGSTOP)
            try:
                seen.append(check(run_dir, proc.pid))
            finally:
                os.killpg(proc.pid, signal.SIGCONT)
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=60) == 130
        after_ctrl_c = check(run_dir, None)
        assert seen[0] == {} and sum(seen[-1].values()) > 0  # frozen before anything was saved, and after
        assert sum(after_ctrl_c.values()) >= sum(seen[-1].values())
        for stop in (lambda p: os.kill(p.pid, signal.SIGTERM), lambda p: os.killpg(p.pid, signal.SIGKILL)):
            proc = start()
            time.sleep(2.0)
            stop(proc)
            proc.wait(timeout=60)
            time.sleep(1.5)  # an orphaned worker of kill -9 exits within a second
            check(run_dir, None)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


def test_status_does_not_count_a_csv_of_another_run_as_done(tmp_path, capsys):
    """A finished-looking seed CSV whose env contradicts its run's config.yaml is what ``imix run``
    refuses (the readers' one check, imix_cli.running.seed_checks); status lists it as corrupt, not done."""
    from imix_cli.commands.cli import main

    assert main(["run", "algo=cem", "env=cartpole", "seeds=1", "generations=3", "popsize=4", "progress=false", f"results_dir={tmp_path}"]) == 0
    (csv,) = tmp_path.rglob("seed_0.csv")
    csv.write_text(csv.read_text().replace(",cartpole,", ",acrobot,"))
    capsys.readouterr()
    assert main(["status", f"results_dir={tmp_path}"]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.strip().startswith(csv.parent.name))
    assert line.split()[1] == "0" and "corrupt" in out and "env=acrobot" in out, out


def _small_run(tmp_path, *keys):
    from imix_cli.running.config.compose import validate_overrides

    (spec,) = validate_overrides(["algo=cem", "env=cartpole", "popsize=8", "progress=false", "workers=1", "seeds=1", "generations=60", *keys,
                                  f"results_dir={tmp_path}"])  # fmt: skip
    spec.run_dir.mkdir(parents=True, exist_ok=True)
    return spec


class _Killed(Exception):
    """Stands for a kill -9 of the run: nothing more is written."""


@pytest.mark.parametrize("compiled", ["0", "1"])
def test_a_running_seeds_last_generation_shows_before_its_first_checkpoint(tmp_path, monkeypatch, compiled):
    """`imix status` showed "last gen -" for the first 30 s of the main job (checkpoint_seconds=30: its first
    checkpoint, with which the live view was written) while the bar moved. The live view is now written every
    LIVE_VIEW_SECONDS between checkpoints too (0 here, for a run of milliseconds): status sees every step.
    Made to fail (issue 48, friction 6): on the code before, status gave None at every step but the last."""
    import imix_cli.running.files.run_writer as run_writer
    from imix_cli.running.loop.es_seeds import CHUNK
    from imix_cli.running.runner import run_seeds

    monkeypatch.setattr(run_writer, "LIVE_VIEW_SECONDS", 0.0, raising=False)
    monkeypatch.setenv("IMIX_COMPILED_LOOP", compiled)  # the Python loop steps a generation, the compiled one a chunk
    spec = _small_run(tmp_path)  # checkpoint_every=50, checkpoint_seconds=30: no checkpoint falls due before the end
    seen = []
    run_seeds(spec, [0], progress=lambda n: seen.append((run_status(spec.run_dir)["last_generation"], list(spec.run_dir.glob(".checkpoints/*")))))
    before_the_end = seen[:-1]
    assert before_the_end and all(not checkpoints for _, checkpoints in before_the_end), seen  # no checkpoint yet
    steps = list(range(1, 60)) if compiled == "0" else list(range(CHUNK, 60, CHUNK))
    assert [generation for generation, _ in before_the_end] == steps, seen


def test_a_stopped_seed_shows_where_a_rerun_resumes_when_its_live_view_is_ahead_of_its_checkpoint(tmp_path, monkeypatch):
    """A kill -9 can leave a seed's live view a few seconds ahead of its last checkpoint: a stopped seed's last gen
    is its checkpoint's (where a re-run resumes), and its rows are cut there."""
    import imix_cli.running.files.run_writer as run_writer
    from imix_cli.running.runner import run_seeds

    def killed_after(generation, spec):
        def progress(_n):  # after each step's files are written
            path = partial_csv_path(spec.run_dir, 0)
            if path.exists() and len(read_run_csv(path)) >= generation:
                raise _Killed()

        return progress

    spec = _small_run(tmp_path, "checkpoint_every=10", "checkpoint_seconds=0")
    with pytest.raises(_Killed):
        run_seeds(spec, [0], progress=killed_after(20, spec))  # checkpoint and live view at 10, then 20
    monkeypatch.setattr(run_writer, "LIVE_VIEW_SECONDS", 0.0)
    spec = _small_run(tmp_path, "checkpoint_every=10", "checkpoint_seconds=3600")  # no checkpoint for an hour: only live views
    with pytest.raises(_Killed):
        run_seeds(spec, [0], progress=killed_after(40, spec))
    assert len(read_run_csv(partial_csv_path(spec.run_dir, 0))) == 40
    s = run_status(spec.run_dir)
    assert (s["stopped"], s["generations"]) == ([0], {0: 20}), s
