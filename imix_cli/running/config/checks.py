"""The checks every algorithm's config shares: typed values, seeds, workers, the env, memory.

The typed checks take the plain config dict (as Hydra composes it) and a key -- the declarations of
:mod:`imix_cli.running.config.keys` name which check each key gets -- and return the validated value
or raise :class:`ConfigError`, a one-line message that names the offending key; the CLI prints
it and exits with status 2 before anything is written.
"""

from __future__ import annotations

import math
import os

from imix_cli.core.processes import default_workers
from imix_cli.core.registry import BUILTIN_ENVS
from imix_cli.messages import shown_value


class ConfigError(ValueError):
    """A bad configuration value; ``str(err)`` is a one-line message naming the key."""


#: Hydra launchers that run several jobs at once on one machine (or in Ray's workers): there a
#: per-job process pool must step aside (a spawn pool inside a joblib/loky worker dies), so
#: `workers` defaults to 1 under them and an explicit workers > 1 is refused.
PARALLEL_LAUNCHERS = {"JoblibLauncher": "joblib", "RayLauncher": "ray", "RayAWSLauncher": "ray_aws", "LocalLauncher": "submitit_local"}


def parallel_launcher_name(launcher_target: str | None) -> str | None:
    """The short name of a parallel launcher from its ``_target_`` class path, else None."""
    cls = (launcher_target or "").rsplit(".", 1)[-1]
    return PARALLEL_LAUNCHERS.get(cls)


def first_line(err: Exception) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


# ----------------------------------------------------------------------------- typed keys
def is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def as_int(cfg: dict, key: str, minimum: int, label: str | None = None) -> int:
    value = cfg.get(key)
    label = label or key
    if not is_number(value) or (isinstance(value, float) and not value.is_integer()):
        raise ConfigError(f"{label}={shown_value(value)}: must be an integer >= {minimum}")
    if value < minimum:
        raise ConfigError(f"{label}={shown_value(value)}: must be >= {minimum}")
    return int(value)


def as_float(cfg: dict, key: str, low: float, low_inclusive: bool, high: float = math.inf, high_inclusive: bool = False) -> float:
    value = cfg.get(key)
    rule = f"{'>=' if low_inclusive else '>'} {low}" + ("" if high == math.inf else f" and {'<=' if high_inclusive else '<'} {high}")
    if not is_number(value) or not math.isfinite(value):
        raise ConfigError(f"{key}={shown_value(value)}: must be a number {rule}")
    ok_low = value >= low if low_inclusive else value > low
    ok_high = value <= high if high_inclusive else value < high
    if not (ok_low and ok_high):
        raise ConfigError(f"{key}={shown_value(value)}: must be {rule}")
    return float(value)


def as_bounded(cfg: dict, key: str, bound):
    """``cfg[key]`` checked against a :class:`~imix_cli.core.bounds.Bound` of the library's (:data:`imix_cli.core.algorithms.base.PARAM_BOUNDS`,
    :data:`imix_cli.core.mixing.generation.MIXING_BOUNDS`): the CLI and the library's constructors check the same numbers."""
    if bound.integer:
        value = as_int(cfg, key, bound.low)
        if not bound.contains(value):
            raise ConfigError(f"{key}={shown_value(value)}: must be {bound.rule()}")
        return value
    return as_float(cfg, key, bound.low, bound.low_inclusive, bound.high, bound.high_inclusive)


def as_bool(cfg: dict, key: str) -> bool:
    value = cfg.get(key)
    if not isinstance(value, bool):
        raise ConfigError(f"{key}={shown_value(value)}: must be true or false")
    return value


def as_choice(value, key: str, choices) -> str:
    if value not in choices:
        raise ConfigError(f"{key}={shown_value(value)}: valid choices are {', '.join(choices)}")
    return value


def as_name(cfg: dict, key: str) -> str:
    value = cfg.get(key)
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{key}={shown_value(value)}: must be a non-empty name")
    return value


#: The largest ``seeds``: one CSV (and one progress line of work) per seed; beyond this a run is
#: a mistake (``seeds=1e9`` would spend minutes listing files before the first generation).
MAX_SEEDS = 100_000


