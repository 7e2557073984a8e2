"""What every worker process of imix shares (the run's seed pool and the evaluation pool).

One BLAS thread per process: imix's matrices are tiny, its seeds already run one process per
core, and two BLAS threads fighting over two cores made CMA-ES's eigendecomposition 10x slower.
That default belongs to imix's own processes only -- the ``imix`` command (set before numpy loads,
:func:`set_one_blas_thread`) and the workers it spawns (:func:`one_blas_thread` around their start,
so a library user's workers get it too) -- and never to a user's Python that imports imix_cli.
A variable the user set is left as it is.
"""

from __future__ import annotations

import multiprocessing.context
import os
import sys
import threading
import time
import types
from contextlib import contextmanager

#: The thread-count variables of OpenBLAS, OpenMP and MKL (numpy reads them when it loads).
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def exit_without_teardown(status: int) -> None:
    """Flush Python's stdio buffers and end the process with ``status``, skipping the modules' teardown (numba, scipy,
    Hydra: ~0.2 s): what a run's worker (:func:`imix_cli.running.pool._exit_without_teardown`) and the ``imix`` command
    (:func:`imix_cli.commands.cli.entry`) do last, each after the hooks it owes."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # a closed or broken stream (imix ... | head): nothing more can be said on it
            pass
    os._exit(status % 256)


def set_one_blas_thread() -> None:
    """In the ``imix`` command's own process, before numpy loads: one BLAS thread unless the user chose."""
    for var in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(var, "1")


@contextmanager
def one_blas_thread():
    """While worker processes are spawned: they inherit one BLAS thread (unless the user chose);
    the calling process's environment is restored afterwards."""
    added = [var for var in BLAS_THREAD_VARIABLES if var not in os.environ]
    for var in added:
        os.environ[var] = "1"
    try:
        yield
    finally:
        for var in added:
            os.environ.pop(var, None)


def spawn_context():
    """The multiprocessing context of every process imix starts: spawn, without re-running the caller's ``__main__``.

    Why: a spawned process normally re-imports the parent's main script (as ``__mp_main__``) before it
    runs its task, so ``imix_cli.run(...)`` at a script's top level -- no ``if __name__ == "__main__":``
    -- ran the whole script again in every worker, each worker's run then finding the folder locked by
    the first. imix's workers need nothing of the caller's script: their task, the RunSpec and the
    env (a gymnasium id, or a module the user named) are imix's or are imported by name. So the
    processes start as a notebook's do, whose main module has no file: the script is never re-run.
    Spawn, not fork: the parent has numba's and the progress bar's threads."""
    return _SpawnContext()


class _SpawnProcess(multiprocessing.context.SpawnProcess):
    """A spawned process told to import no main module (module level: the process object is pickled to the child)."""

    @staticmethod
    def _Popen(process_obj):
        with _main_module_hidden():  # what the child is told to import is decided here, at its start
            return multiprocessing.context.SpawnProcess._Popen(process_obj)


class _SpawnContext(multiprocessing.context.SpawnContext):
    Process = _SpawnProcess


# ------------------------------------------------------------------ the seed workers' fork server
_server_env: dict | None = None  # the fork server's variables read at import (None: not started here)

#: The variables read when numpy, numba, BLAS or Python itself load -- fixed in a forked worker at what the fork server
#: had. Every other variable a worker reads when it runs (``IMIX_COMPILED_LOOP``), and it is given the caller's.
IMPORT_TIME_PREFIXES = ("PYTHON", "NUMBA_", "NPY_", "OPENBLAS", "GOTO", "OMP_", "MKL_", "BLIS_", "LD_", "MALLOC_")
#: Of those, the ones read when used, which a forked worker takes from the caller like any other: ``PYTHONBREAKPOINT``
#: (``breakpoint()`` reads it at each call), which ``ray.init()`` sets in the caller's process -- after which every run
#: of that process spawned its workers.
CALL_TIME_NAMES = frozenset({"PYTHONBREAKPOINT"})


def _import_time_environment() -> dict:
    return {k: v for k, v in os.environ.items() if k.startswith(IMPORT_TIME_PREFIXES) and k not in CALL_TIME_NAMES}


def start_seed_worker_server(preload: list[str]) -> None:
    """Start the fork server of the run's seed workers, if imix has not: it imports the modules ``preload`` names
    (:data:`imix_cli.running.pool.SEED_WORKER_MODULES`) in a process of its own, while the caller goes on (``imix run``
    calls this first, so the import runs beside its validation).

    Why: each seed worker was a spawned Python that imported imix, numpy, numba and gymnasium before its first seed,
    ~0.4 s of the main job's ~4.3 s, and again for every run of a sweep or of ``imix bench grid``. Workers forked from
    a server that has imported them start at once. The server is started with one BLAS thread (:func:`one_blas_thread`),
    as spawned workers are; it ends with this process (multiprocessing's forkserver: its pipe from here closes)."""
    global _server_env
    if _server_env is not None or "forkserver" not in multiprocessing.get_all_start_methods():
        return
    from multiprocessing import forkserver

    with one_blas_thread():
        env = _import_time_environment()
        multiprocessing.get_context("forkserver").set_forkserver_preload(list(preload))
        forkserver.ensure_running()
    _server_env = env


