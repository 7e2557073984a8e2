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

Nothing here changes a result: the groups run the kernels on throw-away inputs of the run's
own types, with their own random numbers, and write no file but numba's cache.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import numpy as np

__all__ = ["compile_groups", "warm_up"]


def _mixing_group(spec) -> None:
    """A few generations of the run's ES with the run's mixing, on made-up returns: compiles the ES
    update and the mixing step (the run's variant), with the run's dimension and population."""
    from imix_cli.generation import Archive, finish_generation, plan_generation
    from imix_cli.lockstep import mixing_settings, new_seed_state

    st = new_seed_state(spec, 0, _num_params(spec))
    settings = mixing_settings(spec)
    archive = Archive()
    rng = np.random.default_rng(0)
    for _ in range(settings.depth + 1):
        plan = plan_generation(st.es, archive, settings, st.sample_rng)
        finish_generation(st.es, archive, settings, plan, rng.normal(size=plan.evaluate.size))


def _episodes_group(spec) -> None:
    """One episode of one member through the run's evaluator: compiles its episode kernel."""
    from imix_cli.parallel_evaluation import build_evaluator

    evaluator = build_evaluator(spec)
    evaluator.evaluate(np.zeros((1, evaluator.num_params)), np.zeros(1, dtype=np.int64))


def _num_params(spec) -> int:
    from imix_cli.parallel_evaluation import build_evaluator

    return build_evaluator(spec).num_params


def compile_groups(spec) -> list:
    """The groups of kernels (functions of ``spec``) whose compile the run can spread over cores, and
    the compiled entry points whose presence in the cache says a group is already compiled."""
    from imix_cli import linalg_kernels, mixing_kernels

    groups = []
    entries = [linalg_kernels._vec_mat] if spec.algo != "cmaes" else [linalg_kernels._eigh, linalg_kernels._cholesky]
    if spec.variant is not None and spec.algo != "cmaes" and spec.variant in mixing_kernels._ENTRY:
        entries.append(mixing_kernels._ENTRY[spec.variant])
    groups.append((_mixing_group, entries))
    if spec.evaluator == "local":
        from imix_cli.envs import kernels
        from imix_cli.evaluation import AcrobotEvaluator, CartPoleEvaluator, ContinuousCartPoleEvaluator
        from imix_cli.parallel_evaluation import build_evaluator

        evaluator = build_evaluator(spec)
        if isinstance(evaluator, (CartPoleEvaluator, ContinuousCartPoleEvaluator)):
            groups.append((_episodes_group, [kernels.cartpole_episodes]))
        elif isinstance(evaluator, AcrobotEvaluator):
            groups.append((_episodes_group, [kernels.acrobot_episodes]))
    return groups


def _cached(dispatcher) -> bool:
    """Whether numba's on-disk cache holds an overload of ``dispatcher`` valid for its current source
    (numba's internal index; True when it cannot tell, so that nothing is started on a doubt)."""
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # numba internals: any change means "cannot tell"
        return True


def warm_up(spec, workers: int) -> int:
    """Compile the run's kernel groups in parallel processes if the cache lacks them and the run has
    ``workers`` >= 2 processes; return the number of groups compiled (0: nothing to do)."""
    if workers < 2:
        return 0  # one process compiles each kernel once anyway, and nothing runs beside it
    try:
        todo = [group for group, entries in compile_groups(spec) if not all(_cached(e) for e in entries)]
    except Exception:  # a warm-up is an optimisation: never a reason for a run to fail
        return 0
    if len(todo) < 2:
        return 0  # a single group would compile serially, as the first worker does
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=ctx) as pool:
        for future in [pool.submit(group, spec) for group in todo]:
            future.result()
    return len(todo)
