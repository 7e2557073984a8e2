"""A run's folder: checked against the config it holds, then locked and written while a run writes it.

``check_run_dir`` decides which seeds are still to run, reading only: a finished seed (its CSV
exists) is skipped, or continued when the config asks for more generations (from its final
checkpoint); results of a different config, a corrupt CSV, one that does not fit the config, or a
symbolic link anywhere in the folder are refused with one line (:class:`RunError`). The runner
calls it before taking the folder's lock, so a refused run writes nothing, not even its lock;
``prepare_run_dir`` checks again under the lock, then writes config.yaml.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat

from imix_cli.messages import MissingExtraError, RunError, shown_value
from imix_cli.running.config.run_spec import differing_keys, identity_of, resume_identity
from imix_cli.running.files.results import CorruptResultError, partial_csv_path, read_run_csv, seed_csv_path
from imix_cli.running.files.run_lock import LOCK_NAME
from imix_cli.running.files.safe_yaml import BadYamlError, load_yaml_file
from imix_cli.running.files.writing import atomic_write_text
from imix_cli.running.seed_checks import SCHEDULE_KEYS, check_seed_csv
from imix_cli.running.trainers import trainer_for


def check_run_dir(spec) -> tuple[list[int], bool]:
    """Check the run folder against ``spec`` without writing anything; return (seeds still to run, whether
    config.yaml is to be (re)written).

    Raises RunError (one line) if the algorithm's optional packages are not installed (:attr:`Trainer.missing_extra`),
    if the folder, the experiment folder or anything in the run folder is a
    symbolic link, if the folder holds results of a different config, a corrupt CSV, or a seed finished
    beyond ``generations`` (a run is never shortened below what a seed finished).
    """
    trainer = trainer_for(spec)
    missing = trainer.missing_extra()
    if missing:  # before anything is made: a run that cannot start leaves no folder for status to list
        raise MissingExtraError(missing)
    run_dir = spec.run_dir
    config_file = run_dir / "config.yaml"
    refuse_links(spec)
    old = recorded = None
    if config_file.exists():
        try:
            old = load_yaml_file(config_file)  # bounded: size, nesting, aliases expanded, tags (safe_yaml)
        except BadYamlError as err:
            raise RunError(f"{err}; move it away or choose another experiment=") from None
        except OSError as err:
            raise RunError(f"{config_file}: unreadable ({err.strerror or err}); move it away or choose another experiment=") from None
        except Exception as err:
            raise RunError(f"{config_file}: unreadable ({type(err).__name__}); move it away or choose another experiment=") from None
        if not isinstance(old, dict) or not all(isinstance(k, str) for k in old):
            raise RunError(f"{config_file}: not a config mapping; move it away or choose another experiment=")
        recorded = old
        old, new = identity_of(old), spec.identity()
        differing = differing_keys(resume_identity(old), resume_identity(new))
        if differing:
            # a value read from the file is shown shortened (shown_value: at most 200 characters, never expanded whole)
            changes = ", ".join(f"{k}={shown_value(old.get(k))} there, {shown_value(new.get(k))} now" for k in differing[:8])
            raise RunError(f"{config_file} holds a different config ({changes}); choose another experiment= or move that folder away")
    # The config the run's CSVs must agree with (check_seed_csv): this command's -- config.yaml's in every identity key,
    # checked above -- with the schedule of the distribution mean's measurements config.yaml records, which its seeds followed.
    kept = {k: recorded[k] for k in SCHEDULE_KEYS if recorded is not None and k in recorded}
    reference = {**spec.config, **kept}
    todo = []
    for seed in range(spec.seeds):
        path = seed_csv_path(run_dir, seed)
        if not path.exists():
            todo.append(seed)
            continue
        try:
            frame = read_run_csv(path)
            if trainer.needs_running(spec, seed, path, frame):
                todo.append(seed)
            check_seed_csv(frame, path, reference)  # a CSV of another run is not a finished seed of this one
        except CorruptResultError as err:
            raise RunError(f"{err}; move or delete it, then re-run") from None
    # A continuable run's generations may change (to more, or back to fewer than a continuation that was
    # killed reached): config.yaml records the latest target. What a run holds is its finished CSVs,
    # which needs_running has checked against that target.
    write_config = old is None or (trainer.continuable and old.get("generations") != spec.generations)
    changed = [k for k in kept if trainer.unit == "gen" and kept[k] != spec.config.get(k)]
    if changed and (todo or write_config):  # eval_mean_* do not change results, but a CSV must follow one schedule
        was = ", ".join(f"{k}={kept[k]}" for k in changed)
        raise RunError(
            f"{config_file} was made with {was}, the command has {', '.join(f'{k}={spec.config.get(k)}' for k in changed)} (a changed default?): "
            f"seeds continued or started now would measure the distribution mean on another schedule; give {was} to resume, or choose another experiment="
        )
    return todo, write_config


def prepare_run_dir(spec) -> list[int]:
    """Check the run folder (:func:`check_run_dir`), write config.yaml, clear what a kill left; return the seeds still to run.

    Called under the folder's lock (:func:`run_dir_lock`); nothing existing is overwritten but
    config.yaml's recorded target (``generations``) and the temporaries of killed writes.
    """
    import yaml

    todo, write_config = check_run_dir(spec)
    run_dir = spec.run_dir
    make_run_dir(spec)
    for seed in range(spec.seeds):
        if seed_csv_path(run_dir, seed).exists():
            partial_csv_path(run_dir, seed).unlink(missing_ok=True)  # left by a kill between the CSV and its clean-up
    if write_config:  # new, or continued to another number of generations
        atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(spec.config, sort_keys=False))
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


#: Where a run's checkpoints live (imix_cli.running.files.checkpoints.checkpoint_path).
CHECKPOINT_AREA = ".checkpoints"


def refuse_links(spec) -> None:
    """RunError if the experiment folder, the run folder, or an entry of the run folder (or of its
    ``.checkpoints``) is a symbolic link.

    Why: a results folder travels (copied from a cluster, shared, downloaded); a link in it would
    make imix write, or delete, outside results_dir (a ``.lock`` pointing at a user's file would
    get a pid written into it). ``results_dir`` itself may be a link: the user chose it.
    """
    experiment_dir = spec.run_dir.parent
    for folder in (experiment_dir, spec.run_dir):
        if folder.is_symlink():
            raise RunError(
                f"{folder} is a symbolic link; imix writes through no link inside results_dir (only results_dir itself may be one): replace it by a folder"
            )
    for folder in (spec.run_dir, spec.run_dir / CHECKPOINT_AREA):
        if folder.is_symlink() or not folder.is_dir():
            continue
        for entry in os.scandir(folder):
            if entry.is_symlink():
                raise RunError(f"{entry.path} is a symbolic link; imix follows no link in a run folder: remove it, then re-run")


def make_run_dir(spec) -> None:
    run_dir = spec.run_dir
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise RunError(f"results_dir={spec.results_dir!r}: cannot create {run_dir} ({err.strerror or err})") from None
    if not os.access(run_dir, os.W_OK):
        raise RunError(f"results_dir={spec.results_dir!r}: {run_dir} is not writable")


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
    try:  # O_NOFOLLOW: a link planted at .lock is refused, never followed (its target would get our pid)
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK, 0o666)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise RunError(f"{path} is a symbolic link; imix follows no link in a run folder: remove it, then re-run") from None
        raise
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise RunError(f"{path} is not a regular file; remove it, then re-run")
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
