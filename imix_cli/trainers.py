"""The trainer interface: what the runner needs to know of a kind of algorithm, and nothing more.

The runner, the run folder's validation and the summary ask the run's :class:`Trainer`
(:func:`trainer_for`) instead of testing the algorithm's name: the evolution strategies
(:mod:`imix_cli.es_seeds`) and the DDPG baseline (:mod:`imix_cli.ddpg_seeds`) share the run
folder, process pool and CSV contract, and differ only in what is declared here.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import import_module
from pathlib import Path


@dataclass(frozen=True)
class Trainer:
    """How the seeds of one kind of algorithm are trained.

    ``module`` holds the two functions (imported when needed, so that SB3 loads only for DDPG):
    ``<loop>(spec, seeds, progress) -> {seed: summary}`` runs seeds to completion in this process
    and ``needs_running(spec, seed, path, frame) -> bool`` says whether a seed whose CSV exists
    is to be run further (RunError if that CSV does not fit the config).
    """

    module: str
    loop: str
    unit: str  # what progress counts: "gen" (seed-generations) or "step" (environment steps)
    budget_key: str  # the RunSpec field (and config.yaml key) holding a seed's budget in those units
    continuable: bool  # a finished run may be continued to a larger budget from its final states
    compares_mixing: bool  # the summary compares sibling runs with other mixing settings

    def budget(self, spec) -> int:
        return getattr(spec, self.budget_key)

    def run_seeds(self, spec, seeds: list[int], progress) -> dict:
        return getattr(import_module(self.module), self.loop)(spec, seeds, progress)

    def needs_running(self, spec, seed: int, path: Path, frame) -> bool:
        return import_module(self.module).needs_running(spec, seed, path, frame)


EVOLUTION_STRATEGY = Trainer("imix_cli.es_seeds", "run_es_seeds", "gen", "generations", continuable=True, compares_mixing=True)
DDPG = Trainer("imix_cli.ddpg_seeds", "run_ddpg_seeds", "step", "total_steps", continuable=False, compares_mixing=False)

#: Algorithms that are not evolution strategies, by name; every other algo is an ES.
TRAINERS = {"ddpg": DDPG}


def trainer_named(algo) -> Trainer:
    """The trainer of algorithm ``algo`` (a name, as ``algo=`` takes it; anything else: an ES's)."""
    return TRAINERS.get(algo, EVOLUTION_STRATEGY) if isinstance(algo, str) else EVOLUTION_STRATEGY


def trainer_for(spec) -> Trainer:
    return trainer_named(spec.algo)
