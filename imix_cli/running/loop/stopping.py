"""Stopping a run between generations: a Ctrl-C or SIGTERM keeps every seed's current generation.

Why: a signal raised as an exception wherever it lands can land in the middle of a generation (an ES
updated, its archive not yet), so all a stopped run could keep was its last periodic checkpoint --
measured: interrupted at ~372 generations a seed, the re-run resumed at 200. Instead, while the
evolution strategies' loop runs (:func:`stops_between_generations`), SIGINT and SIGTERM only set a flag
(:func:`requested`); the loop reads it between steps, where every seed's state is whole, checkpoints
each seed at its current generation and raises :class:`StopRequested`; once the loop has unwound
(files closed, evaluator stopped), the signal goes on to the handler that was there before: the
``imix`` command's (one line, exit 130 or 143), a notebook's KeyboardInterrupt, or the default action
(a worker process ends by its SIGTERM).

How long: the current step ends first -- one generation, or one seed's compiled chunk of at most
:data:`imix_cli.running.loop.es_seeds.CHUNK` generations (the numba call cannot be cut; on the main job a chunk
takes about a fifth of a second; a first run's compilation of the kernels, minutes) -- then one
checkpoint per seed. At most :data:`STOP_GRACE_SECONDS` all told: with worker processes the main process
then kills those still busy; in-process the signal then acts as if it came again. A second Ctrl-C acts at
once. Either way, what was not saved keeps its last periodic checkpoint, as a kill does.
"""

from __future__ import annotations

import contextlib
import signal
import threading

__all__ = ["StopRequested", "requested", "stops_between_generations", "worker_waits_for_its_main"]

_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: The longest a Ctrl-C or SIGTERM waits for the seeds to reach the end of their step and be checkpointed.
STOP_GRACE_SECONDS = 20.0
#: The signal that asked the running loop to stop (None: none did).
_requested: int | None = None
#: In a worker process of the seed pool: a repeated signal is not the user's second Ctrl-C but the main
#: process's own SIGTERM following one to the whole group; the main process bounds the wait itself.
_patient = False


class StopRequested(BaseException):  # noqa: N818 - not an error: the run's answer to a signal
    """Raised by the loop once every seed's current generation is checkpointed (``signum``: the signal).

    A BaseException, as KeyboardInterrupt is, so that no ``except Exception`` on the way swallows it."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def requested() -> int | None:
    """The signal (SIGINT or SIGTERM) that asked the loop to stop, or None."""
    return _requested


def worker_waits_for_its_main() -> None:
    """Called in a seed-pool worker: a repeated signal does not cut its checkpoints short (see ``_patient``)."""
    global _patient
    _patient = True


@contextlib.contextmanager
def stops_between_generations():
    """For the ``with`` block: SIGINT and SIGTERM (those this process does not ignore) set :func:`requested`
    instead of acting; the block's :class:`StopRequested` then hands the signal to the handler that was there
    before (KeyboardInterrupt if that one returns). Off the main thread, where no handler can be set, nothing changes."""
    global _requested
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {signum: signal.getsignal(signum) for signum in _STOP_SIGNALS}
    taken = [signum for signum, handler in previous.items() if handler not in (signal.SIG_IGN, None)]

    def restore() -> None:
        for signum in taken:
            signal.signal(signum, previous[signum])

    def on_signal(signum, frame) -> None:
        global _requested
        if _requested is None or _patient:
            if _requested is None and not _patient:  # in-process: nobody else bounds the wait
                timer.start()
            _requested = _requested or signum
            return
        restore()  # a second Ctrl-C (or the grace period over): the user will not wait for the current step
        _deliver(signum, previous[signum], frame)

    # Sent again, from a timer thread to the main thread (a wait in a system call ends), its handler runs as soon as
    # the main thread is back in Python: in a compilation, at once; in a compiled call, when that returns.
    main = threading.main_thread().ident
    timer = threading.Timer(STOP_GRACE_SECONDS, lambda: signal.pthread_kill(main, _requested) if _requested else None)
    timer.daemon = True
    _requested = None
    for signum in taken:
        signal.signal(signum, on_signal)
    try:
        yield
    except StopRequested as stop:
        restore()
        _deliver(stop.signum, previous[stop.signum], None)
        raise KeyboardInterrupt from None  # the previous handler returned: the run stops all the same
    except BaseException:
        signum = _requested
        if signum is not None:  # the step failed while a stop was pending (evaluator=pool's workers died of the
            restore()  # same SIGTERM to the group): the signal is what the user sent, and what is answered
            _deliver(signum, previous[signum], None)
        raise
    finally:
        timer.cancel()
        restore()
        _requested = None


def _deliver(signum: int, handler, frame) -> None:
    """What ``signum`` would have done under ``handler``: call it, or its default action (the process ends)."""
    if callable(handler):
        handler(signum, frame)
    elif handler == signal.SIG_DFL:
        signal.signal(signum, signal.SIG_DFL)
        signal.raise_signal(signum)
