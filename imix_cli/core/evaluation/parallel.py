"""Evaluating one generation over many cores or a Ray cluster (config key ``evaluator``).

Why: on MuJoCo an episode costs 0.1-1 s instead of microseconds, so a single seed's
generation -- even its few fresh members under importance mixing -- is worth spreading over
every core. The seeds of a run are already spread over processes (``workers``); that is the
right layer when there are at least as many seeds as cores and episodes are cheap. With
expensive episodes, or fewer seeds than cores, the members of a generation are the layer to
parallelise. One layer at a time: ``evaluator=pool`` runs the seeds in one process
(``workers`` defaults to 1 and a larger value is refused, see :mod:`imix_cli.running.config.checks`).

``evaluator`` (config key):

``local`` (default)
    :func:`imix_cli.core.evaluation.make_evaluator` in the run's own process(es), as always.
``pool``
    :class:`PoolEvaluator`: a persistent pool of ``evaluator_workers`` spawned processes
    (default: all cores), each holding its own evaluator (its own env instances). A call's
    members are cut into chunks (up to :attr:`PoolEvaluator.chunks_per_worker` per worker,
    so that short and long episodes balance; one chunk when there is one worker) and gathered back in order.
``ray``
    :class:`RayEvaluator`: the same over Ray actors, one CPU each, on the cluster that
    ``ray.init(address=ray_address)`` joins (``ray_address`` null: a local Ray started for
    the run; ``auto``: the cluster this machine belongs to; ``ray://host:10001``: a remote
    head through Ray Client). ``evaluator_workers`` actors, default: every CPU of the cluster.

Results do not depend on the evaluator nor on the worker count: a member's episode depends
only on its parameters and its episode seed (:mod:`imix_cli.core.evaluation`), chunks are
gathered in member order, and the observation statistics (``last_obs_stats``) are
per-member sums, so whatever adds them up sees the same numbers in the same order
(tests/test_parallel_evaluation.py compares 1 and 2 workers bit for bit).

Every evaluator here has ``evaluate(params, seeds) -> (returns, steps)``, the attributes of
:class:`imix_cli.core.evaluation.BatchEvaluator` (``num_params``, ``obs_dim``, ``out_dim``,
``hidden``...), ``last_obs_stats`` and ``close()``. :func:`build_evaluator` makes the one a
:class:`~imix_cli.running.config.run_spec.RunSpec` asks for.
"""

from __future__ import annotations

import os
import signal
import threading
import weakref
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from imix_cli.core.evaluation import make_evaluator
from imix_cli.core.processes import default_workers, one_blas_thread, spawn_context, start_orphan_watchdog

__all__ = ["PoolEvaluator", "RayEvaluator", "EvaluatorError", "build_evaluator", "EVALUATORS"]


class EvaluatorError(RuntimeError):
    """Evaluation cannot go on (a Ray actor lost for good); ``str(err)`` is one line for the user."""


EVALUATORS = ("local", "pool", "ray")


def build_evaluator(spec):
    """The evaluator of ``spec`` (a :class:`~imix_cli.running.config.run_spec.RunSpec`): local, pool or ray."""
    args, policy = (spec.evaluator_key, spec.env_max_steps), {"hidden": spec.hidden, "output": spec.policy_output}
    if spec.env_kwargs:  # gym.make's constructor arguments (env.kwargs.*)
        policy["env_kwargs"] = dict(spec.env_kwargs)
    if spec.evaluator == "pool":
        return PoolEvaluator(*args, **policy, workers=spec.evaluator_workers)
    if spec.evaluator == "ray":
        return RayEvaluator(*args, **policy, workers=spec.evaluator_workers, address=spec.ray_address)
    return make_evaluator(*args, **policy)


