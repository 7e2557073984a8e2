"""logger=tensorboard|mlflow|wandb: each generation's CSV row, copied to a tracker; the CSV stays the record.

The event files are read back with TensorBoard's own EventAccumulator and must hold exactly the
CSV's numbers (float32, as TensorBoard stores scalars), one step per generation, also for a seed
continued in a second process after a first one logged beyond its last state."""

import os
import subprocess
import sys
import time

import numpy as np
import pytest

import imix_cli
from imix_cli.running.files.results import read_run_csv
from imix_cli.running.files.tracking import TRACKED_COLUMNS, tensorboard_dir


def _scalars(directory):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(directory), size_guidance={"scalars": 0})
    acc.Reload()
    return {tag: [(e.step, e.value) for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


def _assert_same_as_csv(scalars, frame):
    for column in TRACKED_COLUMNS:
        expected = [(int(g), np.float32(v)) for g, v in zip(frame["generation"], frame[column]) if np.isfinite(v)]
        got = [(step, np.float32(value)) for step, value in scalars.get(column, [])]
        assert got == expected, column


def _run(tmp_path, generations, workers=1, **keys):
    return imix_cli.run(algo="cem", env="cartpole", eim=True, seeds=2, generations=generations, workers=workers, popsize=10,
                        eval_mean_every=2, checkpoint_every=2, checkpoint_seconds=0, results_dir=str(tmp_path), experiment="tb", echo=None, **keys)  # fmt: skip


@pytest.mark.tensorboard
@pytest.mark.parametrize("workers", [1, 2])  # 2: each seed's events written by its worker process
def test_tensorboard_event_files_hold_the_csvs_numbers(tmp_path, workers):
    frame = _run(tmp_path, 4, workers=workers, logger="tensorboard")
    run_dir = tmp_path / "tb" / frame["run"].iloc[0]
    for seed in (0, 1):
        scalars = _scalars(tensorboard_dir(run_dir, seed))
        _assert_same_as_csv(scalars, read_run_csv(run_dir / f"seed_{seed}.csv"))
    assert len(scalars["mean_policy_score"]) == 2  # measured at generations 0 and 2 only (NaN elsewhere is not logged)


@pytest.mark.tensorboard
def test_a_continued_seed_replaces_what_a_killed_process_logged_after_its_last_state(tmp_path):
    from tensorboard.compat.proto import event_pb2, summary_pb2
    from tensorboard.summary.writer.event_file_writer import EventFileWriter

    frame = _run(tmp_path, 4, logger="tensorboard")
    run_dir = tmp_path / "tb" / frame["run"].iloc[0]
    # A process that logged generation 4 (a bogus value) and was killed before saving it:
    time.sleep(1.1)  # event file names carry the second they were made: keep this one's after the first
    writer = EventFileWriter(str(tensorboard_dir(run_dir, 0)))
    bogus = summary_pb2.Summary(value=[summary_pb2.Summary.Value(tag="mean_score", simple_value=-12345.0)])
    writer.add_event(event_pb2.Event(wall_time=time.time(), step=4, summary=bogus))
    writer.close()
    time.sleep(1.1)
    _run(tmp_path, 6, logger="tensorboard")  # continues each seed from its final state at generation 4
    scalars = _scalars(tensorboard_dir(run_dir, 0))
    _assert_same_as_csv(scalars, read_run_csv(run_dir / "seed_0.csv"))


@pytest.mark.tensorboard
def test_logger_is_not_part_of_a_runs_identity(tmp_path):
    """A tracker only copies the CSV's rows: the same run with logger=tensorboard is the same run folder, whose
    finished seeds are skipped (not re-run, not refused as another config)."""
    first = _run(tmp_path, 2)
    (folder,) = [p for p in (tmp_path / "tb").iterdir() if p.is_dir()]
    before = {p.name: p.read_bytes() for p in folder.glob("seed_*.csv")}
    second = _run(tmp_path, 2, logger="tensorboard")
    assert [p for p in (tmp_path / "tb").iterdir() if p.is_dir()] == [folder]
    assert {p.name: p.read_bytes() for p in folder.glob("seed_*.csv")} == before and len(before) == 2
    assert first.equals(second)


def test_a_bad_or_missing_logger_is_one_line_before_anything_runs(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(os.path.dirname(os.path.dirname(__file__))), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run(
        [sys.executable, "-m", "imix_cli.commands.cli", "run", "logger=comet", f"results_dir={tmp_path}"], capture_output=True, text=True, env=env
    )
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "logger=" in proc.stderr and "tensorboard" in proc.stderr
    assert not any(tmp_path.iterdir())


@pytest.mark.mlflow
def test_mlflow_gets_one_run_per_seed_with_the_csvs_numbers(tmp_path, monkeypatch):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", (tmp_path / "mlruns").as_uri())  # a local file store (no server, no database)
    monkeypatch.setenv("MLFLOW_ALLOW_FILE_STORE", "true")
    frame = _run(tmp_path, 3, logger="mlflow")
    import mlflow

    client = mlflow.MlflowClient((tmp_path / "mlruns").as_uri())
    experiment = client.get_experiment_by_name("tb")
    runs = {r.info.run_name: r for r in client.search_runs([experiment.experiment_id])}
    name = frame["run"].iloc[0]
    assert sorted(runs) == [f"{name}/seed_0", f"{name}/seed_1"]
    csv = read_run_csv(tmp_path / "tb" / name / "seed_1.csv")
    history = client.get_metric_history(runs[f"{name}/seed_1"].info.run_id, "mean_score")
    assert [(m.step, m.value) for m in sorted(history, key=lambda m: m.step)] == list(zip(csv["generation"], csv["mean_score"]))
    assert runs[f"{name}/seed_1"].data.params["popsize"] == "10"


@pytest.mark.wandb
def test_wandb_offline_gets_one_run_per_seed(tmp_path, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    frame = _run(tmp_path, 2, logger="wandb")
    offline = sorted((tmp_path / "tb" / frame["run"].iloc[0] / "wandb").glob("offline-run-*"))
    assert len(offline) == 2 and all(any(d.glob("*.wandb")) for d in offline)


def test_a_tracker_gets_each_float_as_the_csv_writes_it():
    """The CSV keeps 10 significant digits; a tracker that got the unrounded value could store another
    float32 than the CSV's (this value is one: it rounds to different float32s with and without)."""
    from imix_cli.running.files.results import FLOAT_FORMAT
    from imix_cli.running.files.tracking import scalars

    value = 0.0016486371752648665
    written = float(FLOAT_FORMAT % value)
    assert np.float32(value) != np.float32(written)
    got = scalars({"wall_time": value, "evaluations": 7, "mean_policy_score": float("nan")})
    assert got["wall_time"] == written and got["evaluations"] == 7.0 and "mean_policy_score" not in got
