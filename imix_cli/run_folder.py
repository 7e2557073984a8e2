"""A run's folder: created, checked against the config it holds, locked while a run writes it.

``prepare_run_dir`` decides which seeds are still to run: a finished seed (its CSV exists) is
skipped, or continued when the config asks for more generations (from its final checkpoint);
results of a different config, a corrupt CSV or one that does not fit the config are refused
with one line (:class:`RunError`) before anything is written.
"""

from __future__ import annotations

import contextlib
import os
import reprlib

from imix_cli.results import CorruptResultError, atomic_write_text, partial_csv_path, read_run_csv, regular_file_size, seed_csv_path
from imix_cli.run_spec import differing_keys, identity_of, resume_identity
from imix_cli.trainers import trainer_for

#: The largest config.yaml read back (a real one is a few kB).
MAX_CONFIG_BYTES = 1 << 20


class RunError(RuntimeError):
    """A run cannot proceed (existing results conflict, unwritable folder...); one-line message."""


def prepare_run_dir(spec) -> list[int]:
    """Create the run folder, check/write config.yaml, and return the seeds still to run.

    Raises RunError if the folder holds results of a different config or a corrupt CSV;
    nothing existing is overwritten.
    """
    import yaml

    trainer = trainer_for(spec)
    run_dir = spec.run_dir
    config_file = run_dir / "config.yaml"
    make_run_dir(spec)
    refuse_symlinks(run_dir)
    if config_file.exists():
        try:
            if regular_file_size(config_file) > MAX_CONFIG_BYTES:  # a config is a few kB: bound what a reader allocates
                raise ValueError(f"{config_file.stat().st_size:,} bytes")
            existing = yaml.safe_load(config_file.read_text())
        except OSError as err:
            raise RunError(f"{config_file}: unreadable ({err.strerror or err}); move it away or choose another experiment=") from None
        except Exception as err:
            raise RunError(f"{config_file}: unreadable ({type(err).__name__}); move it away or choose another experiment=") from None
        if not isinstance(existing, dict) or not all(isinstance(k, str) for k in existing):
            raise RunError(f"{config_file}: not a config mapping; move it away or choose another experiment=")
        old, new = identity_of(existing), spec.identity()
        differing = differing_keys(resume_identity(old), resume_identity(new))
        if differing:
            # reprlib: a value read from the file is shown shortened (a YAML alias bomb must not expand here)
            changes = ", ".join(f"{k}={reprlib.repr(old.get(k))} there, {new.get(k)!r} now" for k in differing[:8])
            raise RunError(f"{config_file} holds a different config ({changes}); choose another experiment= or move that folder away")
        if trainer.continuable and isinstance(old.get("generations"), int) and old["generations"] > spec.generations:
            raise RunError(
                f"{config_file} holds a different config (generations={old['generations']} there, {spec.generations} now): "
                "a run can be continued to more generations, not shortened; choose another experiment= or move that folder away"
            )
    continued = config_file.exists() and trainer.continuable and old.get("generations") != spec.generations
    todo = []
    for seed in range(spec.seeds):
        path = seed_csv_path(run_dir, seed)
        if not path.exists():
            todo.append(seed)
            continue
        try:
            frame = read_run_csv(path)
        except CorruptResultError as err:
            raise RunError(f"{err}; move or delete it, then re-run") from None
        partial_csv_path(run_dir, seed).unlink(missing_ok=True)  # left by a kill between the CSV and its clean-up
        if trainer.needs_running(spec, seed, path, frame):
            todo.append(seed)
    if not config_file.exists() or continued:  # new, or continued to more generations
        atomic_write_text(config_file, yaml.safe_dump(spec.config, sort_keys=False))
    # Temporaries of writes cut short by a kill are never at a final name; clear them away. (run()
    # holds the folder's lock, so no other live run is writing them; an orphaned worker of a
    # killed run exits within a second and only loses a write that is redone on resume.)
    # Only plain files inside the run folder: a symlinked checkpoint area was refused above, and a
    # symlink named like a temporary is only unlinked itself (never its target).
    for folder in (run_dir, run_dir / CHECKPOINT_AREA):
        if folder.is_dir() and not folder.is_symlink():
            for stale in folder.glob(".*.tmp"):
                if stale.parent == folder and (stale.is_symlink() or stale.is_file()):
                    stale.unlink(missing_ok=True)
    return todo


#: Where a run's checkpoints live (imix_cli.resume.checkpoint_path).
CHECKPOINT_AREA = ".checkpoints"


def refuse_symlinks(run_dir) -> None:
    """RunError if the run's checkpoint area, or anything in it, is a symlink.

    Why: imix writes checkpoints there, reads them back and deletes its temporaries there; a
    symlink (a results folder from elsewhere, a prank) would make it write, read or delete
    outside the run folder. It is refused, never followed.
    """
    area = run_dir / CHECKPOINT_AREA
    if area.is_symlink():
        raise RunError(f"{area} is a symlink; imix never writes or deletes through one: replace it with a folder (or remove it)")
    if area.is_dir():
        linked = next((p for p in sorted(area.iterdir()) if p.is_symlink()), None)
        if linked is not None:
            raise RunError(f"{linked} is a symlink in {CHECKPOINT_AREA}; imix never reads, writes or deletes through one: remove it")


def make_run_dir(spec) -> None:
    run_dir = spec.run_dir
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise RunError(f"results_dir={spec.results_dir!r}: cannot create {run_dir} ({err.strerror or err})") from None
    if not os.access(run_dir, os.W_OK):
        raise RunError(f"results_dir={spec.results_dir!r}: {run_dir} is not writable")


LOCK_NAME = ".lock"


@contextlib.contextmanager
def run_dir_lock(spec):
    """Hold the run folder's lock for the ``with`` block; RunError at once if another run holds it.

    ``fcntl.flock`` on ``<run_dir>/.lock``: the kernel drops the lock when its holder exits,
    however it dies (kill -9 included), so a stale lock file never blocks a re-run. The file
    holds the holder's pid, for the message.
    """
    import fcntl

    make_run_dir(spec)
    path = spec.run_dir / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            raise RunError(f"{spec.run_dir} is in use by another imix run (pid {holder}); wait for it to end, or choose another experiment=") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock
