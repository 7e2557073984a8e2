"""`imix status` on a run folder with a finished, a partial, a checkpoint-only and a missing seed."""

from __future__ import annotations

import io
import json

import numpy as np
import yaml

from imix_cli.commands.cli import main
from imix_cli.commands.status import run_status
from imix_cli.running.results import partial_csv_path, rows_to_frame, seed_csv_path, write_run_csv


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
    assert (s["done"], s["running"], s["not_started"]) == ([0], [1, 2, 3], [4])
    assert s["last_generation"] == 10 and s["target"] == 10
    assert s["best_score"] == 195.0
    assert s["current_score"] == (190.0 + 100.0) / 2  # last rows of the seeds that have rows


def test_status_command_prints_one_line_per_run_and_writes_nothing(tmp_path, capsys):
    run_dir = make_run(tmp_path)
    before = {p: p.read_bytes() for p in run_dir.rglob("*") if p.is_file()}
    assert main(["status", f"results_dir={tmp_path}"]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.strip().startswith("snes-cartpole-eim"))
    assert line.split() == ["snes-cartpole-eim", "1", "3", "1", "10/10", "195.00", "145.00"]
    assert "running seeds: 1-3" in out
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
