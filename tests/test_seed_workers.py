"""A run's seed workers are forked from a server that has imported what they run (imix_cli.core.processes,
"the seed workers' fork server"): they must run as spawned workers do -- the caller's environment of now, the same
numbers -- and the program must keep its accounting of them."""

import os

import pandas as pd
import pytest

import imix_cli
from imix_cli.core import processes
from imix_cli.running import pool

pytestmark = pytest.mark.skipif("forkserver" not in __import__("multiprocessing").get_all_start_methods(), reason="no fork server here")


def read_variable(name, chunk):
    """A pool task (module level: the workers import it by name): this worker's value of ``name``, and its chunk."""
    return os.environ.get(name), chunk


def test_a_variable_set_after_the_fork_server_started_reaches_the_workers(monkeypatch):
    """A fork carries the server's environment, not the caller's: a variable set since the server started
    (``IMIX_COMPILED_LOOP=0``) would silently not reach the workers; one read at import (a numba or BLAS setting)
    cannot reach a forked worker at all, so the workers are spawned then. Made to fail by not giving the forked
    workers the caller's variables (pool._init_worker): they read None."""
    pool.start_worker_server()
    assert pool.run_pool(read_variable, "IMIX_TEST_SEED_WORKERS", [[0], [1]], pool._NoBar()) == [(None, [0]), (None, [1])]
    monkeypatch.setenv("IMIX_TEST_SEED_WORKERS", "set after the server")
    assert processes.seed_worker_context(pool.SEED_WORKER_MODULES).get_start_method() == "forkserver"
    assert pool.run_pool(read_variable, "IMIX_TEST_SEED_WORKERS", [[0], [1]], pool._NoBar()) == [("set after the server", [0]), ("set after the server", [1])]
    monkeypatch.setenv("NUMBA_IMIX_TEST_SEED_WORKERS", "read at import")
    assert processes.seed_worker_context(pool.SEED_WORKER_MODULES).get_start_method() == "spawn"
    assert pool.run_pool(read_variable, "NUMBA_IMIX_TEST_SEED_WORKERS", [[0]], pool._NoBar()) == [("read at import", [0])]


def test_a_variable_read_when_used_set_after_the_server_started_keeps_the_workers_forked(monkeypatch):
    """``ray.init()`` sets PYTHONBREAKPOINT in the caller's process (read by ``breakpoint()`` at each call, not at import):
    the runs of that process after it kept spawning their workers (found when the suite ran Ray's tests before these).
    Made to fail by counting PYTHONBREAKPOINT among the variables read at import again: the context is spawn's."""
    pool.start_worker_server()
    monkeypatch.setenv("PYTHONBREAKPOINT", "ray.util.rpdb._driver_set_trace")
    assert processes.seed_worker_context(pool.SEED_WORKER_MODULES).get_start_method() == "forkserver"
    assert pool.run_pool(read_variable, "PYTHONBREAKPOINT", [[0]], pool._NoBar()) == [("ray.util.rpdb._driver_set_trace", [0])]


def test_forked_and_spawned_workers_write_the_same_csvs(tmp_path, monkeypatch):
    """The same run with workers forked from the server and with spawned workers (forced by a variable read at import,
    set after the server started): every CSV identical but its wall times, and the CPU time of the forked workers counted."""
    small = {"algo": "snes", "env": "acrobot", "eim": True, "seeds": 4, "generations": 12, "popsize": 20, "workers": 2, "echo": None}
    pool.start_worker_server()
    assert processes.seed_worker_context(pool.SEED_WORKER_MODULES).get_start_method() == "forkserver"
    before = pool.forked_workers_cpu_seconds()
    forked = imix_cli.run(**small, results_dir=str(tmp_path / "forked"))
    assert pool.forked_workers_cpu_seconds() > before  # imix bench's CPU column counts them
    monkeypatch.setenv("NUMBA_IMIX_TEST_SEED_WORKERS", "spawn")
    assert processes.seed_worker_context(pool.SEED_WORKER_MODULES).get_start_method() == "spawn"
    spawned = imix_cli.run(**small, results_dir=str(tmp_path / "spawned"))
    assert len(forked) == 4 * 12
    pd.testing.assert_frame_equal(forked.drop(columns=["wall_time"]), spawned.drop(columns=["wall_time"]))
