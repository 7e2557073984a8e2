"""One-line messages on stderr, the same shape everywhere (``imix: warning: ...``), and the one-line error of a run.

Both live below every layer that raises or prints them (the run folder, the seeds of each trainer, the commands).
"""

from __future__ import annotations

import sys


class RunError(RuntimeError):
    """A run cannot proceed (existing results conflict, unwritable folder...); one-line message."""


def warn(message: str) -> None:
    print(f"imix: warning: {message}", file=sys.stderr, flush=True)


class MissingExtraError(RunError):
    """What the command needs is an optional extra that is not installed (one line naming how to install it).

    Exit status :data:`EXIT_MISSING_EXTRA` for every extra, as for a bad command line."""


#: The exit status of a command refused because an optional extra is not installed, whichever extra (mujoco, ddpg,
#: tensorboard, ray...): 2, as for a bad command line (the command cannot run as given; nothing was written).
EXIT_MISSING_EXTRA = 2

#: The extras `make install-all` installs (pyproject's ``all``): for them that make target is the other way in.
INSTALL_ALL_EXTRAS = ("test", "render", "ddpg", "cluster", "mujoco", "tensorboard", "docs")


def install_extra(extra: str, first: str = "") -> str:
    """How to install imix's optional ``extra``, in the words every message uses.

    imix-cli is not on the package index: imix is installed from a clone of its repository, so the extra is named by
    the clone's path (``pip install ".[mujoco]"`` run there, in the venv imix runs in), or ``make install-all``
    where it installs that extra. ``first``: a requirement to install in the same command before it (DDPG's CPU torch).
    """
    also = " (or make install-all)" if extra in INSTALL_ALL_EXTRAS else ""
    return f'pip install {first + " " if first else ""}".[{extra}]" from the imix clone{also}'
