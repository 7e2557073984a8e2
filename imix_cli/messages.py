"""One-line messages on stderr, the same shape everywhere (``imix: warning: ...``), and the one-line error of a run.

Both live below every layer that raises or prints them (the run folder, the seeds of each trainer, the commands).
"""

from __future__ import annotations

import reprlib
import sys

#: The most characters of a value a message shows (:func:`shown_value`).
SHOWN_MAX = 200


class RunError(RuntimeError):
    """A run cannot proceed (existing results conflict, unwritable folder...); one-line message."""


def warn(message: str) -> None:
    print(bounded_line(f"imix: warning: {message}"), file=sys.stderr, flush=True)


class MissingExtraError(RunError):
    """What the command needs is an optional extra that is not installed (one line naming how to install it).

    Exit status :data:`EXIT_MISSING_EXTRA` for every extra, as for a bad command line."""


#: The exit status of a command refused because an optional extra is not installed, whichever extra (mujoco, ddpg,
#: tensorboard, ray...): 2, as for a bad command line (the command cannot run as given; nothing was written).
EXIT_MISSING_EXTRA = 2

#: The extras `make install-all` installs (pyproject's ``all``): for them that make target is the other way in.
INSTALL_ALL_EXTRAS = ("test", "render", "ddpg", "cluster", "mujoco", "tensorboard", "docs", "bbob", "search")


def install_extra(extra: str, first: str = "") -> str:
    """How to install imix's optional ``extra``, in the words every message uses.

    imix-cli is not on the package index: imix is installed from a clone of its repository, so the extra is named by
    the clone's path (``pip install ".[mujoco]"`` run there, in the venv imix runs in), or ``make install-all``
    where it installs that extra. ``first``: a requirement to install in the same command before it (DDPG's CPU torch).
    """
    also = " (or make install-all)" if extra in INSTALL_ALL_EXTRAS else ""
    return f'pip install {first + " " if first else ""}".[{extra}]" from the imix clone{also}'


def shown_value(value, limit: int = SHOWN_MAX) -> str:
    """``repr(value)`` as a one-line message shows a value read from a file or given by a user: at most ``limit``
    characters (then ``...``), built level by level with :mod:`reprlib` so that a huge or deeply nested value is never
    expanded whole. A message names the file or key; the value only has to be recognisable."""
    shortener = reprlib.Repr()
    shortener.maxlevel, shortener.maxstring, shortener.maxother, shortener.maxlong = 4, limit, limit, limit
    shortener.maxlist = shortener.maxtuple = shortener.maxdict = shortener.maxset = shortener.maxfrozenset = 8
    text = shortener.repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


#: The longest line an error or warning prints (:func:`bounded_line`).
LINE_MAX = 1000


def bounded_line(text: str, limit: int = LINE_MAX) -> str:
    """``text`` cut to at most ``limit`` characters by dropping its middle: the head (the command, the file or key named)
    and the tail (what to do) are kept. The last guard of every one-line message, whatever a value in it held."""
    if len(text) <= limit:
        return text
    tail = limit // 4
    return f"{text[: limit - tail - 5]} ... {text[-tail:]}"
