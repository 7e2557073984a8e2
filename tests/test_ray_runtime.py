"""evaluator=ray: one Ray runtime per run, sized to it; a lost actor restarted (or reported in one line);
no process left behind after Ctrl-C, SIGTERM or kill -9 of the main process."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from process_tree import alive, cmdline, descendants

from imix_cli.running.config.compose import ConfigError, validate_overrides

pytestmark = pytest.mark.cluster

IMIX = str(Path(sys.executable).parent / "imix")


def test_evaluator_ray_runs_the_seeds_in_one_process():
    """One process drives the Ray runtime: seed processes each starting their own Ray (each sized
    to every CPU) is what made 2 seeds start 2 clusters and 4 actors on 2 cores."""
    (spec,) = validate_overrides(["evaluator=ray", "seeds=4"])
    assert spec.workers == 1
    with pytest.raises(ConfigError, match=r"workers=2.*evaluator=ray"):
        validate_overrides(["evaluator=ray", "workers=2"])


def _actor_pid(evaluator, k: int) -> int:
    import ray

    return ray.get(evaluator._actors[k].__ray_call__.remote(lambda self: os.getpid()), timeout=60)


def test_a_local_ray_is_sized_to_the_run_and_a_killed_actor_is_restarted():
    import ray

    from imix_cli.core.evaluation.parallel import RayEvaluator

    evaluator = RayEvaluator("cartpole", hidden=(4,), workers=1)
    try:
        assert ray.cluster_resources().get("CPU") == 1  # not every CPU of the machine
        rng = np.random.default_rng(0)
        params, seeds = rng.normal(size=(12, evaluator.num_params)), np.arange(12)
        before = evaluator.evaluate(params, seeds)
        os.kill(_actor_pid(evaluator, 0), signal.SIGKILL)
        after = evaluator.evaluate(params, seeds)  # same episodes on the restarted actor
        assert np.array_equal(before[0], after[0]) and np.array_equal(before[1], after[1])
    finally:
        evaluator.close()


def test_an_actor_lost_for_good_is_one_line(monkeypatch):
    from imix_cli.core.evaluation.parallel import EvaluatorError, RayEvaluator

    monkeypatch.setattr(RayEvaluator, "max_restarts", 0)
    evaluator = RayEvaluator("cartpole", hidden=(4,), workers=1)
    try:
        os.kill(_actor_pid(evaluator, 0), signal.SIGKILL)
        time.sleep(1)
        with pytest.raises(EvaluatorError) as caught:
            evaluator.evaluate(np.zeros((3, evaluator.num_params)), np.arange(3))
        assert len(str(caught.value).splitlines()) == 1 and "evaluator=ray" in str(caught.value)
    finally:
        evaluator.close()


# ------------------------------------------------------------------ nothing left behind
@pytest.mark.parametrize("stop", ["kill -9", "Ctrl-C", "SIGTERM"])
def test_no_process_is_left_behind(tmp_path, stop):
    args = [IMIX, "run", "algo=cem", "seeds=2", "generations=100000", "popsize=8", "checkpoint_every=5", "checkpoint_seconds=0",
            "evaluator=ray", "evaluator_workers=1",
            "progress=false", f"results_dir={tmp_path}"]  # fmt: skip
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)
    seen = set()
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.rglob(".checkpoints/seed_*.npz")) and time.monotonic() < deadline and proc.poll() is None:
            seen |= descendants(proc.pid)
            time.sleep(0.2)
        for _ in range(10):  # Ray's helpers (agents) start a little later
            seen |= descendants(proc.pid)
            time.sleep(0.2)
        assert any("ray::" in cmdline(p) for p in seen), [cmdline(p) for p in seen]
        assert sum("gcs_server" in cmdline(p) for p in seen) == 1  # one Ray runtime for the run
        if stop == "kill -9":
            os.kill(proc.pid, signal.SIGKILL)
        elif stop == "Ctrl-C":
            os.killpg(proc.pid, signal.SIGINT)  # what a terminal does: the whole foreground group
        else:
            os.kill(proc.pid, signal.SIGTERM)
        code = proc.wait(timeout=60)
        deadline = time.monotonic() + 15
        while any(alive(p) for p in seen) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = {p: cmdline(p) for p in seen if alive(p)}
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        for p in seen:
            if alive(p):
                try:
                    os.kill(p, signal.SIGKILL)
                except OSError:
                    pass
    assert not left, left
    if stop != "kill -9":
        err = proc.stderr.read().strip()
        assert code == {"Ctrl-C": 130, "SIGTERM": 143}[stop], (code, err)
        assert len(err.splitlines()) == 1 and "Traceback" not in err, err
