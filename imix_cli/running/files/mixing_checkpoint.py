"""A :class:`~imix_cli.MixingES` as data: its ES's state, the archive and the mixing stream in one file.

Written as imix's own checkpoints are (:mod:`imix_cli.running.files.checkpoints`: an ``.npz`` of arrays
with a JSON header and a checksum, read back with ``allow_pickle=False``): nothing in it is code.
It holds what changes during a search -- the ES's ``state_dict()`` (an imix ES's, or an adapter's:
evosax's state and key), the archive (generations, their returns, ages and the calibration
pairs), the mixing Generator and the counters; the constructor's arguments are the caller's, so
the file is read back onto a MixingES built with the same arguments (an ES of another kind,
dimension or population is refused).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imix_cli.core.mixing.generation import Archive
from imix_cli.running.files.checkpoints import read_checkpoint, write_checkpoint

__all__ = ["load_mixing", "save_mixing"]


@dataclass
class _MixingState:
    es: object
    archive: Archive
    rng: np.random.Generator
    evaluations: int
    reused: int
    members: int


def _identity(m) -> dict:
    es = m.es
    return {"es": getattr(es, "name", type(es).__name__), "dim": int(es.distribution.dim), "popsize": int(es.popsize),
            "settings": {k: v for k, v in vars(m.settings).items()}}  # fmt: skip


def save_mixing(path, m) -> None:
    """Write MixingES ``m`` (between a ``tell`` and the next ``ask``) to ``path``."""
    if m.plan is not None:
        raise RuntimeError("save_mixing(): a generation was asked and not told; tell it first")
    state = _MixingState(m.es, m.archive, m.rng, m.evaluations, m.reused, m.members)
    write_checkpoint(path, state, identity=_identity(m), seed=0, generation=int(m.es.generation))


def load_mixing(path, m):
    """Load what :func:`save_mixing` wrote onto ``m``, a MixingES built with the same arguments; returns ``m``.
    Raises :class:`~imix_cli.running.files.checkpoints.CheckpointError` for a file of another MixingES or a damaged one."""
    template = _MixingState(m.es, Archive(), np.random.default_rng(), 0, 0, 0)
    state = read_checkpoint(path, template, identity=_identity(m), seed=0)
    m.es, m.archive, m.rng = state.es, state.archive, state.rng
    m.evaluations, m.reused, m.members = state.evaluations, state.reused, state.members
    m.plan = None
    return m
