"""One-line messages on stderr, the same shape everywhere: ``imix: warning: ...``."""

from __future__ import annotations

import sys


def warn(message: str) -> None:
    print(f"imix: warning: {message}", file=sys.stderr, flush=True)
