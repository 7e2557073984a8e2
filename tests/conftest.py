"""Fixtures shared by several test files.

The test process is one of imix's own: it gets imix's one-BLAS-thread default before anything loads
numpy (``import imix_cli`` no longer sets it; tiny CMA-ES matrices on two BLAS threads of a loaded
2-core machine ran ~5x slower). The test of the library's promise runs in a subprocess of its own.
"""

import errno
from pathlib import Path

import pytest

from imix_cli.processes import set_one_blas_thread

set_one_blas_thread()


@pytest.fixture
def csv_disk_full(monkeypatch):
    """Every fsync of a seed CSV being written (its ``.seed_*.csv.*`` temporary; not a checkpoint's) fails with ENOSPC, as on a full disk."""
    import imix_cli.running.results as results_module

    real_fsync = results_module.os.fsync

    def fsync_fails_for_csvs(fd):
        name = Path(f"/proc/self/fd/{fd}").resolve().name
        if name.startswith(".seed_") and ".csv." in name:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_fsync(fd)

    monkeypatch.setattr(results_module.os, "fsync", fsync_fails_for_csvs)
