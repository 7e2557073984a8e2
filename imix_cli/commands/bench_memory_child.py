"""``python -m imix_cli.commands.bench_memory_child <imix run arguments>``: the measured process of ``imix bench memory``.

Runs ``imix run`` in this process while a thread polls the peak RSS (VmHWM) of every descendant
(the worker processes), then prints one line ``IMIX_BENCH {json}``: exit code, peak RSS of this
process and of its workers (KB), CPU seconds of this process and of its finished workers.
"""

from __future__ import annotations

import json
import os
import resource
import sys
import threading


def hwm_kb(pid: int) -> int:
    """Peak resident set size of a live process (its own address space), in KB; 0 if unknown."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
    except (OSError, StopIteration, ValueError):
        return 0


def descendants(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            kids = [int(k) for k in f.read().split()]
    except OSError:
        return []
    return kids + [d for k in kids for d in descendants(k)]


def is_fork_server(pid: int) -> bool:
    """Whether ``pid`` is the seed workers' fork server (:func:`imix_cli.core.processes.start_seed_worker_server`), a child
    of this process that only imports and forks: not a worker (the workers forked from it are its children)."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            forkserver = b"multiprocessing.forkserver" in f.read()
        with open(f"/proc/{pid}/stat") as f:
            return forkserver and int(f.read().rsplit(")", 1)[1].split()[1]) == os.getpid()
    except (OSError, IndexError, ValueError):
        return False


def main(args: list[str]) -> int:
    peaks, done = {}, threading.Event()

    def poll():  # ru_maxrss would count the RSS a process inherits at fork; VmHWM does not
        while not done.is_set():
            for pid in descendants(os.getpid()):
                if not is_fork_server(pid):
                    peaks[pid] = max(peaks.get(pid, 0), hwm_kb(pid))
            done.wait(0.05)

    threading.Thread(target=poll, daemon=True).start()
    from imix_cli.commands.cli import main as imix_main

    code = imix_main(["run", *args])
    done.set()
    from imix_cli.running.pool import forked_workers_cpu_seconds

    me, workers = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    worker_peaks = [kb for kb in peaks.values() if kb > 0]
    print("IMIX_BENCH " + json.dumps({
        "code": code, "main_kb": hwm_kb(os.getpid()), "worker_kb": max(worker_peaks, default=0),
        "workers_total_kb": sum(worker_peaks), "processes": len(worker_peaks),
        "main_cpu": me.ru_utime + me.ru_stime, "worker_cpu": workers.ru_utime + workers.ru_stime + forked_workers_cpu_seconds(),
    }))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
