"""What a trial of ``imix run -m hydra/sweeper=optuna`` returns: one number measured from its run's seed CSVs.

Each objective is a measure every run already records (the CSV contract, :mod:`imix_cli.running.files.results`):

``theta`` (maximised)
    the distribution mean θ's return on fresh episodes (``mean_policy_score``) where each seed last measured it, mean
    over seeds -- the summary table's θ column; free of reused returns.
``iqm`` (maximised)
    the same per-seed values, their interquartile mean over seeds (:func:`imix_cli.core.stats.iqm`: ``int(0.25 n)``
    seeds cut at each end; with fewer than 4 seeds none is cut, so it is the mean).
``episodes`` (minimised)
    per seed, the episodes (cumulative ``evaluations``) of the first generation whose measurement of θ's return
    (``mean_policy_score``, every ``eval_mean_every`` generations) reaches ``threshold`` -- the definition of ``imix
    plot``'s episodes-to-threshold tables, free of reused returns (the population's mean would count a reused member's
    lucky stored episode as progress: docs/outputs.md, "Which return each output measures"). A seed that
    never reaches it counts the episodes it spent, and each such seed adds :data:`UNREACHED` to the value: a run where
    k seeds never reach the threshold ranks below every run where fewer do, whatever their episodes (as long as a seed
    spends fewer than 10^12 episodes), and among runs with the same k, fewer episodes rank better.
``return_at`` (maximised)
    per seed, θ's return at its last measurement whose cumulative episodes are at most ``budget`` (the zero-order hold
    of ``imix plot``'s curves against episodes), mean over seeds. A seed that measured θ only after spending more has
    no value there: the trial fails (raise the budget, or measure θ more often with ``eval_mean_every``).
"""

from __future__ import annotations

import math

import numpy as np

from imix_cli.running.files.results import read_run_csv, seed_csv_path

#: What each seed that never reaches the threshold adds to objective=episodes.
UNREACHED = 1e12


class ObjectiveError(ValueError):
    """The run has no value for the objective (one line)."""


def objective_value(run_dir, seeds: int, objective: str, threshold=None, budget=None) -> tuple[float, dict]:
    """The objective of the run in ``run_dir`` (its ``seeds`` finished seed CSVs), and what it was made of (per seed)."""
    frames = [read_run_csv(seed_csv_path(run_dir, seed)) for seed in range(seeds)]
    if objective in ("theta", "iqm"):
        values = []
        for frame in frames:
            measured = frame["mean_policy_score"].to_numpy(dtype=float)
            measured = measured[np.isfinite(measured)]
            values.append(float(measured[-1]) if measured.size else math.nan)
        if not all(math.isfinite(v) for v in values):
            raise ObjectiveError(f"objective={objective}: a seed of {run_dir} has no finite measurement of θ's return (eval_mean_every)")
        if objective == "theta":
            return float(np.mean(values)), {"per_seed": values}
        from imix_cli.core.stats import iqm

        return float(iqm(values)), {"per_seed": values}
    if objective == "episodes":
        episodes, reached = [], 0
        for frame in frames:
            scores, spent = frame["mean_policy_score"].to_numpy(dtype=float), frame["evaluations"].to_numpy(dtype=float)
            hits = np.flatnonzero(scores >= threshold)  # NaN (no measurement that generation) is never a hit
            reached += bool(hits.size)
            episodes.append(float(spent[hits[0]] if hits.size else spent[-1]))
        unreached = seeds - reached
        return float(np.mean(episodes)) + UNREACHED * unreached, {"per_seed": episodes, "seeds_reached": reached}
    if objective == "return_at":
        values = []
        for seed, frame in enumerate(frames):
            spent, theta = frame["evaluations"].to_numpy(dtype=float), frame["mean_policy_score"].to_numpy(dtype=float)
            within = np.flatnonzero((spent <= budget) & np.isfinite(theta))
            if not within.size:
                raise ObjectiveError(
                    f"objective=return_at: seed {seed} of {run_dir} measured θ only after {budget} episodes (budget=): raise the budget "
                    "or lower eval_mean_every"
                )
            values.append(float(theta[within[-1]]))
        short = sum(int(f["evaluations"].iloc[-1]) < budget for f in frames)  # seeds that ended before the budget: their last value
        return float(np.mean(values)), {"per_seed": values, "seeds_short_of_budget": short}
    raise ObjectiveError(f"unknown objective {objective!r}")