def seeds_of(cfg: dict) -> int:
    seeds = as_int(cfg, "seeds", 1)
    if seeds > MAX_SEEDS:
        raise ConfigError(f"seeds={seeds}: at most {MAX_SEEDS:,} seeds per run (one CSV per seed); split the work into experiments")
    return seeds


def workers_of(workers: int | None, launcher: str | None, pool: str | None = None) -> int:
    """The checked ``workers`` (None: all cores; 1 under a parallel launcher or with ``pool``, the name of an
    evaluator that spreads each generation itself: ``pool`` or ``ray``), refused where the launcher or ``pool`` run in parallel."""
    parallel = parallel_launcher_name(launcher)
    if workers is None:
        return 1 if parallel or pool else default_workers()
    if parallel and workers > 1:
        raise ConfigError(f"workers={workers}: hydra/launcher={parallel} already runs jobs in parallel; use workers=1 (or leave it null)")
    if pool and workers > 1:
        raise ConfigError(
            f"workers={workers}: evaluator={pool} already spreads each generation over evaluator_workers "
            f"{'processes' if pool == 'pool' else 'Ray actors (one Ray runtime per run)'}; use workers=1 (or leave it null)"
        )
    return workers


def experiment_of(cfg: dict, key: str = "experiment") -> str:
    """``experiment``: a plain folder name the other commands can name too."""
    experiment = as_name(cfg, key)
    if "/" in experiment or "\\" in experiment or experiment in (".", ".."):
        raise ConfigError(f"experiment={shown_value(experiment)}: must be a plain folder name (no path separators)")
    printable = "".join(c for c in experiment if c.isprintable())
    if experiment != printable.strip():  # `imix plot experiment= x` and the other commands strip a value: they could not name this folder
        raise ConfigError(f"experiment={shown_value(experiment)}: must be a plain folder name without leading or trailing spaces or control characters "
                          f"(the other commands could not name it), e.g. experiment={printable.strip() or 'default'}")  # fmt: skip
    return experiment


#: Memory one gymnasium env instance holds (bytes). The generic evaluator keeps one env per member
#: of a batch (:class:`imix_cli.core.evaluation.GymEvaluator`), and the first generation evaluates every
#: member of every seed. Measured as the RSS growth over 300 ``gym.make`` + reset + step, gymnasium
#: 1.x: Hopper-v5 1.05 MiB, HalfCheetah-v5 1.07 MiB per env (MuJoCo: model and data buffers);
#: CartPole-v1 0.005 MiB. MuJoCo envs are counted at 1.1 MiB, any other gymnasium env at 64 KiB.
MUJOCO_ENV_BYTES = int(1.1 * 2**20)
GYM_ENV_BYTES = 64 * 2**10


def check_memory(popsize: int, num_params: int, archive_depth: int, seeds: int = 1, env_bytes: int = 0, env_id: str | None = None) -> None:
    """Refuse a population whose arrays (and envs) cannot fit in this machine's memory.

    A generation holds popsize x d float64 numbers about (archive depth + 3) times over
    (samples, the archive, mixing's and the evaluator's temporaries), plus ``env_bytes`` per
    member for a gymnasium env (:data:`MUJOCO_ENV_BYTES`); every seed of a run is held at once
    (seeds run in lockstep in a process, and the processes run side by side).
    """
    per_seed = 8 * popsize * (num_params + 16) * (archive_depth + 3) + popsize * env_bytes
    needed = seeds * per_seed
    try:
        available = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # not on Linux: no check
        return
    if needed > available:
        envs = f" and one {env_id} env per member (~{env_bytes / 2**20:.2g} MiB each)" if env_bytes else ""
        of_seeds = f"{seeds} seeds of " if seeds > 1 else ""
        raise ConfigError(
            f"popsize={popsize}: {of_seeds}a population of {popsize:,} x {num_params} parameters{envs} need ~{needed / 2**30:,.1f} GiB, "
            f"more than this machine's {available / 2**30:,.1f} GiB" + ("; use fewer seeds per run" if seeds > 1 and per_seed <= available else "")
        )


