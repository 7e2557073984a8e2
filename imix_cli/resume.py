"""Where a seed's state waits between processes: its checkpoint files in a run folder.

A checkpoint of a seed's whole state (:class:`imix_cli.lockstep.SeedState`: ES, archive, RNG
states, rows so far) is written atomically to ``.checkpoints/seed_<k>.npz`` (plain data, see
:mod:`imix_cli.checkpoints`) and deleted once the seed's CSV exists -- but for the final state,
from which a larger ``generations=`` continues the seed. A checkpoint that is damaged, of
another seed or config, or a pickle of an older imix is refused with one warning line naming
the file and why, and its seed restarts from scratch.
"""

from __future__ import annotations

from pathlib import Path

from imix_cli.checkpoints import load_or_warn, write_checkpoint
from imix_cli.messages import warn as _warn
from imix_cli.results import partial_csv_path


def checkpoint_path(run_dir: Path, seed: int) -> Path:
    return Path(run_dir) / ".checkpoints" / f"seed_{seed}.npz"


def legacy_checkpoint_path(run_dir: Path, seed: int) -> Path:
    """Where imix 0.1 kept a pickled checkpoint: never opened (unpickling runs code), only removed."""
    return Path(run_dir) / ".checkpoints" / f"seed_{seed}.pkl"


def save_checkpoint(run_dir: Path, st, identity: dict) -> None:
    write_checkpoint(checkpoint_path(run_dir, st.seed), st, identity=identity, seed=st.seed, generation=st.generation)


def load_checkpoint(run_dir: Path, seed: int, identity: dict, fresh, warn=None):
    """The saved state of ``seed`` (built on ``fresh``, a new state of the same run and seed), or None.

    None if there is no checkpoint, or -- after one warning line naming the file and why --
    if it is damaged, of another seed or config, or a pickle of an older imix.
    """
    legacy = legacy_checkpoint_path(run_dir, seed)
    if legacy.exists():
        (warn or _warn)(f"{legacy}: checkpoint ignored: a pickle (older imix), never opened since loading it could run code; seed {seed} restarts from scratch")
    st = load_or_warn(checkpoint_path(run_dir, seed), fresh, identity=identity, seed=seed, warn=warn)
    if st is not None and (st.seed != seed or st.generation != len(st.rows)):
        (warn or _warn)(f"{checkpoint_path(run_dir, seed)}: checkpoint ignored: inconsistent state; seed {seed} restarts from scratch")
        return None
    return st


def can_checkpoint(es) -> bool:
    """Whether ``es`` has a state dict; if not, say once that its seeds will not be checkpointed."""
    try:
        es.state_dict()
    except NotImplementedError:
        _warn(f"algo={es.name} cannot be checkpointed yet: a killed run restarts its unfinished seeds")
        return False
    return True


def remove_checkpoints(run_dir: Path, seed: int, keep_final: bool = False) -> None:
    """A finished seed's checkpoints (and its live-view partial CSV) are no longer needed -- but for
    its final state (``keep_final``), from which a larger ``generations=`` continues the seed."""
    if not keep_final:
        checkpoint_path(run_dir, seed).unlink(missing_ok=True)
    legacy_checkpoint_path(run_dir, seed).unlink(missing_ok=True)
    partial_csv_path(run_dir, seed).unlink(missing_ok=True)
