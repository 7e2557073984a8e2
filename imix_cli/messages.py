"""One-line messages on stderr, the same shape everywhere (``imix: warning: ...``), and the one-line error of a run.

Both live below every layer that raises or prints them (the run folder, the seeds of each trainer, the commands).
"""

from __future__ import annotations

import sys


class RunError(RuntimeError):
    """A run cannot proceed (existing results conflict, unwritable folder...); one-line message."""


def warn(message: str) -> None:
    print(f"imix: warning: {message}", file=sys.stderr, flush=True)
