"""What every worker process of imix shares (the run's seed pool and the evaluation pool).

One BLAS thread per process: imix's matrices are tiny, its seeds already run one process per
core, and two BLAS threads fighting over two cores made CMA-ES's eigendecomposition 10x slower.
That default belongs to imix's own processes only -- the ``imix`` command (set before numpy loads,
:func:`set_one_blas_thread`) and the workers it spawns (:func:`one_blas_thread` around their start,
so a library user's workers get it too) -- and never to a user's Python that imports imix_cli.
A variable the user set is left as it is.
"""

from __future__ import annotations

import os
import threading
import time
from contextlib import contextmanager

#: The thread-count variables of OpenBLAS, OpenMP and MKL (numpy reads them when it loads).
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def set_one_blas_thread() -> None:
    """In the ``imix`` command's own process, before numpy loads: one BLAS thread unless the user chose."""
    for var in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(var, "1")


@contextmanager
def one_blas_thread():
    """While worker processes are spawned: they inherit one BLAS thread (unless the user chose);
    the calling process's environment is restored afterwards."""
    added = [var for var in BLAS_THREAD_VARIABLES if var not in os.environ]
    for var in added:
        os.environ[var] = "1"
    try:
        yield
    finally:
        for var in added:
            os.environ.pop(var, None)


def default_workers() -> int:
    """All cores this process may use (respects CPU affinity, e.g. a Slurm allocation)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def start_orphan_watchdog(parent_pid: int) -> None:
    """A worker whose main process died (kill -9) must not linger, idle on its task queue forever
    or racing a re-run: a daemon thread makes it exit within a second (its checkpoints stay valid)."""
    threading.Thread(target=_exit_when_orphaned, args=(parent_pid,), daemon=True).start()


def _exit_when_orphaned(parent_pid: int) -> None:
    while True:
        time.sleep(1.0)
        if os.getppid() != parent_pid:
            os._exit(1)