def seed_worker_context(preload: list[str]):
    """The multiprocessing context of a run's seed workers (:mod:`imix_cli.running.pool`): forked from the fork server
    (:func:`start_seed_worker_server` with ``preload``, started here on first use) when the variables read at import
    (:data:`IMPORT_TIME_PREFIXES`) are still those it started with -- a thread count or a numba setting changed since
    must reach the workers, and a fork carries the server's -- else spawned (:func:`spawn_context`). Either way the
    caller's ``__main__`` is never imported again, and a worker's numbers are the same. A forked worker takes the
    caller's other variables when it starts (:func:`worker_environment`)."""
    start_seed_worker_server(preload)
    if _server_env is None:
        return spawn_context()
    with one_blas_thread():  # the variables a spawned worker would get
        now = _import_time_environment()
    return _ForkServerContext() if now == _server_env else spawn_context()


def worker_environment(ctx) -> dict | None:
    """What a worker of ``ctx`` must set as its ``os.environ`` when it starts: the caller's variables of now (with one BLAS
    thread, :func:`one_blas_thread`) for a worker forked from the server, which has the server's; None for a spawned one."""
    if ctx.get_start_method() != "forkserver":
        return None
    with one_blas_thread():
        return dict(os.environ)


class _ForkServerProcess(multiprocessing.context.ForkServerProcess):
    """A process forked from the fork server, told to import no main module (as :class:`_SpawnProcess`)."""

    @staticmethod
    def _Popen(process_obj):
        with _main_module_hidden():
            return multiprocessing.context.ForkServerProcess._Popen(process_obj)


class _ForkServerContext(multiprocessing.context.ForkServerContext):
    Process = _ForkServerProcess


@contextmanager
def _main_module_hidden():
    """While a process is spawned, ``__main__`` is a module with neither ``__file__`` nor ``__spec__``: multiprocessing's
    preparation data then names no main module for the child to import (``multiprocessing.spawn.get_preparation_data``)."""
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        if main is None:
            sys.modules.pop("__main__", None)
        else:
            sys.modules["__main__"] = main


def default_workers() -> int:
    """All cores this process may use (respects CPU affinity, e.g. a Slurm allocation)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def start_orphan_watchdog(parent_pid: int) -> None:
    """A worker whose main process died (kill -9) must not linger, idle on its task queue forever
    or racing a re-run: a daemon thread makes it exit within a second (its checkpoints stay valid)."""
    threading.Thread(target=_exit_when_orphaned, args=(parent_pid,), daemon=True).start()


def _exit_when_orphaned(parent_pid: int) -> None:
    while True:
        time.sleep(1.0)
        if os.getppid() != parent_pid:
            os._exit(1)


# A process of its own (a new session: a terminal's Ctrl-C or a kill of the main's process group
# does not reach it) that keeps the list of the processes under ``roots`` while the main process
# lives, and SIGKILLs those still running once the main process dies (its stdin, a pipe from the
# main, reaches end of file) or says it is done (closes that pipe). A process is recognised by
# its pid and start time, so a pid reused by an unrelated process is never killed. Linux only.
_REAPER = r"""
import os, signal, sys, threading
signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.signal(signal.SIGTERM, signal.SIG_IGN)
roots = {int(a) for a in sys.argv[1:]}
me = os.getpid()

def table():
    procs = {}
    for name in os.listdir("/proc"):
        if name.isdigit():
            try:
                with open(f"/proc/{name}/stat") as fh:
                    fields = fh.read().rsplit(")", 1)[1].split()
                if fields[0] != "Z":
                    procs[int(name)] = (int(fields[1]), fields[19])  # parent pid, start time
            except (OSError, IndexError, ValueError):
                pass
    return procs

def subtree(procs, tops):
    tree = {p for p in tops if p in procs}
    while True:
        more = {p for p, (parent, _) in procs.items() if parent in tree} - tree
        if not more:
            return tree - {me}
        tree |= more

seen = {}
ended = threading.Event()
threading.Thread(target=lambda: (sys.stdin.buffer.read(), ended.set()), daemon=True).start()
while not ended.wait(0.5):
    procs = table()
    seen.update({p: procs[p][1] for p in subtree(procs, roots | set(seen))})
for _ in range(3):  # what they start while being killed is killed in the next pass
    procs = table()
    alive = {p for p, start in seen.items() if p in procs and procs[p][1] == start}
    for p in subtree(procs, alive):
        try:
            os.kill(p, signal.SIGKILL)
        except OSError:
            pass
        seen.setdefault(p, procs[p][1])
"""


def children_of(pid: int) -> set:
    """The pids whose parent is ``pid`` (Linux; an empty set elsewhere)."""
    found = set()
    try:
        names = os.listdir("/proc")
    except OSError:
        return found
    for name in names:
        if name.isdigit():
            try:
                with open(f"/proc/{name}/stat") as fh:
                    if int(fh.read().rsplit(")", 1)[1].split()[1]) == pid:
                        found.add(int(name))
            except (OSError, IndexError, ValueError):
                pass
    return found


def start_reaper(roots: set):
    """Make sure the processes under ``roots`` (and all they start) end with this process, however it
    ends -- kill -9 included: see ``_REAPER``. Returns the reaper (a Popen) for :func:`stop_reaper`,
    or None where /proc is missing."""
    import subprocess
    import sys

    if not roots or not os.path.isdir("/proc/self"):
        return None
    return subprocess.Popen(
        [sys.executable, "-c", _REAPER, *map(str, sorted(roots))],
        stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True, close_fds=True,
    )  # fmt: skip


def stop_reaper(reaper) -> None:
    """This process is done with the processes under the reaper's roots: the reaper kills what is left of them, and exits."""
    if reaper is None:
        return
    try:
        reaper.stdin.close()
        reaper.wait(timeout=10)
    except Exception:  # noqa: BLE001 - a reaper that is already gone has nothing left to do
        pass
