"""``hydra/sweeper=optuna``: the search's own settings and its search space, checked before any trial runs.

imix's Optuna sweeper (``hydra_plugins/imix_optuna_sweeper``, the logic in :mod:`imix_cli.commands.search`) takes
Hydra's sweep syntax as a search space::

    sigma=interval(0.01,0.5)            a float in [0.01, 0.5]
    lr=tag(log, interval(1e-3,1e-1))    the same on a log scale
    popsize=choice(10,20,50)            one of these (also popsize=10,20,50)
    popsize=range(10,60,10)             an integer 10, 20, ..., 50 (stop excluded, as Hydra's range)
    popsize=tag(int, interval(10,50))   an integer in [10, 50] (tag(log, int, ...): on a log scale)

and its settings as ``hydra.sweeper.<key>`` (conf/hydra/sweeper/optuna.yaml). :func:`probe_values` gives, for each
search-space override, the values validation composes and checks as sweep points (both ends of an interval and one
value inside it, every choice, both ends of a range): a key that does not exist or a bound no value may take is one
line, exit status 2, before the first trial. :func:`check_search_settings` checks the sweeper's keys.
"""

from __future__ import annotations

import math

from imix_cli.messages import MissingExtraError, install_extra, shown_value
from imix_cli.running.config.checks import ConfigError, is_number

#: The measures a trial returns (:mod:`imix_cli.running.objective`), by ``hydra.sweeper.objective``, and their direction.
OBJECTIVES = {"theta": "maximize", "episodes": "minimize", "return_at": "maximize", "iqm": "maximize"}
SAMPLERS = ("tpe", "cmaes", "random")
#: The ``_target_`` of conf/hydra/sweeper/optuna.yaml: how validation and the task know the search is imix's own.
SWEEPER_TARGET = "hydra_plugins.imix_optuna_sweeper.optuna_sweeper.ImixOptunaSweeper"
#: The sweeper's keys (conf/hydra/sweeper/optuna.yaml), with ``_target_``.
SWEEPER_KEYS = ("_target_", "objective", "threshold", "budget", "n_trials", "n_jobs", "sampler", "seed", "storage", "study_name", "pruner")
PRUNERS = ("none", "median")
#: With a pruner, a trial's run is made in these fractions of its ``generations`` (a run continued to more generations
#: is exactly the run made with them at once: :data:`imix_cli.running.config.run_spec.CONTINUABLE_KEYS`), its objective
#: reported to the pruner after each but the last.
PRUNING_STAGES = (0.25, 0.5, 1.0)


def is_search(sweeper_target) -> bool:
    return str(sweeper_target or "") == SWEEPER_TARGET


def missing_search_extra() -> str | None:
    """The one line for ``hydra/sweeper=optuna`` without optuna installed (exit status 2, as every missing extra)."""
    import importlib.util

    if importlib.util.find_spec("optuna") is None:
        return f"hydra/sweeper=optuna: optuna is not installed; {install_extra('search')}"
    return None


