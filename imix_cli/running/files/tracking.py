"""Experiment trackers (``logger=tensorboard|wandb|mlflow``): the CSV's numbers, live, in the tool a lab already uses.

Why only a copy: the seed CSVs stay the contract (plots, ``imix status``, resume read them); a
tracker gets, per seed and per generation, the numeric columns of the row just written to the
CSV, with the generation as the step, and nothing else. One small interface (:class:`Tracker`:
``log(seed, row)``, ``close()``) is implemented three times:

``tensorboard``  event files ``<run>/tensorboard/seed_<k>/events.out.tfevents.*``, written with the
                 ``tensorboard`` package's own event writer (no TensorFlow, no torch). A seed that
                 resumes from a checkpoint starts its new file with TensorBoard's restart marker at
                 that generation, so readers drop what the killed process logged after it.
``mlflow``       one MLflow run per seed (run name ``<run>/seed_<k>``, the config as params), in
                 the experiment named by ``experiment=``; where it goes is MLflow's own setting
                 (``MLFLOW_TRACKING_URI``: a server, ``sqlite:///mlflow.db``, or a ``file:`` store with
                 ``MLFLOW_ALLOW_FILE_STORE=true`` since MLflow 3.17).
``wandb``        one W&B run per seed (project ``imix``, group ``<experiment>/<run>``, the config);
                 ``WANDB_MODE=offline`` keeps it on disk. Needs a login otherwise.

The packages are optional extras (``pip install ".[tensorboard]"`` from the imix clone, ``[mlflow]``, ``[wandb]``);
a missing one is refused before the run starts.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

#: logger= values -> the module each needs (checked before the run) and the extra that installs it.
LOGGERS = {"none": None, "tensorboard": ("tensorboard", "tensorboard"), "mlflow": ("mlflow", "mlflow"), "wandb": ("wandb", "wandb")}

#: The CSV columns a tracker receives (every numeric column but the seed and the generation, which is the step).
TRACKED_COLUMNS = (
    "evaluations", "env_steps", "mean_score", "best_score", "reused", "reused_im", "reused_eim", "reevaluated",
    "popsize", "sigma_mean", "nonfinite", "wall_time", "mean_policy_score", "mean_policy_episodes", "diverged",
)  # fmt: skip

__all__ = ["LOGGERS", "TRACKED_COLUMNS", "Tracker", "make_tracker", "missing_logger_package", "tensorboard_dir"]


def missing_logger_package(logger: str) -> str | None:
    """One line saying how to install what ``logger`` needs, or None if it is installed (or not needed)."""
    import importlib.util

    needs = LOGGERS[logger]
    if needs is None or importlib.util.find_spec(needs[0]) is not None:
        return None
    from imix_cli.messages import install_extra

    return f"logger={logger}: {needs[0]} is not installed; {install_extra(needs[1])}"


def scalars(row: dict) -> dict:
    """The tracked numbers of a CSV row, as the CSV writes them: finite values of :data:`TRACKED_COLUMNS`
    (``mean_policy_score`` is NaN on generations where theta is not measured; no tracker wants those)."""
    from imix_cli.running.files.results import as_written

    out = {}
    for column in TRACKED_COLUMNS:
        value = row.get(column, 0 if column == "diverged" else None)  # the CSV's diverged is 0 unless set
        if value is not None and math.isfinite(float(value)):
            out[column] = as_written(value) if isinstance(value, float) else float(value)
    return out


class Tracker:
    """Receives each seed's rows as they are made; :func:`make_tracker` builds the one ``logger=`` names."""

    def log(self, seed: int, row: dict) -> None:
        raise NotImplementedError

    def close(self) -> None:
        pass


def tensorboard_dir(run_dir, seed: int) -> Path:
    return Path(run_dir) / "tensorboard" / f"seed_{seed}"


