"""The trainer interface: what the runner needs to know of a kind of algorithm, and nothing more.

The runner, the run folder's validation and the summary ask the run's :class:`Trainer`
(:func:`trainer_for`) instead of testing the algorithm's name: the evolution strategies
(:mod:`imix_cli.running.loop.es_seeds`) and the DDPG baseline (:mod:`imix_cli.running.loop.ddpg_seeds`) share the run
folder, process pool and CSV contract, and differ only in what is declared here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from imix_cli.messages import install_extra
from imix_cli.running.files.results import es_seed_finished
from imix_cli.running.loop import SEED_GROUP  # noqa: F401 (re-exported: the runner reads it here)


@dataclass(frozen=True)
class Trainer:
    """How the seeds of one kind of algorithm are trained.

    ``run_seeds(spec, seeds, progress, resumed) -> {seed: summary}`` runs seeds to completion in this process
    (``resumed({seed: generation})``: where each starts, told once)
    and ``needs_running(spec, seed, path, frame) -> bool`` says whether a seed whose CSV exists
    is to be run further (RunError if that CSV does not fit the config). Both are the functions
    below (the ES's ``run_seeds`` also builds the run's evaluator, and closes it), which import
    their trainer's module when called: ``imix status`` and the run folder's
    checks load neither numba nor the envs, and SB3 loads only for DDPG.
    """

    run_seeds: Callable[..., dict]
    needs_running: Callable[..., bool]
    finished: Callable[..., bool]  # finished(frame, budget): whether a seed whose CSV holds ``frame`` is done (see es_seed_finished)
    unit: str  # what progress counts: "gen" (seed-generations) or "step" (environment steps)
    budget_key: str  # the RunSpec field (and config.yaml key) holding a seed's budget in those units
    continuable: bool  # a finished run may be continued to a larger budget from its final states
    compares_mixing: bool  # the summary compares sibling runs with other mixing settings
    needs: tuple = ()  # (module, pip requirement): the optional packages its seeds import
    install: str = ""  # how to install them, as the docs say

    def budget(self, spec) -> int:
        return getattr(spec, self.budget_key)

    def missing_extra(self) -> str | None:
        """One line naming what to install if a package of :attr:`needs` is missing (looked up, not imported:
        torch takes seconds to import), else None. Why up front: the import failed only in the seeds' processes,
        as a 40-line traceback, after the run folder was made."""
        import importlib.util

        def found(module: str) -> bool:
            try:
                return importlib.util.find_spec(module) is not None
            except (ImportError, ValueError):  # ValueError: sys.modules holds None for it (an import blocked)
                return False

        missing = [requirement for module, requirement in self.needs if not found(module)]
        return f"algo=ddpg needs {' and '.join(missing)}, not installed: {self.install}" if missing else None


def _run_es_seeds(spec, seeds: list[int], progress, resumed=None) -> dict:
    """The run's evaluator, then its seeds on it: the evaluator's processes (pool, Ray) end with the
    seeds, a Ctrl-C or SIGTERM included. A Ctrl-C or SIGTERM stops the seeds between two generations,
    checkpointed, and acts once the evaluator is closed (:mod:`imix_cli.running.loop.stopping`)."""
    from imix_cli.core.evaluation.parallel import build_evaluator
    from imix_cli.running.loop.es_seeds import run_es_seeds
    from imix_cli.running.loop.stopping import stops_between_generations

    evaluator = build_evaluator(spec)
    with stops_between_generations():
        try:
            return run_es_seeds(spec, seeds, progress, evaluator, resumed)
        finally:
            close = getattr(evaluator, "close", None)  # a user's evaluator may have nothing to close
            if close is not None:
                close()


def _ddpg_seed_finished(frame, total_steps) -> bool:
    return True  # a DDPG seed's CSV is written once, when it ends (never continued: needs_running)


def _es_needs_running(spec, seed: int, path: Path, frame) -> bool:
    from imix_cli.running.loop.es_seeds import needs_running

    return needs_running(spec, seed, path, frame)


def _run_ddpg_seeds(spec, seeds: list[int], progress, resumed=None) -> dict:  # a DDPG seed is never resumed
    from imix_cli.running.loop.ddpg_seeds import run_ddpg_seeds

    return run_ddpg_seeds(spec, seeds, progress)


def _ddpg_needs_running(spec, seed: int, path: Path, frame) -> bool:
    from imix_cli.running.loop.ddpg_seeds import needs_running

    return needs_running(spec, seed, path, frame)


EVOLUTION_STRATEGY = Trainer(_run_es_seeds, _es_needs_running, es_seed_finished, "gen", "generations", continuable=True, compares_mixing=True)
DDPG = Trainer(
    _run_ddpg_seeds, _ddpg_needs_running, _ddpg_seed_finished, "step", "total_steps", continuable=False, compares_mixing=False,
    needs=(("torch", "torch"), ("stable_baselines3", "stable-baselines3")),
    install=install_extra("ddpg", first="torch==2.13.0") + " (a CPU torch first: an unpinned one pulls several GB of CUDA packages)",
)  # fmt: skip

#: Algorithms that are not evolution strategies, by name; every other algo is an ES.
TRAINERS = {"ddpg": DDPG}


def trainer_named(algo) -> Trainer:
    """The trainer of algorithm ``algo`` (a name, as ``algo=`` takes it; anything else: an ES's)."""
    return TRAINERS.get(algo, EVOLUTION_STRATEGY) if isinstance(algo, str) else EVOLUTION_STRATEGY


def trainer_for(spec) -> Trainer:
    return trainer_named(spec.algo)