def check_search_settings(sweeper: dict) -> dict:
    """The ``hydra.sweeper.*`` settings of imix's Optuna sweeper, checked (ConfigError naming the key); returns them."""
    missing = missing_search_extra()
    if missing:
        raise MissingExtraError(missing)
    unknown = sorted(set(sweeper) - set(SWEEPER_KEYS))
    if unknown:  # a --config-name YAML's hydra.sweeper (the command line's typo is refused by Hydra's struct)
        raise ConfigError(f"unknown key hydra.sweeper.{unknown[0]}; valid keys: {', '.join(k for k in SWEEPER_KEYS if k != '_target_')}")
    out = dict(sweeper)
    objective = sweeper.get("objective")
    if objective not in OBJECTIVES:
        raise ConfigError(f"hydra.sweeper.objective={shown_value(objective)}: must be one of {', '.join(OBJECTIVES)}")
    for key in ("n_trials", "n_jobs"):
        value = sweeper.get(key)
        if not is_number(value) or float(value) != int(value) or value < 1:
            raise ConfigError(f"hydra.sweeper.{key}={shown_value(value)}: must be an integer >= 1")
        out[key] = int(value)
    if sweeper.get("sampler") not in SAMPLERS:
        raise ConfigError(f"hydra.sweeper.sampler={shown_value(sweeper.get('sampler'))}: must be one of {', '.join(SAMPLERS)}")
    seed = sweeper.get("seed")
    if seed is not None and (not is_number(seed) or float(seed) != int(seed) or seed < 0):
        raise ConfigError(f"hydra.sweeper.seed={shown_value(seed)}: must be an integer >= 0 (or null)")
    threshold, budget = sweeper.get("threshold"), sweeper.get("budget")
    if objective == "episodes" and (not is_number(threshold) or not math.isfinite(threshold)):
        raise ConfigError(f"hydra.sweeper.threshold={shown_value(threshold)}: objective=episodes needs the return that counts as reached, e.g. -100")
    if objective != "episodes" and threshold is not None:
        raise ConfigError(f"hydra.sweeper.threshold={shown_value(threshold)}: read by objective=episodes only (objective={objective})")
    if objective == "return_at" and (not is_number(budget) or float(budget) != int(budget) or budget < 1):
        raise ConfigError(f"hydra.sweeper.budget={shown_value(budget)}: objective=return_at needs the episodes per seed, an integer >= 1")
    if objective != "return_at" and budget is not None:
        raise ConfigError(f"hydra.sweeper.budget={shown_value(budget)}: read by objective=return_at only (objective={objective})")
    if sweeper.get("pruner", "none") not in PRUNERS:
        raise ConfigError(f"hydra.sweeper.pruner={shown_value(sweeper.get('pruner'))}: must be one of {', '.join(PRUNERS)}")
    out["pruner"] = sweeper.get("pruner", "none")
    for key in ("storage", "study_name"):
        value = sweeper.get(key)
        if value is not None and (not isinstance(value, str) or not value.strip() or not value.isprintable()):
            raise ConfigError(f"hydra.sweeper.{key}={shown_value(value)}: must be a non-empty string (or null)")
    return out


def check_trial_config(spec, settings: dict) -> None:
    """What a trial's run must measure for the objective: θ's return (``eval_mean_every`` > 0), which every objective reads; an ES."""
    if spec.algo == "ddpg":
        raise ConfigError("hydra/sweeper=optuna: algo=ddpg is not supported (the objectives are an evolution strategy's measures)")
    if not spec.eval_mean_every:  # every objective reads θ's return on fresh episodes
        raise ConfigError(f"hydra.sweeper.objective={settings['objective']} measures the distribution mean's return: eval_mean_every must be > 0")


def probe_values(override) -> list:
    """The values of a search-space override (Hydra's parsed override) that validation composes as sweep points: every
    choice, both ends of a range, both ends of an interval and a point inside it (a non-integer one, so that an integer
    key given a float interval is refused up front rather than at its first trial). ConfigError for what Optuna cannot
    search (an empty interval, a log scale reaching 0)."""
    from hydra.core.override_parser.types import ChoiceSweep, IntervalSweep, RangeSweep

    value = override.value()
    line = override.input_line
    if isinstance(value, ChoiceSweep):
        if not value.list:
            raise ConfigError(f"{line}: an empty choice")
        return list(value.list)
    if isinstance(value, RangeSweep):
        values = list(override.sweep_iterator())
        if not values:
            raise ConfigError(f"{line}: an empty range")
        return [values[0], values[-1]] if len(values) > 1 else values
    if isinstance(value, IntervalSweep):
        low, high = float(value.start), float(value.end)
        unknown = sorted(set(value.tags) - {"log", "int"})
        if unknown:
            raise ConfigError(f"{line}: unknown tag {unknown[0]!r}; an interval takes tag(log, ...) and tag(int, ...)")
        if not low < high:
            raise ConfigError(f"{line}: the interval's start must be below its end")
        if "log" in value.tags and low <= 0:
            raise ConfigError(f"{line}: a log-scale interval must start above 0")
        if "int" in value.tags:
            if not (low.is_integer() and high.is_integer()):
                raise ConfigError(f"{line}: tag(int, ...) needs integer ends")
            return [int(low), int(high)]
        inside = low + (high - low) * 0.3719
        return [low, high, inside]
    raise ConfigError(f"{line}: not a search space the optuna sweeper reads (interval, choice, range)")