class TensorBoardTracker(Tracker):
    """One event file per seed and process; generation = step (module docstring)."""

    def __init__(self, spec):
        self.run_dir = spec.run_dir
        self.writers = {}

    def start(self, seed: int, generation: int) -> None:
        """Open seed ``seed``'s writer; a seed resumed at ``generation`` > 0 marks the restart there."""
        from tensorboard.compat.proto import event_pb2
        from tensorboard.summary.writer.event_file_writer import EventFileWriter

        writer = EventFileWriter(str(tensorboard_dir(self.run_dir, seed)))
        if generation:  # TensorBoard drops events of earlier files at steps >= this one (torch's purge_step)
            start = event_pb2.SessionLog(status=event_pb2.SessionLog.START)
            writer.add_event(event_pb2.Event(wall_time=time.time(), step=generation, session_log=start))
        self.writers[seed] = writer

    def log(self, seed: int, row: dict) -> None:
        from tensorboard.compat.proto import event_pb2, summary_pb2

        if seed not in self.writers:
            self.start(seed, int(row["generation"]))
        values = [summary_pb2.Summary.Value(tag=k, simple_value=v) for k, v in scalars(row).items()]
        event = event_pb2.Event(wall_time=time.time(), step=int(row["generation"]), summary=summary_pb2.Summary(value=values))
        self.writers[seed].add_event(event)

    def close(self) -> None:
        for writer in self.writers.values():
            writer.close()
        self.writers = {}


class MLflowTracker(Tracker):
    """One MLflow run per seed (module docstring)."""

    def __init__(self, spec):
        import mlflow

        self.mlflow, self.spec, self.runs = mlflow, spec, {}
        self.client = mlflow.MlflowClient()
        experiment = self.client.get_experiment_by_name(spec.experiment)
        if experiment is None:
            try:
                self.experiment_id = self.client.create_experiment(spec.experiment)
            except mlflow.exceptions.MlflowException:  # another worker process of the run created it first
                self.experiment_id = self.client.get_experiment_by_name(spec.experiment).experiment_id
        else:
            self.experiment_id = experiment.experiment_id

    def log(self, seed: int, row: dict) -> None:
        from mlflow.entities import Metric

        if seed not in self.runs:
            run = self.client.create_run(self.experiment_id, run_name=f"{self.spec.run_name}/seed_{seed}", tags={"imix.run": self.spec.run_name})
            for key, value in flat_keys(self.spec.config).items():
                self.client.log_param(run.info.run_id, key, value)
            self.runs[seed] = run.info.run_id
        now, step = int(time.time() * 1000), int(row["generation"])
        metrics = [Metric(key, value, now, step) for key, value in scalars(row).items()]
        self.client.log_batch(self.runs[seed], metrics=metrics)

    def close(self) -> None:
        for run_id in self.runs.values():
            self.client.set_terminated(run_id)
        self.runs = {}


class WandbTracker(Tracker):
    """One W&B run per seed (module docstring)."""

    def __init__(self, spec):
        import wandb

        self.wandb, self.spec, self.runs = wandb, spec, {}

    def log(self, seed: int, row: dict) -> None:
        if seed not in self.runs:
            self.runs[seed] = self.wandb.init(
                project="imix", group=f"{self.spec.experiment}/{self.spec.run_name}", name=f"{self.spec.run_name}/seed_{seed}",
                config=self.spec.config, dir=str(self.spec.run_dir), reinit="create_new",
            )  # fmt: skip
        self.runs[seed].log(scalars(row), step=int(row["generation"]))

    def close(self) -> None:
        for run in self.runs.values():
            run.finish()
        self.runs = {}


def make_tracker(spec) -> Tracker | None:
    """The tracker of ``spec.logger`` (None for ``logger=none``)."""
    kind = getattr(spec, "logger", "none")
    return {"none": lambda s: None, "tensorboard": TensorBoardTracker, "mlflow": MLflowTracker, "wandb": WandbTracker}[kind](spec)


def flat_keys(config: dict, prefix: str = "") -> dict:
    """``{"algo": {"name": "cmaes"}}`` -> ``{"algo.name": "cmaes"}``: each setting named as its key is written."""
    out = {}
    for key, value in config.items():
        if isinstance(value, dict):
            out.update(flat_keys(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out