def gym_env_bytes(env_id: str) -> int:
    """The memory one instance of gymnasium env ``env_id`` is counted at (:data:`MUJOCO_ENV_BYTES`)."""
    import gymnasium as gym

    try:
        entry_point = gym.spec(env_id).entry_point
    except Exception:  # noqa: BLE001 - an id env_of accepted in a form gym.spec does not resolve here: count it as a plain env
        return GYM_ENV_BYTES
    return MUJOCO_ENV_BYTES if isinstance(entry_point, str) and entry_point.startswith("gymnasium.envs.mujoco") else GYM_ENV_BYTES


# ----------------------------------------------------------------------------------- env
def env_of(env_cfg: dict):
    name, env_id = env_cfg.get("name"), env_cfg.get("id")
    if name is not None and not isinstance(name, str):  # env.name=[a] from the command line: a name, never a list or a number
        raise ConfigError(f"env.name={shown_value(name)}: must be the name of an env config ({', '.join(BUILTIN_ENVS)}, gym, ...)")
    max_steps = env_cfg.get("max_steps")
    if max_steps is not None:
        max_steps = as_int(env_cfg, "max_steps", 1, label="env.max_steps")
    if not isinstance(env_id, str) or not env_id or env_id == "???":
        raise ConfigError(f"env.id={shown_value(env_id)}: give a gymnasium id, e.g. env.id=MountainCar-v0")
    if name in BUILTIN_ENVS and env_id == BUILTIN_ENVS[name]:
        return name, env_id, max_steps
    if name in BUILTIN_ENVS and max_steps is not None:
        _warn_kept_cap(name, env_id, max_steps)
    # A gymnasium id other than a built-in's: the generic (slower) path; the id names the run.
    import gymnasium as gym

    import imix_cli.core.envs  # noqa: F401  (registers the imix/ environments)
    from imix_cli.core.envs.ids import EnvIdError, import_user_env

    try:  # the user's own env as module:Id (gymnasium's convention): the user typed it, so its module is imported
        plain = import_user_env(env_id)
    except EnvIdError as err:
        raise ConfigError(str(err)) from None
    try:
        gym.spec(plain)
    except Exception as err:  # gymnasium raises several error types for unknown/deprecated ids
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        hint = "; your own env? give it as module:Id, e.g. env.id=myenvs:Reach1D-v0" if ":" not in env_id else ""
        raise ConfigError(f"env.id={shown_value(env_id)}: not a registered gymnasium environment ({reason}){hint}") from None
    from imix_cli.core.evaluation import missing_extra_message

    missing = missing_extra_message(plain)  # names imix's extra, before gymnasium's generic hint
    if missing:
        raise ConfigError(missing)
    _check_env_dependencies(plain)
    # The plain id names the run (folder, CSV); the full id is recorded, so that eval and render of
    # the run can tell which module the user must name to evaluate it.
    return plain, env_id, max_steps


#: gym.make's own keywords, which env.kwargs does not set: imix sets the episode cap (env.max_steps) and renders itself.
_MAKE_KEYWORDS = ("max_episode_steps", "render_mode", "autoreset", "apply_api_compatibility", "disable_env_checker")


