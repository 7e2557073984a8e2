"""Fixtures shared by several test files."""

import errno
from pathlib import Path

import pytest


@pytest.fixture
def csv_disk_full(monkeypatch):
    """Every fsync of a seed CSV being written (its ``.seed_*`` temporary) fails with ENOSPC, as on a full disk."""
    import imix_cli.results as results_module

    real_fsync = results_module.os.fsync

    def fsync_fails_for_csvs(fd):
        if Path(f"/proc/self/fd/{fd}").resolve().name.startswith(".seed_"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_fsync(fd)

    monkeypatch.setattr(results_module.os, "fsync", fsync_fails_for_csvs)
