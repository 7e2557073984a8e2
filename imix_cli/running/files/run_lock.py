"""Whether a live ``imix run`` holds a run folder: read without taking the lock (for ``imix status``).

The lock itself is taken by :func:`imix_cli.running.run_folder.run_dir_lock` (``fcntl.flock`` on
``<run_dir>/.lock``, which holds the holder's pid). This module imports nothing but the standard library:
``imix status`` loads neither numba nor the envs.
"""

from __future__ import annotations

import os
import stat

#: The lock file of a run folder.
LOCK_NAME = ".lock"


def lock_holder(run_dir) -> int | None:
    """The pid of the live ``imix run`` holding ``run_dir``'s lock (:func:`imix_cli.running.run_folder.run_dir_lock`), or None; reads only.

    Why not try the lock: a reader taking it, even for an instant, would make a run starting at that instant
    refuse the folder as in use. Instead: the pid written in ``.lock``, alive and holding a lock on that very
    file as the kernel lists it (``/proc/locks``: a pid reused by another process holds no lock on it). Where
    ``/proc/locks`` cannot be read (not Linux), a live process of that pid is taken as the holder."""
    path = os.path.join(run_dir, LOCK_NAME)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            return None
        text = os.pread(fd, 32, 0).decode(errors="replace").strip()
    finally:
        os.close(fd)
    if not text.isdigit():
        return None
    pid = int(text)
    try:
        with open("/proc/locks") as fh:
            locks = fh.read().splitlines()
    except OSError:
        try:
            os.kill(pid, 0)
        except PermissionError:
            return pid
        except OSError:
            return None
        return pid
    where = f"{os.major(info.st_dev):02x}:{os.minor(info.st_dev):02x}:{info.st_ino}"
    for line in locks:  # "1: FLOCK  ADVISORY  WRITE 1234 fe:00:2147282 0 EOF"
        fields = line.split()
        if len(fields) >= 6 and fields[1] == "FLOCK" and fields[4] == str(pid) and fields[5] == where:
            return pid
    return None
