"""The one error boundary of every imix command: what ends a command becomes one line and a documented exit status.

Why: a user who presses Ctrl-C, pipes into ``head``, or runs an env of their own that raises must get one
line saying what happened, never a 40-line traceback (which buries the one line that matters: which env,
what it said). Files are never half-written whatever ends the command: every write goes through
:mod:`imix_cli.running.files.writing` (a temporary file, renamed only when complete).

Exit statuses (docs/reliability.md):

====  ==========================================================================================
0     done
1     failed: a run folder refused, a file that cannot be written, an env of the user's that raised
      (:class:`imix_cli.core.evaluation.UserEnvError`), out of memory (MemoryError), an internal error
2     bad command line (the key or value named), or an optional extra the command needs is not installed
      (whichever extra: mujoco, ddpg, tensorboard, ray...; the line says how to install it from the clone)
130   interrupted (Ctrl-C, SIGINT): 128 + 2, as a shell reports it
141   the reader of the output went away (``imix status | head -1``: EPIPE): 128 + SIGPIPE, what a
      shell reports for any program that SIGPIPE stops, silently; files already written are whole
143   terminated (SIGTERM: ``kill``, a scheduler's time limit): 128 + 15
====  ==========================================================================================

``--debug`` anywhere on the command line, or ``IMIX_DEBUG=1`` in the environment, prints the full
traceback before the line (the env variable reaches worker processes too).

``imix run`` keeps its own handling of Ctrl-C and SIGTERM while seeds run (they checkpoint first:
:mod:`imix_cli.commands.cli`); what its Hydra task does not handle comes here through :func:`report`.
"""

from __future__ import annotations

import os
import signal
import sys
import traceback

from imix_cli.messages import EXIT_MISSING_EXTRA, MissingExtraError, bounded_line

EXIT_FAILED = 1
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141
EXIT_TERMINATED = 143

DEBUG_FLAG = "--debug"
DEBUG_ENV = "IMIX_DEBUG"


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like a Ctrl-C (so ``finally`` blocks and the writer's clean-up run)."""


def _raise_terminated(signum, frame) -> None:
    raise Terminated()


def take_debug_flag(argv: list) -> list:
    """``argv`` without ``--debug``; the flag sets ``IMIX_DEBUG=1`` for this process and its workers."""
    if DEBUG_FLAG in argv:
        os.environ[DEBUG_ENV] = "1"
    return [a for a in argv if a != DEBUG_FLAG]


def debugging() -> bool:
    return os.environ.get(DEBUG_ENV, "").strip().lower() not in ("", "0", "false", "no")


def first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def guard(command: str, body) -> int:
    """Run ``body()`` (returns the exit status) with Ctrl-C and SIGTERM as exceptions; anything that escapes it
    becomes one line on stderr and its exit status (:func:`report`)."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        return body()
    except BaseException as err:  # noqa: BLE001 - the boundary: everything ends here in one line
        if isinstance(err, SystemExit):
            raise
        return report(command, err)


def report(command: str, err: BaseException) -> int:
    """One line on stderr for ``err`` (the full traceback first under ``--debug``); returns the exit status."""
    evaluation = sys.modules.get("imix_cli.core.evaluation")  # not imported: the error cannot be one of its (and gymnasium stays unloaded)
    user_env_error = getattr(evaluation, "UserEnvError", ())
    if isinstance(err, BrokenPipeError):
        return broken_pipe()
    if debugging():
        traceback.print_exception(err)
    hint = "" if debugging() else f" (run with --debug or {DEBUG_ENV}=1 for the traceback)"
    if isinstance(err, Terminated):
        return _say(f"imix {command}: terminated (SIGTERM)", EXIT_TERMINATED)
    if isinstance(err, KeyboardInterrupt):
        return _say(f"imix {command}: interrupted", EXIT_INTERRUPTED)
    if isinstance(err, MissingExtraError):
        return _say(f"imix {command}: error: {err}", EXIT_MISSING_EXTRA)
    if isinstance(err, user_env_error):
        return _say(f"imix {command}: error: {err}{hint}", EXIT_FAILED)
    if isinstance(err, MemoryError):
        return _say(
            f"imix {command}: error: out of memory; files already written are whole (a smaller run, fewer workers=, or frames= for render)", EXIT_FAILED
        )
    if isinstance(err, OSError) and err.filename:
        return _say(f"imix {command}: error: {err.filename}: {err.strerror or first_line(err)}", EXIT_FAILED)
    return _say(f"imix {command}: error: {type(err).__name__}: {first_line(err)}{hint}", EXIT_FAILED)


def _say(line: str, status: int) -> int:
    try:
        print(bounded_line(line), file=sys.stderr, flush=True)
    except OSError:
        pass  # stderr gone too: the status still tells
    return status


def broken_pipe() -> int:
    """The reader of stdout went away: say nothing (no one reads it), and point stdout at /dev/null so that
    Python's final flush does not print "Exception ignored ... BrokenPipeError"."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass
    return EXIT_BROKEN_PIPE
