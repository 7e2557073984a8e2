"""``imix bench breakdown``: where a run's time goes -- evaluation, mixing (or plain sampling) and
ES update of a lockstep run in this process (the seeds of one worker, paper dimensions).

Nothing is patched: the timed evaluator, the timed planning step (which mixes, or samples
without mixing) and the timed ES updates are handed to :func:`imix_cli.running.loop.lockstep.advance_lockstep`.
"""

from __future__ import annotations

import time

from imix_cli.bench.common import table


def _timed(fn, clock: dict, key: str):
    """``fn`` that adds its wall time to ``clock[key]``."""

    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            clock[key] += time.perf_counter() - t

    return wrapper


class _TimedEvaluator:
    """An evaluator whose ``evaluate`` adds its wall time to ``clock["evaluate"]``; anything else is the wrapped one's."""

    def __init__(self, evaluator, clock: dict):
        self._evaluator, self.evaluate = evaluator, _timed(evaluator.evaluate, clock, "evaluate")

    def __getattr__(self, name):
        return getattr(self._evaluator, name)


def breakdown_rows(configs, seeds: int, generations: int | None) -> list[dict]:
    """Lockstep runs in this process: seconds in evaluation, mixing/sampling and ES update."""
    from imix_cli.core.evaluation import make_evaluator
    from imix_cli.core.mixing.generation import plan_generation
    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.loop.lockstep import advance_lockstep, loop_settings, new_seed_state

    rows = []
    for overrides in configs:
        gens = [] if generations is None else [f"generations={generations}"]
        spec = validate_overrides([*overrides, f"seeds={seeds}", "workers=1", *gens])[0]
        clock = {"evaluate": 0.0, "mix": 0.0, "tell": 0.0}  # mix: the planning step, mixing or plain sampling
        ev = make_evaluator(spec.evaluator_key, spec.env_max_steps)
        settings = loop_settings(spec, ev)
        states = [new_seed_state(settings, s) for s in range(seeds)]
        for st in states:
            st.es.tell = _timed(st.es.tell, clock, "tell")
        timed_ev, timed_plan = _TimedEvaluator(ev, clock), _timed(plan_generation, clock, "mix")
        started = time.perf_counter()
        for _ in range(spec.generations):
            advance_lockstep(states, settings, timed_ev, plan=timed_plan)
        total = time.perf_counter() - started
        rows.append({
            "run": spec.run_name, "seeds": seeds, "generations": spec.generations, "dim": ev.num_params, "total": total,
            **clock, "env_steps": sum(st.env_steps for st in states),
        })  # fmt: skip
    return rows


def format_breakdown(rows: list[dict]) -> str:
    body = []
    for r in rows:
        sampling = r["mix"]
        other = r["total"] - r["evaluate"] - sampling - r["tell"]
        shares = [f"{100 * x / r['total']:.1f}%" for x in (r["evaluate"], sampling, r["tell"], sampling + r["tell"], other)]
        body.append([r["run"], r["seeds"], r["generations"], r["dim"], f"{r['total']:.1f}", *shares])
    header = ["run", "seeds", "generations", "d", "time (s)", "evaluation", "mixing / sampling", "ES update",
              "mixing + update", "other"]  # fmt: skip
    return table(header, body, "lrrrrrrrrr")