def env_kwargs_of(env_cfg: dict, env_name: str, env_id: str) -> tuple:
    """``env.kwargs``: the gymnasium env's constructor arguments (``+env.kwargs.continuous=true``), checked against its
    constructor's signature before anything runs; returned as (key, value) pairs sorted by key (``()`` if none).

    ConfigError (one line naming the argument) for an argument the constructor does not take, one of gym.make's own
    keywords, a value that is not plain data, or any argument to a built-in (compiled) env. A constructor that takes
    ``**kwargs`` (the MuJoCo envs pass theirs on to MujocoEnv) is checked by making the env once (es_config)."""
    kwargs = env_cfg.get("kwargs")
    if kwargs is None:
        return ()
    if not isinstance(kwargs, dict):
        raise ConfigError(f"env.kwargs={shown_value(kwargs)}: must be a mapping of constructor arguments, e.g. +env.kwargs.continuous=true")
    if not kwargs:
        return ()
    if env_name in BUILTIN_ENVS:
        raise ConfigError(f"env.kwargs: env={env_name} is imix's compiled episode and takes no constructor arguments; "
                          f"give the gymnasium id instead (env=gym env.id={env_id} +env.kwargs.<name>=...)")  # fmt: skip
    for key, value in kwargs.items():
        if key in _MAKE_KEYWORDS:
            hint = " (the episode cap is env.max_steps)" if key == "max_episode_steps" else ""
            raise ConfigError(f"env.kwargs.{key}: gym.make's own keyword, not the env's constructor's{hint}")
        if not _plain(value):
            raise ConfigError(f"env.kwargs.{key}={shown_value(value)}: must be a number, string, bool, null or a list/mapping of them")
    accepted, open_ended = _constructor_arguments(env_id)
    if not open_ended:
        unknown = sorted(k for k in kwargs if k not in accepted)
        if unknown:
            shown = ", ".join(sorted(a for a in accepted if a not in _MAKE_KEYWORDS)) or "none"
            raise ConfigError(f"env.kwargs.{unknown[0]}: {env_id}'s constructor takes no argument {unknown[0]!r}; it takes: {shown}")
    return tuple(sorted(kwargs.items()))


def _plain(value) -> bool:
    if value is None or isinstance(value, (bool, int, float, str)):
        return True
    if isinstance(value, (list, tuple)):
        return all(map(_plain, value))
    if isinstance(value, dict):
        return all(isinstance(k, str) and _plain(v) for k, v in value.items())
    return False


def _constructor_arguments(env_id: str) -> tuple[set, bool]:
    """The keyword arguments ``env_id``'s constructor (its entry point) takes, and whether it takes any (``**kwargs``)."""
    import inspect

    import gymnasium as gym
    from gymnasium.envs.registration import load_env_creator

    entry_point = gym.spec(env_id).entry_point
    try:
        creator = load_env_creator(entry_point) if isinstance(entry_point, str) else entry_point
        parameters = inspect.signature(creator).parameters.values()
    except (TypeError, ValueError, ImportError, AttributeError):  # a builtin or C constructor: no signature to read
        return set(), True
    names = {p.name for p in parameters if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    return names, any(p.kind == p.VAR_KEYWORD for p in parameters)


_WARNED: set = set()


def _warn_kept_cap(name: str, env_id: str, max_steps: int) -> None:
    """``env=cartpole env.id=CartPole-v1``: the built-in config's episode cap stays (an explicit env.max_steps
    looks the same), which is not the id's own; say so once per process, and how to get the id's own cap."""
    import gymnasium as gym

    try:
        own = gym.spec(env_id).max_episode_steps
    except Exception:  # an unknown id is refused just after this, with its own message
        return
    if own is not None and own != max_steps and (name, env_id) not in _WARNED:
        _WARNED.add((name, env_id))
        from imix_cli.messages import warn

        warn(f"env={name} env.id={env_id}: episodes end at env.max_steps={max_steps} (env={name}'s cap), not at {env_id}'s own {own}; "
             f"for that, use env=gym env.id={env_id} (or env.max_steps={own})")  # fmt: skip


def _check_env_dependencies(env_id: str) -> None:
    """Import the env's module now, so a missing extra (Box2D, MuJoCo, ...) is one line before anything is written.

    gymnasium raises ``DependencyNotInstalled`` with its install hint when the module loads.
    """
    import gymnasium as gym
    from gymnasium.envs.registration import load_env_creator

    entry_point = gym.spec(env_id).entry_point
    if not isinstance(entry_point, str):
        return
    try:
        load_env_creator(entry_point)
    except gym.error.DependencyNotInstalled as err:
        raise ConfigError(f"env.id={shown_value(env_id)}: a dependency is missing: {first_line(err)}") from None
    except ImportError as err:
        raise ConfigError(f"env.id={shown_value(env_id)}: cannot import its module ({first_line(err)})") from None
