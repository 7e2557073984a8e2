"""A run's first compile, spread over the cores before its workers start.

Why: imix's compiled kernels (numba, ``cache=True``) are compiled on first use and then loaded
from numba's on-disk cache by every later process. On a user's first run the cache is empty,
so every worker process compiled the same kernels at once: the mixing step (the biggest: about
two thirds of the compile), the episodes and the ES's linear algebra, one after the other in
each worker. Here the run's kernels are split into groups -- mixing (with the ES update that
builds its archive) and episodes -- that are compiled at the same time in separate processes,
each writing its share to the cache; the workers then only load them. The first run's extra
time is then the slowest group's compile rather than the sum of all of them.

When the cache already holds the run's entry points (every run after the first), nothing is
started: the check reads numba's cache index, and when it cannot tell (numba's internals
moved), it assumes the cache is warm, i.e. the workers compile as they go, as before.
The check itself builds the run's ES, whose set-up runs the package's first kernel in the main process:
numba's compiler target loaded for that alone, ~0.35 s before the workers could start (7 % of the
main job's whole process). So once a config's kernels were found in (or written to) the package's shared
cache folder, a stamp file there says so (:func:`_stamp`), and later runs of that config skip the check.
The folder is one content of the package's compiled sources (:mod:`imix_cli.core.numerics.numba_cache`): an
edit starts a new folder without stamps; the stamp names numba's version too. A stamp that is wrong
(cache files deleted by hand) costs what a missing warm-up costs -- the workers compile -- never a number.

Nothing here changes a result: the groups run the kernels on throw-away inputs of the run's
own types, with their own random numbers, and write no file but numba's cache.

``python -m imix_cli.running.warmup`` (``make install`` runs it) compiles, the same way, the kernels of
every built-in environment, mixing variant and ES, so that even a user's first run loads them.
A kernel's machine code depends on its argument types only (not on dimensions or population
sizes), so a few configurations cover all runs on the built-in environments.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from imix_cli.core.processes import spawn_context

__all__ = ["compile_groups", "warm_up", "warm_all"]

#: Configurations whose kernels together are every compiled kernel of a run on a built-in
#: environment: each mixing variant's step, both episode kernels (continuous CartPole shares
#: CartPole's), each compiled ES update with its compiled loop (one entry per ES) and CMA-ES's linear algebra.
INSTALL_CONFIGS = [
    ["algo=snes", "env=cartpole", "eim=true"],
    ["algo=openes", "env=cartpole", "eim=true"],
    ["algo=snes", "env=acrobot", "im=true"],
    ["algo=snes", "env=cartpole", "im=true", "im_variant=sun2009"],
    ["algo=cem", "env=cartpole", "eim=true"],
    ["algo=cmaes", "env=cartpole", "eim=true"],
    ["algo=ars", "env=cartpole", "eim=true"],
]


def _mixing_group(spec) -> None:
    """A few generations of the run's ES with the run's mixing, on made-up returns: compiles the ES
    update and the mixing step (the run's variant), with the run's dimension and population."""
    from imix_cli.core.evaluation.parallel import build_evaluator
    from imix_cli.core.mixing.generation import Archive, finish_generation, plan_generation
    from imix_cli.running.loop.lockstep import loop_settings, new_seed_state

    settings = loop_settings(spec, build_evaluator(spec))
    st = new_seed_state(settings, 0)
    archive = Archive()
    rng = np.random.default_rng(0)
    for _ in range(settings.mixing.depth + 1):
        plan = plan_generation(st.es, archive, settings.mixing, st.sample_rng)
        finish_generation(st.es, archive, settings.mixing, plan, rng.normal(size=len(plan.points)))


def _policy_group(spec) -> None:
    """The elementary functions (imix_cli.core.numerics.elementary) of the gymnasium policies, of the numpy mixing path
    (CMA-ES) and of the ES's Python side (CMA-ES's constants, Adam's bias correction)."""
    from imix_cli.core import numerics as xp

    xp.tanh(np.zeros((2, 2)))
    xp.expm1(np.zeros(2))
    xp.exp(0.5), xp.log(0.5), xp.log1p(0.5), xp.power(0.5, 0.5)


def _episodes_group(spec) -> None:
    """One episode of one member through the run's evaluator: compiles its episode kernel."""
    from imix_cli.core.evaluation.parallel import build_evaluator

    evaluator = build_evaluator(spec)
    evaluator.evaluate(np.zeros((1, evaluator.num_params)), np.zeros(1, dtype=np.int64))


def _compiled_loop_group(spec) -> None:
    """One generation of one seed through the compiled loop (:mod:`imix_cli.running.loop.compiled_loop`): compiles
    its entry point, which holds its own copy of the mixing, episode and update kernels."""
    from imix_cli.core.evaluation.parallel import build_evaluator
    from imix_cli.running.loop import compiled_loop
    from imix_cli.running.loop.lockstep import loop_settings, new_seed_state

    evaluator = build_evaluator(spec)
    settings = loop_settings(spec, evaluator)
    compiled_loop.advance(new_seed_state(settings, 0), settings, evaluator, 1)


def compile_groups(spec) -> list:
    """The groups of kernels (functions of ``spec``) whose compile the run can spread over cores, and
    the compiled entry points whose presence in the cache says a group is already compiled."""
    from imix_cli.core.algorithms import make_es
    from imix_cli.core.mixing import kernels as mixing_kernels
    from imix_cli.core.mixing import variant_spec
    from imix_cli.core.numerics import linalg_kernels

    groups = []
    es = make_es(spec.algo, 1)
    step = es.compiled_step()  # the ES's compiled update, which its tell runs (imix_cli.core.algorithms.base.CompiledStep)
    if step is not None:
        entries = [step.update]
    else:
        entries = [linalg_kernels.vec_mat_kernel] if spec.algo != "cmaes" else [linalg_kernels.eigh_kernel, linalg_kernels.cholesky_kernel]
    kernel = variant_spec(spec.variant).kernel if spec.variant is not None else 0
    if kernel and spec.algo != "cmaes":
        entries.append(mixing_kernels.KERNELS[kernel])
    groups.append((_mixing_group, entries))
    if spec.evaluator == "local":
        from imix_cli.core.envs import kernels
        from imix_cli.core.evaluation import AcrobotEvaluator, CartPoleEvaluator, ContinuousCartPoleEvaluator
        from imix_cli.core.evaluation.parallel import build_evaluator

        evaluator = build_evaluator(spec)
        if isinstance(evaluator, (CartPoleEvaluator, ContinuousCartPoleEvaluator)):
            groups.append((_episodes_group, [kernels.cartpole_episodes]))
        elif isinstance(evaluator, AcrobotEvaluator):
            groups.append((_episodes_group, [kernels.acrobot_seeded_episodes]))
        from imix_cli.core.mixing import compiled_generation
        from imix_cli.running.loop import compiled_loop
        from imix_cli.running.loop.lockstep import loop_settings

        if compiled_loop.applies_to_run(loop_settings(spec, evaluator), evaluator):  # one entry per ES, every built-in env
            groups.append((_compiled_loop_group, [compiled_generation.entry_for(es)]))
    return groups


def _cached(dispatcher) -> bool:
    """Whether numba's on-disk cache holds an overload of ``dispatcher`` valid for its current source
    (numba's internal index; True when it cannot tell, so that nothing is started on a doubt)."""
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # numba internals: any change means "cannot tell"
        return True


def _stamp(spec) -> Path | None:
    """The file whose presence says that ``spec``'s kernel groups are in the package's shared numba cache (module
    docstring); None when the cache is numba's own folder (``NUMBA_CACHE_DIR``, a read-only environment): no stamps."""
    import numba

    from imix_cli.core.numerics import numba_cache

    root = numba_cache._SHARED[0] if numba_cache._SHARED else None
    if root is None:
        return None
    key = json.dumps([numba.__version__, spec.algo, spec.variant, spec.evaluator, spec.identity()], sort_keys=True, default=repr)
    return root / "warm-runs" / hashlib.sha256(key.encode()).hexdigest()[:32]


def _stamp_now(stamp: Path | None) -> None:
    if stamp is not None:
        try:
            stamp.parent.mkdir(parents=True, exist_ok=True)
            stamp.touch()
        except OSError:  # a stamp is an optimisation: the next run checks again
            pass


def warm_up(spec, workers: int) -> int:
    """Compile the run's kernel groups in parallel processes if the cache lacks them and the run has
    ``workers`` >= 2 processes; return the number of groups compiled (0: nothing to do)."""
    if workers < 2:
        return 0  # one process compiles each kernel once anyway, and nothing runs beside it
    try:
        stamp = _stamp(spec)
        if stamp is not None and stamp.is_file():
            return 0  # found (or written) before: the check would build the ES for nothing (module docstring)
        todo = [group for group, entries in compile_groups(spec) if not all(_cached(e) for e in entries)]
    except Exception:  # a warm-up is an optimisation: never a reason for a run to fail
        return 0
    if not todo:
        _stamp_now(stamp)
    if len(todo) < 2:
        return 0  # a single group would compile serially, as the first worker does
    _run_groups([(group, spec) for group in todo], workers)
    _stamp_now(stamp)
    return len(todo)


def _run_groups(jobs, workers: int) -> None:
    """``group(spec)`` for each job, in up to ``workers`` spawn processes; on Ctrl-C or an error the
    processes are stopped at once (a compile can take tens of seconds) and the exception re-raised."""
    from imix_cli.running.pool import _terminate_workers

    pool = ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=spawn_context())
    try:
        for future in [pool.submit(group, spec) for group, spec in jobs]:
            future.result()
    except BaseException:
        _terminate_workers(pool)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def warm_all(workers: int | None = None) -> int:
    """Compile every kernel of :data:`INSTALL_CONFIGS` not yet in numba's cache, over ``workers``
    processes (default: all cores); return the number of groups compiled."""
    from imix_cli.core.numerics import elementary, linalg_kernels
    from imix_cli.running.config.compose import validate_overrides

    policy_entries = [linalg_kernels.tanh_kernel, elementary.math_exp, elementary.math_log, elementary.math_log1p, elementary.math_pow]
    jobs, seen = [(_policy_group, None)] if not all(_cached(e) for e in policy_entries) else [], set()
    for overrides in INSTALL_CONFIGS:
        (spec,) = validate_overrides(overrides)
        for group, entries in compile_groups(spec):
            key = (group.__name__, tuple(id(e) for e in entries))
            if key not in seen and not all(_cached(e) for e in entries):
                seen.add(key)
                jobs.append((group, spec))
    if jobs:
        _run_groups(jobs, workers or os.cpu_count() or 1)
    return len(jobs)


if __name__ == "__main__":
    # Through the module's own name: the compile groups are pickled to spawned processes by reference, and the
    # processes imix starts never import the parent's __main__ (imix_cli.core.processes.spawn_context), where they
    # would otherwise be looked up (`make install` failed: "Can't pickle <function _mixing_group>").
    from imix_cli.running import warmup as _warmup

    started = time.perf_counter()
    compiled = _warmup.warm_all()
    print(f"imix: {compiled} group(s) of compiled kernels written to numba's cache in {time.perf_counter() - started:.0f} s", file=sys.stderr)
