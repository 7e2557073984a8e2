"""The one command-line style of ``imix plot | eval | render | status | bench``: ``key=value`` arguments.

(``imix run`` takes Hydra overrides, also ``key=value``, validated by :mod:`imix_cli.running.config.compose`;
``imix bench`` adds its section words, :mod:`imix_cli.bench.cli`.) Each command declares its keys -- a
default and, when the value is not a plain string, a converter that checks it -- and gets a
settings dict back; a bad argument is one :class:`UsageError` naming the key, reported in one line.
"""

from __future__ import annotations

import math
from pathlib import Path


class UsageError(ValueError):
    """Bad command line or missing results; one line, exit status 2 (usage) or 1 (nothing to do)."""

    def __init__(self, message: str, status: int = 2):
        super().__init__(message)
        self.status = status


def help_requested(argv: list, text) -> bool:
    """``-h``, ``--help`` or ``help`` among the arguments: print ``text`` (a string, or a function
    giving it, called only then) and return True."""
    if any(a in ("-h", "--help", "help") for a in argv):
        print(text() if callable(text) else text, end="")
        return True
    return False


def parse_key_values(argv: list, prog: str, defaults: dict, convert: dict | None = None, prefixed: dict | None = None,
                     known: str | None = None) -> dict:  # fmt: skip
    """``key=value`` arguments -> a copy of ``defaults`` with the values given; every key must be in ``defaults``.

    ``convert``: key -> ``f(key, value) -> setting`` (raises UsageError); other keys keep the string.
    ``prefixed``: prefix -> ``f(key, value)`` for keys such as ``threshold.<env>``, which the
    handler stores itself. ``known``: how the unknown-key message lists the keys (default: ``defaults``'s).
    """
    settings = dict(defaults)
    for arg in argv:
        if "=" not in arg:
            raise UsageError(f"expected key=value, got {arg!r} (see imix {prog} --help)")
        key, value = (part.strip() for part in arg.split("=", 1))
        prefix = next((p for p in (prefixed or {}) if key.startswith(p)), None)
        if prefix is not None:
            prefixed[prefix](key, value)
        elif key in defaults:
            settings[key] = convert[key](key, value) if convert and key in convert else value
        else:
            raise UsageError(f"unknown key {key!r} (known: {known or ', '.join(defaults)}; see imix {prog} --help)")
    return settings


# ----------------------------------------------------------------------------- converters
def one_of(*values: str):
    def check(key: str, value: str) -> str:
        if value not in values:
            raise UsageError(f"bad value for {key}: {value!r} (expected {' or '.join(values)})")
        return value

    return check


def flag(key: str, value: str) -> bool:
    """true or false (yes/no, 1/0)."""
    if value.lower() in ("true", "yes", "1"):
        return True
    if value.lower() in ("false", "no", "0"):
        return False
    raise UsageError(f"bad value for {key}: {value!r} (expected true or false)")


def at_least(minimum: int):
    """An integer >= ``minimum``."""

    def check(key: str, value: str) -> int:
        try:
            number = int(value)
        except ValueError:
            raise UsageError(f"bad value for {key}: {value!r} (expected an integer >= {minimum})") from None
        if number < minimum:
            raise UsageError(f"bad value for {key}: {value!r} (expected an integer >= {minimum})")
        return number

    return check


def folder_name(key: str, value: str) -> str:
    """One folder's name (an experiment, a run): no path."""
    if not value or "/" in value or value in (".", ".."):
        raise UsageError(f"bad value for {key}: {value!r} (expected a folder name)")
    return value


def results_dir_value(key: str, value: str) -> str:
    """A results folder's path (any non-empty path)."""
    if not value:
        raise UsageError(f"bad value for {key}: empty path")
    return value


def experiment_name(key: str, value: str) -> str:
    """An experiment's folder below results_dir: a plain name, as ``imix run`` accepts (an absolute path or ".."
    would put figures outside results_dir)."""
    if not value or ".." in Path(value).parts or Path(value).is_absolute() or "\\" in value:
        raise UsageError(f"bad value for {key}: {value!r} (expected a folder name)")
    return value


def finite_number(key: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"bad value for {key}: {text!r} (expected a number)") from None
    if not math.isfinite(value):
        raise UsageError(f"bad value for {key}: {text!r} (expected a finite number)")
    return value
