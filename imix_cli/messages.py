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
