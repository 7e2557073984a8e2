"""A finished seed's CSV checked against the config of its run: the one check run, plot, eval and status share.

:func:`imix_cli.running.files.results.read_run_csv` checks that a CSV follows the contract; :func:`check_seed_csv` checks
that it is a seed of *this* run -- the run folder's config.yaml (or, for ``imix run``, the command's config) -- and raises
:class:`~imix_cli.running.files.results.ResultMismatchError`, a :class:`~imix_cli.running.files.results.CorruptResultError`, so that
every reader's handling of a corrupt CSV applies to it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imix_cli.core.envs.ids import plain_env_id
from imix_cli.core.registry import BUILTIN_ENVS, env_return_bounds
from imix_cli.messages import shown_value
from imix_cli.running.files.results import COLUMNS, ResultMismatchError
from imix_cli.running.trainers import trainer_named

__all__ = ["SCHEDULE_KEYS", "check_seed_csv", "check_seed_scores", "csv_env_name"]


#: The schedule keys of a run's config.yaml: where and on how many episodes the distribution mean is measured.
SCHEDULE_KEYS = ("eval_mean_every", "eval_mean_episodes")


def csv_env_name(config: dict) -> str | None:
    """The ``env`` column a run of ``config`` (config.yaml's mapping) writes: a built-in env's config name when its
    id is the built-in's, else the plain gymnasium id (``module:`` dropped), as ``env_of`` names the run; None if the
    config does not say."""
    env = config.get("env")
    if not isinstance(env, dict) or not isinstance(env.get("id"), str):
        return None
    name, env_id = env.get("name"), env["id"]
    return name if name in BUILTIN_ENVS and env_id == BUILTIN_ENVS[name] else plain_env_id(env_id)


def check_seed_csv(frame, path, config: dict) -> None:
    """Raise :class:`ResultMismatchError` (one line naming ``path`` and the mismatch) if a seed's CSV contradicts the
    config of its run.

    ``frame``: the CSV as :func:`read_run_csv` returned it (the contract already holds); ``config``: the run's
    config.yaml mapping (``imix run`` passes its own config, schedule keys from config.yaml). A key ``config`` lacks (or
    holds null) is not compared: a config.yaml of an older imix still lets its CSVs be read; one it holds as a value of
    a type no run writes (``popsize: [1, 2]``) is a mismatch naming config.yaml.

    Why: a CSV is a file like any other -- copied from another run, left by an older version, edited -- and every
    reader took one that follows the contract as a seed of the run it sits in: ``imix run`` summed a CSV of another env
    or popsize into its summary as a finished seed ("reuse 100.0%"), and a run continued after a changed default
    (``eval_mean_every``) appended rows measured on another schedule. Run, plot, eval (and status) share this one check:
    the schema (the header is :data:`COLUMNS`, in order), algo, env, mixing, popsize, at most the run's budget
    (generations, or DDPG's total_steps), the distribution mean measured exactly where :data:`SCHEDULE_KEYS` say, and
    every score a return the run's env can give (:func:`check_seed_scores`). A compared key of ``config`` holding a value
    of a type no run writes is a mismatch naming config.yaml."""
    _check_config_types(config, path)
    header = frame.attrs.get("header", COLUMNS)
    if tuple(header) != COLUMNS:
        extra = [c for c in header if c not in COLUMNS]
        what = f"extra column(s) {extra[:3]}" if extra else "its columns in another order"
        raise ResultMismatchError(f"{path}: not the seed CSV schema of this imix ({what})")
    algo_cfg = config.get("algo") if isinstance(config.get("algo"), dict) else {}
    algo = algo_cfg.get("name")
    expected = {"algo": algo, "env": csv_env_name(config), "mixing": config.get("mixing")}
    for column, want in expected.items():
        got = str(frame[column].iloc[0])
        if isinstance(want, str) and got != want:
            raise ResultMismatchError(f"{path}: a {column}={got} seed, its run's config has {column}={want} (a CSV of another run?)")
    popsize = config.get("popsize")  # an ES's (algo=ddpg's config.yaml has none: one member)
    if _is_count(popsize) and int(frame["popsize"].iloc[0]) != popsize:
        raise ResultMismatchError(f"{path}: rows of popsize {int(frame['popsize'].iloc[0])}, its run's config has popsize={popsize}")
    trainer = trainer_named(algo)
    budget = config.get(trainer.budget_key)
    spent = len(frame) if trainer.unit == "gen" else int(frame["env_steps"].iloc[-1])  # generations, or DDPG's env steps
    if _is_count(budget) and spent > budget:
        unit = "generations" if trainer.unit == "gen" else "env steps"
        raise ResultMismatchError(f"{path}: has {spent} {unit}, its run's config has {trainer.budget_key}={budget}")
    if trainer.unit == "gen":  # an ES measures its distribution mean on a schedule; DDPG never does
        _check_schedule(frame, path, config)
    check_seed_scores(frame, path, config)  # last: a CSV of another run is named as such first


def check_seed_scores(frame, path, config: dict) -> None:
    """ResultMismatchError (one line naming ``path``, the column, the value and the generation) unless every score of
    the CSV is a return the run's env can give: the bounds a checkpoint's scores are checked against
    (:func:`imix_cli.core.registry.env_return_bounds`: CartPole 0 to its episode cap, Acrobot minus the cap to 0;
    members' returns moved by ARS's ``algo.alive_bonus_offset``), from ``config`` (config.yaml's ``env.name``,
    ``env.id``, ``env.max_steps``). Before, a CartPole seed scoring 1e308 reached plot's iqm threshold and status
    printed its 309 digits. (:func:`~imix_cli.running.files.results.read_run_csv` has refused infinities, a NaN
    where a run writes a number, and a mean above the best.)"""
    env_name = csv_env_name(config)
    if env_name is None:
        return
    env_cfg = config.get("env") if isinstance(config.get("env"), dict) else {}
    algo_cfg = config.get("algo") if isinstance(config.get("algo"), dict) else {}
    cap = env_cfg.get("max_steps") if _is_count(env_cfg.get("max_steps")) else None
    offset = algo_cfg.get("alive_bonus_offset", 0.0)
    offset = float(offset) if isinstance(offset, (int, float)) and not isinstance(offset, bool) and np.isfinite(offset) else 0.0
    for column, training in (("mean_score", True), ("best_score", True), ("mean_policy_score", False)):
        low, high = env_return_bounds(env_name, cap, offset if training else 0.0)
        values = frame[column].to_numpy(dtype=np.float64)
        outside = (values < low - 1e-9) | (values > high + 1e-9)  # NaN: neither; the checkpoint check's tolerance
        if outside.any():
            row = int(np.argmax(outside))
            episodes = f", episodes of at most {cap} steps" if cap else ""
            raise ResultMismatchError(f"{path}: {column}={values[row]:.6g} at generation {row} is not a return of {env_name} "
                                      f"(from {low:g} to {high:g}{episodes})")  # fmt: skip


#: The keys of a run's config.yaml that ``check_seed_csv`` compares, and what every run writes there (or null).
_COUNT_KEYS = ("popsize", "generations", "total_steps", *SCHEDULE_KEYS)
_NAME_KEYS = (("mixing",), ("algo", "name"), ("env", "name"), ("env", "id"))


def _check_config_types(config: dict, path) -> None:
    """ResultMismatchError naming the run's config.yaml if a key the check compares holds a value of a type no run
    writes (``popsize: [1, 2]``, ``generations: '2'``, ``mixing: 3``): such a config is not the run's, and comparing
    nothing with it let plot and eval use the CSVs without a word (``popsize: 7`` was caught, ``[1, 2]`` was not)."""
    config_file = Path(path).parent / "config.yaml"
    for key in _COUNT_KEYS:
        value = config.get(key)
        if value is not None and not _is_count(value):
            raise ResultMismatchError(f"{config_file}: {key}={shown_value(value)} is not an integer >= 0, as every run writes it; "
                                      f"{Path(path).name} is not read against it (fix or move that config.yaml)")  # fmt: skip
    for keys in _NAME_KEYS:
        value = config
        for key in keys:
            value = value.get(key) if isinstance(value, dict) else None
        if value is not None and not isinstance(value, str):
            raise ResultMismatchError(f"{config_file}: {'.'.join(keys)}={shown_value(value)} is not a name, as every run writes it; "
                                      f"{Path(path).name} is not read against it (fix or move that config.yaml)")  # fmt: skip
    for group in ("algo", "env"):
        if config.get(group) is not None and not isinstance(config.get(group), dict):
            raise ResultMismatchError(f"{config_file}: {group}={shown_value(config.get(group))} is not a mapping, as every run writes it; "
                                      f"{Path(path).name} is not read against it (fix or move that config.yaml)")  # fmt: skip


def _is_count(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _check_schedule(frame, path, config: dict) -> None:
    """ResultMismatchError unless the distribution mean was measured (``mean_policy_episodes`` grows by
    ``eval_mean_episodes``) at exactly the rows ``eval_mean_every`` schedules -- row r when (r + 1) % every == 0 -- and
    nowhere else (a diverged seed's last row may go unmeasured: its mean is not finite)."""
    every, episodes = (config.get(k) for k in SCHEDULE_KEYS)
    if not _is_count(every) or not _is_count(episodes):
        return
    counted = frame["mean_policy_episodes"].to_numpy(dtype=np.int64)
    grown = np.diff(counted, prepend=0)
    rows = np.arange(len(frame))
    due = (rows + 1) % every == 0 if every else np.zeros(len(frame), dtype=bool)
    diverged_last = np.zeros(len(frame), dtype=bool)
    diverged_last[-1] = frame["diverged"].iloc[-1] == 1
    measured = np.isfinite(frame["mean_policy_score"].to_numpy(dtype=np.float64))
    wrong = (grown != np.where(due, episodes, 0)) & ~(due & diverged_last & (grown == 0)) | (measured & (grown == 0))
    if np.any(wrong):
        first = int(np.argmax(wrong))
        raise ResultMismatchError(
            f"{path}: the distribution mean was measured on another schedule than its run's eval_mean_every={every}, "
            f"eval_mean_episodes={episodes} (generation {first}: {int(grown[first])} episodes); a CSV continued after a change of either?"
        )
