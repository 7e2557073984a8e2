"""``imix bench memory``: wall time, CPU time and peak RSS of a 25-seed ``imix run`` in a subprocess
(:mod:`imix_cli.commands.bench_memory_child`)."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time

from imix_cli.bench.common import table


def memory_row(overrides: list[str], seeds: int, generations: int | None, workers: int | None) -> dict:
    """Run ``imix run <overrides> seeds=<seeds>`` in a subprocess; wall time and peak RSS."""
    with tempfile.TemporaryDirectory(prefix="imix-bench-") as tmp:
        args = [*overrides, f"seeds={seeds}", "progress=false", f"results_dir={tmp}", "experiment=bench"]
        if generations is not None:
            args.append(f"generations={generations}")
        if workers is not None:
            args.append(f"workers={workers}")
        started = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "imix_cli.commands.bench_memory_child", *args], capture_output=True, text=True, check=False)
        wall = time.perf_counter() - started
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("IMIX_BENCH ")), None)
    if proc.returncode != 0 or line is None:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"imix run {' '.join(args)} failed: {tail}")
    info = json.loads(line.split(" ", 1)[1])
    if info["code"] != 0:
        raise RuntimeError(f"imix run {' '.join(args)} exited with {info['code']}")
    return {
        "command": "imix run " + " ".join(a for a in args if not a.startswith(("results_dir=", "experiment="))),
        "wall": wall, "main_mb": info["main_kb"] / 1024, "worker_mb": info["worker_kb"] / 1024,
        "total_mb": (info["main_kb"] + info["workers_total_kb"]) / 1024, "processes": 1 + info["processes"],
        "main_cpu": info["main_cpu"], "worker_cpu": info["worker_cpu"],
    }  # fmt: skip


def format_memory(row: dict) -> str:
    body = [[f"`{row['command']}`", f"{row['wall']:.1f}", f"{row['main_cpu']:.1f} / {row['worker_cpu']:.1f}",
             f"{row['main_mb']:.0f}", f"{row['worker_mb']:.0f}", f"{row['total_mb']:.0f} ({row['processes']} processes)"]]  # fmt: skip
    header = ["command", "wall (s)", "CPU (s): main / all workers", "main process peak RSS (MB)",
              "largest worker peak RSS (MB)", "sum of peaks (MB)"]  # fmt: skip
    return table(header, body, "lrrrrr")