class _Remote:
    """What the pool and Ray evaluators share: a local evaluator for the attributes, chunking, gathering."""

    #: Chunks per worker and call: more than 1 lets workers that drew short episodes take more.
    chunks_per_worker = 4

    def __init__(self, env_key: str, max_steps: int | None, hidden, output: str, env_kwargs=None):
        # make_evaluator's keyword arguments, which every worker process or actor gets too
        self._make_args = {"env_name": env_key, "max_steps": max_steps, "output": output, **({} if hidden is None else {"hidden": tuple(hidden)})}
        if env_kwargs:
            self._make_args["env_kwargs"] = dict(env_kwargs)
        self._local = make_evaluator(**self._make_args)
        self.last_obs_stats = None

    def __getattr__(self, name):  # env_name, obs_dim, out_dim, num_params, hidden, discrete, max_steps, policy
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._local, name)

    def _check(self, params, seeds):
        params = np.asarray(params, dtype=np.float64)
        if params.ndim == 1:
            params = params[None, :]
        seeds = np.asarray(seeds).reshape(-1)
        if params.ndim != 2 or params.shape[1] != self._local.num_params:
            raise ValueError(f"{self._local.env_name}: params must have shape (B, {self._local.num_params}), got {params.shape}")
        if seeds.shape[0] != params.shape[0]:
            raise ValueError(f"{self._local.env_name}: {params.shape[0]} members but {seeds.shape[0]} episode seeds")
        if seeds.size and (seeds.dtype.kind not in "iu" or seeds.min() < 0):
            raise ValueError(f"{self._local.env_name}: episode seeds must be non-negative integers")
        return params, seeds

    def _chunks(self, n: int) -> list[np.ndarray]:
        if n == 0:
            return []
        # One worker has nothing to balance: one chunk spares the per-call overhead of the others
        # (a batched evaluator's per-step work is shared by every member of its call).
        per_worker = self.chunks_per_worker if self.workers > 1 else 1
        return np.array_split(np.arange(n), min(n, self.workers * per_worker))

    def _gather(self, results, n: int):
        returns = np.concatenate([r[0] for r in results]) if results else np.zeros(0)
        steps = np.concatenate([r[1] for r in results]) if results else np.zeros(0, dtype=np.int64)
        stats = [r[2] for r in results]
        if stats and all(s is not None for s in stats):
            self.last_obs_stats = (np.concatenate([s[0] for s in stats]), np.concatenate([s[1] for s in stats]))
        else:
            self.last_obs_stats = None
        assert returns.shape[0] == n
        return returns, steps

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._local.env_name!r}, workers={self.workers}, num_params={self._local.num_params})"


# --------------------------------------------------------------------------- process pool
_worker_evaluator = None


def _init_pool_worker(make_args, parent_pid: int) -> None:
    global _worker_evaluator
    _worker_evaluator = make_evaluator(**make_args)
    # Ctrl-C reaches the whole process group: the main process alone decides, and shuts the pool down
    # (each worker printed a line of its own); SIGTERM ends a worker silently.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    start_orphan_watchdog(parent_pid)


def _evaluate_chunk(params: np.ndarray, seeds: np.ndarray):
    returns, steps = _worker_evaluator.evaluate(params, seeds)
    return returns, steps, getattr(_worker_evaluator, "last_obs_stats", None)


class PoolEvaluator(_Remote):
    """Evaluation over a persistent pool of ``workers`` spawned processes (module docstring)."""

    def __init__(self, env_key: str, max_steps: int | None = None, hidden=None, workers: int | None = None, output: str = "tanh", env_kwargs=None):
        super().__init__(env_key, max_steps, hidden, output, env_kwargs)
        self.workers = int(workers or default_workers())
        # One BLAS thread per worker process (the workers already use every core): one_blas_thread() around the
        # submits, which start them.
        ctx = spawn_context()
        self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=ctx, initializer=_init_pool_worker, initargs=(self._make_args, os.getpid()))
        self._finalizer = weakref.finalize(self, self._pool.shutdown, wait=True, cancel_futures=True)

    def evaluate(self, params, seeds) -> tuple[np.ndarray, np.ndarray]:
        params, seeds = self._check(params, seeds)
        with one_blas_thread():
            futures = [self._pool.submit(_evaluate_chunk, params[c], seeds[c]) for c in self._chunks(len(seeds))]
        return self._gather([f.result() for f in futures], len(seeds))

    def close(self) -> None:
        self._finalizer()


# --------------------------------------------------------------------------- Ray
class _RayWorker:
    """A Ray actor holding one evaluator (its own env instances)."""

    def __init__(self, make_args):
        self.evaluator = make_evaluator(**make_args)

    def evaluate(self, params, seeds):
        returns, steps = self.evaluator.evaluate(params, seeds)
        return returns, steps, getattr(self.evaluator, "last_obs_stats", None)


