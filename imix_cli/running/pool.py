"""The process pool of a run: spawn-safe workers, their progress, Ctrl-C, and the orphan watchdog.

``run_pool(task, spec, chunks, bar)`` runs ``task(spec, chunk)`` for every chunk of seeds in its
own process and returns their results. Workers report progress through :func:`report_progress`
(a queue drained into ``bar``); they ignore SIGINT (the main process alone decides, and stops
them with SIGTERM, after which each checkpoints its seeds' current generation: at most
:data:`imix_cli.running.loop.stopping.STOP_GRACE_SECONDS`), and exit within a second if the main process dies (kill -9), so that none lingers.
Workers are forked from a server that has imported what they run, or spawned where it cannot serve
(:func:`imix_cli.core.processes.seed_worker_context`), with one BLAS thread each (:func:`imix_cli.core.processes.one_blas_thread`).
"""

from __future__ import annotations

import atexit
import logging
import os
import queue as queue_module
import resource
import signal
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

from imix_cli.core.processes import (
    exit_without_teardown,
    one_blas_thread,
    seed_worker_context,
    start_orphan_watchdog,
    start_seed_worker_server,
    worker_environment,
)
from imix_cli.running.loop import stopping

#: What a run's seed workers import before they are forked from the fork server
#: (:func:`imix_cli.core.processes.seed_worker_context`): the trainer, the loop and the compiled generation, with numpy,
#: numba and gymnasium under them, and numba's CPU target set up (:mod:`imix_cli.running.worker_start`).
SEED_WORKER_MODULES = ["imix_cli.running.runner", "imix_cli.running.loop.es_seeds", "imix_cli.running.loop.compiled_loop", "imix_cli.running.worker_start"]

_progress_queue = None
_forked_cpu = 0.0  # CPU seconds of finished workers forked from the fork server (forked_workers_cpu_seconds)


def start_worker_server() -> None:
    """Start the seed workers' fork server now (:func:`imix_cli.core.processes.start_seed_worker_server`): ``imix run``
    calls it first, so that the server's imports run beside its validation."""
    start_seed_worker_server(SEED_WORKER_MODULES)


def report_progress(n: int) -> None:
    """A worker's progress (no-op outside a pool worker)."""
    if _progress_queue is not None:
        _progress_queue.put(n)


def report_resumed(starts: dict) -> None:
    """A worker's seeds and the generation each starts from (no-op outside a pool worker)."""
    if _progress_queue is not None:
        _progress_queue.put(("resumed", starts))


def run_pool(task, spec, chunks: list[list[int]], bar, when_a_core_is_free=None, resumed=None) -> list:
    """``[task(spec, chunk) for chunk in chunks]``, each in a worker process of its own.

    ``when_a_core_is_free()`` is called once, here, when a worker has finished its chunk while others
    still run: work this process will need next can be done then without slowing a worker.
    ``resumed(starts)`` receives what each worker reports with :func:`report_resumed`."""
    global _forked_cpu
    ctx = seed_worker_context(SEED_WORKER_MODULES)
    forked = ctx.get_start_method() == "forkserver"
    progress_queue = ctx.Queue()
    pool = ProcessPoolExecutor(max_workers=len(chunks), mp_context=ctx, initializer=_init_worker, initargs=(progress_queue, worker_environment(ctx)))
    try:
        with one_blas_thread():  # the workers start at these submits
            futures = [pool.submit(_with_cpu, task, spec, chunk) for chunk in chunks]
        pending = set(futures)
        while pending:
            done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            _drain_into(progress_queue, bar, resumed)
            for future in done:
                future.result()  # re-raise a worker's error here
            if done and pending and when_a_core_is_free is not None:
                when_a_core_is_free()
                when_a_core_is_free = None
        _drain_into(progress_queue, bar, resumed)
        results = [future.result() for future in futures]
        if forked:  # not this process's children: their CPU time never reaches its RUSAGE_CHILDREN
            _forked_cpu += sum(cpu for _, cpu in results)
        return [result for result, _ in results]
    except BaseException:
        # Ctrl-C / SIGINT to this process alone, or a worker's error: stop the other workers now rather than
        # let them finish their seeds; each checkpoints its seeds' current generation first (writes are atomic).
        _terminate_workers(pool, grace=stopping.STOP_GRACE_SECONDS)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def forked_workers_cpu_seconds() -> float:
    """CPU seconds of the finished seed workers this process had forked from the fork server: the children of that
    server, so missing from this process's ``RUSAGE_CHILDREN`` (``imix bench`` adds them)."""
    return _forked_cpu


def _with_cpu(task, spec, chunk):
    """``(task(spec, chunk), this worker's CPU seconds so far)``."""
    result = task(spec, chunk)
    me = resource.getrusage(resource.RUSAGE_SELF)
    return result, me.ru_utime + me.ru_stime


def _init_worker(progress_queue, environ=None) -> None:
    global _progress_queue
    _progress_queue = progress_queue
    if environ is not None:  # forked from the fork server: the caller's variables, not the server's
        os.environ.clear()
        os.environ.update(environ)
    # Ctrl-C reaches the whole process group: the main process alone decides, and stops us.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # SIGTERM (the main process stopping us): the seeds' loop checkpoints their current generation, then the worker
    # ends silently (the main process's one line is enough); outside that loop it ends at once.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    stopping.worker_waits_for_its_main()
    start_orphan_watchdog(os.getppid())
    atexit.register(_exit_without_teardown)  # registered first, so it runs after the tasks' own atexit hooks


def _exit_without_teardown() -> None:
    """End a worker whose work is done without the interpreter's teardown.

    Why: the main process joins its workers before the run returns, and tearing down numba, pandas
    and numpy's modules takes a worker ~0.2 s (more on a busy machine), every run. By the time the
    atexit hooks run, the worker loop has returned its results and flushed its queues, and every
    file the worker wrote was synced when it was written; only the logging handlers (a tracker's)
    and Python's stdio buffers are left to flush."""
    logging.shutdown()
    exit_without_teardown(0)


def _terminate_workers(pool: ProcessPoolExecutor, grace: float = 5.0) -> None:
    """SIGTERM to every worker, then up to ``grace`` seconds in all for them to exit (a run's workers checkpoint
    first: :mod:`imix_cli.running.loop.stopping`); those still alive are killed, at once on a second Ctrl-C."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        process.terminate()
    deadline = time.monotonic() + grace
    try:
        for process in processes:
            process.join(timeout=max(0.0, deadline - time.monotonic()))
    except KeyboardInterrupt:  # a second Ctrl-C: the user will not wait (the last periodic checkpoints are kept)
        pass
    for process in processes:
        if process.is_alive():
            process.kill()
            process.join(timeout=5)


def _drain_into(progress_queue, bar, resumed=None) -> None:
    while True:
        try:
            item = progress_queue.get_nowait()
        except queue_module.Empty:
            return
        if isinstance(item, tuple):  # ("resumed", starts)
            if resumed is not None:
                resumed(item[1])
        else:
            bar.update(item)


class _NoBar:
    def update(self, n=1):
        pass

    def close(self):
        pass


def progress_bar(total: int, desc: str, unit: str, enabled: bool = True):
    """A tqdm bar of ``total`` ``unit``s (``"gen"``, or ``"step"``: SI-scaled), or one that shows nothing."""
    if not enabled or total == 0:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, unit_scale=unit == "step", mininterval=0.5, dynamic_ncols=True)
