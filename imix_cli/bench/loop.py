"""``imix bench loop``: the compiled generation loop against the Python loop, in this process.

The same seeds of the same run advance through :func:`imix_cli.running.loop.lockstep.advance_lockstep` (the
reference: one generation of all seeds per call) and through :func:`imix_cli.running.loop.compiled_loop.advance`
(chunks of :data:`imix_cli.running.loop.es_seeds.CHUNK` generations per seed); the table gives each one's time
per seed-generation, their ratio, and whether their rows are the same (wall times aside).
"""

from __future__ import annotations

import time

from imix_cli.bench.common import table

#: The runs measured: the main job, OpenES with EIM, SNES without mixing (every episode run) and ARS with EIM
#: (mirrored pairs: the anchors mixed, the mirrors fresh).
LOOP_CONFIGS = (
    ["algo=snes", "env=cartpole", "eim=true"],
    ["algo=openes", "env=cartpole", "eim=true"],
    ["algo=snes", "env=cartpole", "eim=false"],
    ["algo=ars", "env=cartpole", "eim=true"],
)


def _rows_without_times(states) -> str:
    """The states' rows, wall times aside, as text (repr: floats exactly, and NaN equal to NaN)."""
    return repr([[{k: v for k, v in row.items() if k != "wall_time"} for row in st.rows] for st in states])


def loop_rows(configs, seeds: int, generations: int) -> list[dict]:
    from imix_cli.core.evaluation.parallel import build_evaluator
    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.loop import compiled_loop
    from imix_cli.running.loop.es_seeds import CHUNK
    from imix_cli.running.loop.lockstep import advance_lockstep, loop_settings, new_seed_state

    rows = []
    for overrides in configs:
        (spec,) = validate_overrides(list(overrides))
        evaluator = build_evaluator(spec)
        settings = loop_settings(spec, evaluator)
        warm = new_seed_state(settings, 10_000)
        compiled_loop.advance(warm, settings, evaluator, 2)  # loads (or compiles) the kernels of both loops
        advance_lockstep([warm], settings, evaluator)
        python = [new_seed_state(settings, s) for s in range(seeds)]
        started = time.perf_counter()
        for _ in range(generations):
            advance_lockstep(python, settings, evaluator)
        python_s = time.perf_counter() - started
        compiled = [new_seed_state(settings, s) for s in range(seeds)]
        started = time.perf_counter()
        for st in compiled:
            while st.generation < generations:
                if not compiled_loop.advance(st, settings, evaluator, min(CHUNK, generations - st.generation)):
                    advance_lockstep([st], settings, evaluator)
        compiled_s = time.perf_counter() - started
        per = 1e6 / (seeds * generations)
        rows.append({
            "run": " ".join(o.split("=", 1)[1] for o in overrides), "seeds": seeds, "generations": generations,
            "python_us": python_s * per, "compiled_us": compiled_s * per, "ratio": python_s / compiled_s,
            "same": _rows_without_times(python) == _rows_without_times(compiled),
        })  # fmt: skip
    return rows


def format_loop(rows: list[dict]) -> str:
    header = ["run", "seeds", "generations", "Python loop (µs / seed-generation)", "compiled loop", "× faster", "same rows"]
    body = [
        [r["run"], r["seeds"], r["generations"], f"{r['python_us']:.0f}", f"{r['compiled_us']:.0f}", f"{r['ratio']:.2f}", "yes" if r["same"] else "**NO**"]
        for r in rows
    ]
    return table(header, body, "lrrrrrl")