class RayEvaluator(_Remote):
    """Evaluation over Ray actors, one CPU each (module docstring).

    ``address``: given to ``ray.init`` (None: start a local Ray for this process, sized to
    ``workers`` CPUs, shut down by :meth:`close`). Every node needs imix installed (the same
    version) in the Python that runs its Ray workers.

    Why a reaper: Ray's server processes die with the process that started them, but the agents
    they start lingered 30-90 s after a kill -9 of it; :func:`imix_cli.core.processes.start_reaper`
    ends every process of the local Ray within a second, however this process ends. A killed
    actor is restarted by Ray and its chunk retried (``max_restarts`` times; an episode depends only
    on its parameters and episode seed, so a retry returns the same numbers); an actor lost for good
    is an :class:`EvaluatorError` (one line).
    """

    #: Restarts of a dead actor (and retries of the chunks it was running) before the run stops.
    max_restarts = 3

    def __init__(
        self, env_key: str, max_steps: int | None = None, hidden=None, workers: int | None = None, address: str | None = None, output: str = "tanh",
        env_kwargs=None,
    ):  # fmt: skip
        super().__init__(env_key, max_steps, hidden, output, env_kwargs)
        import ray

        from imix_cli.core.processes import children_of, start_reaper

        self._reaper = None
        self._started_ray = not ray.is_initialized()
        if self._started_ray:
            options = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
            handlers = _python_signal_handlers()
            if address is None:  # a local Ray for this run alone, sized to it
                before = children_of(os.getpid())
                with _quiet_token_notice():
                    ray.init(num_cpus=int(workers or default_workers()), **options)
                self._reaper = start_reaper(children_of(os.getpid()) - before)
            else:
                ray.init(address=address, **options)
            # Ray's driver replaces the SIGTERM/SIGINT handlers at C level (a stack dump, then exit 15):
            # the run's own handlers stop it cleanly, with one line.
            for signum, handler in handlers.items():
                signal.signal(signum, handler)
        self.workers = int(workers or max(1, int(ray.cluster_resources().get("CPU", 1))))
        actor = ray.remote(num_cpus=1, max_restarts=self.max_restarts, max_task_retries=self.max_restarts)(_RayWorker)
        self._actors = [actor.remote(self._make_args) for _ in range(self.workers)]

    def evaluate(self, params, seeds) -> tuple[np.ndarray, np.ndarray]:
        from ray.exceptions import RayActorError
        from ray.util import ActorPool

        params, seeds = self._check(params, seeds)
        chunks = self._chunks(len(seeds))
        pool = ActorPool(self._actors)
        try:
            results = list(pool.map(lambda actor, c: actor.evaluate.remote(params[c], seeds[c]), chunks))  # in order
        except RayActorError as err:
            reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            raise EvaluatorError(
                f"evaluator=ray: an actor was lost after {self.max_restarts} restarts ({reason[:200]}); re-run the same command to resume from the checkpoints"
            ) from None
        return self._gather(results, len(seeds))

    def close(self) -> None:
        import ray

        from imix_cli.core.processes import stop_reaper

        for a in getattr(self, "_actors", []):
            try:
                ray.kill(a)
            except Exception:  # noqa: BLE001 - an actor already gone
                pass
        self._actors = []
        if self._started_ray and ray.is_initialized():
            ray.shutdown()
        self._started_ray = False
        stop_reaper(getattr(self, "_reaper", None))
        self._reaper = None


def _python_signal_handlers() -> dict:
    """SIGINT's and SIGTERM's Python handlers, where this is the main thread (only it may set them)."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    handlers = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    return {signum: handler for signum, handler in handlers.items() if handler is not None}


def _quiet_token_notice():
    """Ray 2.5x+ logs a notice at every local start that it enabled token authentication (it stays
    enabled): one line per run on stderr that says nothing about the run."""
    import contextlib
    import logging

    logger = logging.getLogger("ray._private.authentication.authentication_token_setup")

    @contextlib.contextmanager
    def quiet():
        level = logger.level
        logger.setLevel(logging.ERROR)
        try:
            yield
        finally:
            logger.setLevel(level)

    return quiet()
