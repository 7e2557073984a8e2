"""What every benchmark shares: repeated timings, markdown tables, the rollouts' baseline envs."""

from __future__ import annotations

import resource
import time

import numpy as np

from imix_cli.core.registry import ENV_SPECS, MAIN_GRID_ENVS

# Gymnasium ids of the baselines: the -v1 ids of the registry's envs (same physics as the -v0 the
# registry names for CartPole, without its deprecation warning), capped at the registry's episode length.
ROLLOUT_ENVS = {name: ENV_SPECS[name].gym_id.replace("-v0", "-v1") for name in MAIN_GRID_ENVS}
EPISODE_CAP = ENV_SPECS[MAIN_GRID_ENVS[0]].max_steps
assert all(ENV_SPECS[name].max_steps == EPISODE_CAP for name in MAIN_GRID_ENVS)


def median_rate(fn, args: tuple, min_repeats: int = 1, min_seconds: float = 0.0) -> tuple[float, object]:
    """Median of ``units / seconds`` over repeats of ``fn(*args) -> (units, result)``; at least
    ``min_repeats`` repeats and ``min_seconds`` in total."""
    rates, started, result = [], time.perf_counter(), None
    while len(rates) < min_repeats or time.perf_counter() - started < min_seconds:
        t = time.perf_counter()
        units, result = fn(*args)
        rates.append(units / max(time.perf_counter() - t, 1e-12))
    return float(np.median(rates)), result


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def table(header: list[str], rows: list[list], align: str) -> str:
    """A markdown table; ``align`` has one of 'l'/'r' per column."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" if a == "l" else "---:" for a in align) + "|"]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def si(x: float) -> str:
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if abs(x) >= scale:
            return f"{x / scale:.2f}{unit}"
    return f"{x:.0f}"


def cpu_seconds() -> float:
    """User + system CPU seconds of this process and of its finished workers: its children, and the seed workers it had
    forked from the fork server (:func:`imix_cli.running.pool.forked_workers_cpu_seconds`)."""
    from imix_cli.running.pool import forked_workers_cpu_seconds

    me, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + children.ru_utime + children.ru_stime + forked_workers_cpu_seconds()
