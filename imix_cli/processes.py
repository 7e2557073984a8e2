"""What every worker process of imix shares (the run's seed pool and the evaluation pool).

One BLAS thread per process is not set here: ``imix_cli/__init__.py`` sets it once, before numpy
loads, and spawned workers inherit it.
"""

from __future__ import annotations

import os
import threading
import time


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
