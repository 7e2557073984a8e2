"""Sweeps through Hydra's launcher plugins (the `cluster` extra): joblib, submitit, Ray.

One layer of parallelism at a time: under a launcher that runs jobs in parallel, each job's
seed pool steps aside (workers=1) -- a spawn pool inside a joblib (loky) worker would crash.
"""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from imix_cli.commands.cli import main
from imix_cli.running.files.results import read_run_csv

IMIX = str(Path(sys.executable).parent / "imix")
pytestmark = pytest.mark.cluster  # the launcher plugins come with the cluster extra

SWEEP = ["algo=cem", "generations=3", "seeds=2", "popsize=8,10", "progress=false"]


def assert_two_points(results: Path):
    for popsize in (8, 10):
        for seed in range(2):
            assert len(read_run_csv(results / "default" / f"cem-cartpole-none-popsize={popsize}" / f"seed_{seed}.csv")) == 3


@pytest.mark.slow
def test_joblib_launcher_runs_points_in_parallel_with_in_process_seeds(tmp_path):
    assert main(["run", "-m", "hydra/launcher=joblib", *SWEEP, f"results_dir={tmp_path}"]) == 0
    assert_two_points(tmp_path)


@pytest.mark.slow
def test_submitit_local_launcher(tmp_path):
    proc = subprocess.run([IMIX, "run", "-m", "hydra/launcher=submitit_local", *SWEEP, f"results_dir={tmp_path}"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert_two_points(tmp_path)


def test_slurm_launcher_is_configured(capsys):
    assert main(["run", "hydra/launcher=slurm", "--cfg", "hydra", "--package", "hydra.launcher"]) == 0
    out = capsys.readouterr().out
    assert "SlurmLauncher" in out and "cpus_per_task: 8" in out


@pytest.mark.slow
def test_ray_launcher_against_a_local_ray_started_here(tmp_path):
    ray = shutil.which("ray", path=str(Path(sys.executable).parent))
    assert ray, "the ray CLI comes with the cluster extra"
    start = subprocess.run(
        [ray, "start", "--head", "--num-cpus=2", "--disable-usage-stats", "--include-dashboard=false"], capture_output=True, text=True, timeout=180
    )
    assert start.returncode == 0, start.stderr[-2000:]
    try:
        proc = subprocess.run([IMIX, "run", "-m", "hydra/launcher=ray_cluster", *SWEEP, f"results_dir={tmp_path}"], capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert_two_points(tmp_path)
    finally:
        subprocess.run([ray, "stop", "--force"], capture_output=True, timeout=120)
