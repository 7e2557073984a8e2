"""Configuration: the one place that knows every key, validates it, and turns it into a RunSpec.

``imix run`` composes ``conf/config.yaml`` (+ the ``algo`` and ``env`` groups) with Hydra;
:func:`spec_from_config` then checks every value and returns an immutable :class:`RunSpec`
that the runner consumes. Errors are :class:`ConfigError` with a one-line message that names
the offending key; the CLI prints it and exits with status 2 before anything is written.

:func:`validate_overrides` does the same for a whole command line -- every point of a
``-m`` sweep -- before Hydra starts, so a bad value in the 10th sweep point is reported
before the first point runs.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
import os
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

from imix_cli.algorithms.base import WEIGHT_DECAY_FORMS, Params
from imix_cli.algorithms.cmaes import MAX_DIM as CMAES_CLASS_MAX_DIM
from imix_cli.algorithms.ddpg_settings import PAPER_SETTINGS
from imix_cli.registry import (
    ALGO_NAMES,
    ALGORITHM_SPECS,
    BUILTIN_ENVS,
    CONTINUOUS_BUILTIN_ENVS,
    EIM_VARIANTS,
    ENV_SPECS,
    IM_VARIANTS,
    MIXING_DEFAULTS,
)

#: The top-level keys that set an ES's :class:`~imix_cli.algorithms.base.Params`.
ES_PARAM_KEYS = ("popsize", "sigma", "lr", "weight_decay", "weight_decay_form")

#: The paper's setting (section 4.1): the defaults of :class:`~imix_cli.algorithms.base.Params`
#: and of the mixing schemes (:data:`imix_cli.registry.MIXING_DEFAULTS`). A run folder's name
#: carries, as ``-key=value,...``, the hyper-parameters that differ from these, so sweep points
#: get folders of their own.
PAPER_DEFAULTS = {**{key: getattr(Params, key) for key in ES_PARAM_KEYS}, **MIXING_DEFAULTS}


def algo_option_fields(algo: str) -> dict:
    """The ``algo.<key>`` options of an ES (conf/algo/<name>.yaml): key -> its field of the ES's Params."""
    spec = ALGORITHM_SPECS[algo]
    if not spec.options:
        return {}
    by_name = {f.name: f for f in dataclasses.fields(spec.es_class().Params)}
    return {key: by_name[key] for key in spec.options}


#: The settings of algo=ddpg (conf/algo/ddpg.yaml, paper section 4.3). A DDPG run folder's name
#: carries, as ``-key=value,...``, the ones that differ from these.
DDPG_DEFAULTS = PAPER_SETTINGS

#: Top-level keys of the evolution strategies only: algo=ddpg ignores them (and leaves them out
#: of its config.yaml, so they never make two DDPG runs differ). ``total_steps`` is ddpg's only.
ES_ONLY_KEYS = (
    "im", "eim", "im_variant", "eim_variant", "im_alpha", "eim_generations", "reeval_age", "reeval_prob",
    "generations", "popsize", "sigma", "lr", "weight_decay", "weight_decay_form", "checkpoint_every",
    "policy", "evaluator", "evaluator_workers", "ray_address",
)  # fmt: skip

#: Keys that do not change a run's results (everything else in config.yaml must match to resume).
NON_IDENTITY_KEYS = (
    "seeds", "workers", "progress", "results_dir", "experiment", "checkpoint_every",
    "evaluator", "evaluator_workers", "ray_address",  # where episodes run never changes their results
    "eval_mean_every", "eval_mean_episodes",  # measuring the distribution mean uses its own random stream
)  # fmt: skip

TOP_LEVEL_KEYS = (
    "algo", "env", "im", "eim", "im_variant", "eim_variant", "im_alpha", "eim_generations", "reeval_age",
    "reeval_prob", "seeds", "generations",
    "popsize", "sigma", "lr", "weight_decay", "weight_decay_form", "workers", "checkpoint_every",
    "progress", "results_dir", "experiment", "total_steps", "policy", "evaluator", "evaluator_workers", "ray_address",
    "eval_mean_every", "eval_mean_episodes",
)  # fmt: skip


#: Hydra launchers that run several jobs at once on one machine (or in Ray's workers): there a
#: per-job process pool must step aside (a spawn pool inside a joblib/loky worker dies), so
#: `workers` defaults to 1 under them and an explicit workers > 1 is refused.
PARALLEL_LAUNCHERS = {"JoblibLauncher": "joblib", "RayLauncher": "ray", "RayAWSLauncher": "ray_aws", "LocalLauncher": "submitit_local"}


def parallel_launcher_name(launcher_target: str | None) -> str | None:
    """The short name of a parallel launcher from its ``_target_`` class path, else None."""
    cls = (launcher_target or "").rsplit(".", 1)[-1]
    return PARALLEL_LAUNCHERS.get(cls)


def default_workers() -> int:
    """All cores this process may use (respects CPU affinity, e.g. a Slurm allocation)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


class ConfigError(ValueError):
    """A bad configuration value; ``str(err)`` is a one-line message naming the key."""


@dataclass(frozen=True)
class RunSpec:
    """Everything a run needs, validated. Built by :func:`spec_from_config`."""

    algo: str
    env_name: str  # config name ("cartpole", "acrobot") or the gymnasium id of a generic env
    env_id: str
    env_max_steps: int | None
    mixing: str  # none | im | eim
    variant: str | None  # mix() variant: paper | sun2009 | eim | eim_paper; None without mixing
    im_alpha: float
    eim_generations: int
    reeval_age: int | None  # re-evaluate a reused member whose return is older than this (None: never)
    reeval_prob: float  # ... and any reused member with this probability
    seeds: int
    generations: int
    popsize: int
    sigma: float
    lr: float
    weight_decay: float
    weight_decay_form: str
    workers: int
    checkpoint_every: int
    progress: bool
    results_dir: str
    experiment: str
    config: dict = field(repr=False, compare=False)  # the resolved config, written as config.yaml
    algo_options: dict = field(default_factory=dict, compare=False)  # per-ES options (algo.style of cem)
    # algo=ddpg only (the ES fields above then hold inert placeholders: generations 0, mixing none):
    total_steps: int | None = None  # environment steps of each seed
    ddpg: dict | None = field(default=None, compare=False)  # validated conf/algo/ddpg.yaml settings
    # The ES policy and where its episodes run (see _policy_and_evaluator):
    hidden: tuple = (8, 8)  # policy.hidden: tanh hidden layer sizes, () = linear
    obs_norm: bool = False  # policy.obs_norm: observation normalisation, frozen after the warm-up
    obs_norm_warmup: int = 0  # policy.obs_norm_warmup: generations of statistics (mixing off) before it freezes
    evaluator: str = "local"  # local | pool | ray (imix_cli.parallel_evaluation)
    evaluator_workers: int = 1  # processes (pool) or actors (ray)
    ray_address: str | None = None  # ray.init(address=...) for evaluator=ray
    # The return of the distribution mean theta (the policy one deploys), measured on
    # eval_mean_episodes fresh episodes every eval_mean_every generations (0: never); these episodes
    # are counted apart (CSV column mean_policy_episodes), never in evaluations or env_steps.
    eval_mean_every: int = 0
    eval_mean_episodes: int = 5

    @property
    def evaluator_key(self) -> str:
        """What :func:`imix_cli.evaluation.make_evaluator` takes: a built-in name or a gymnasium id."""
        return self.env_name if self.env_name in BUILTIN_ENVS else self.env_id

    @property
    def overrides_suffix(self) -> str:
        """``key=value,...`` for the hyper-parameters that differ from the paper's, and ``env.max_steps``
        if given (sorted). Other keys that change results (``generations``, ``algo.*``) do not name
        the folder: a sweep whose points would share one is refused up front (validate_overrides)."""
        # env.max_steps (default: the env's own cap) changes results too: it names the folder when set.
        if self.env_name in BUILTIN_ENVS:
            default_caps = {ENV_SPECS[self.env_name].max_steps}
        else:  # a gymnasium id (env=gym, or a config such as env=hopper): its own registered time limit
            default_caps = {None, _registered_cap(self.env_id)}
        cap = {} if self.env_max_steps in default_caps else {"env.max_steps": self.env_max_steps}
        if self.algo == "ddpg":
            changed = {k: v for k, v in (self.ddpg or {}).items() if k in DDPG_DEFAULTS and v != DDPG_DEFAULTS[k]}
            return ",".join(f"{k}={_format(v)}" for k, v in sorted({**changed, **cap}.items()))
        values = {
            "popsize": self.popsize, "sigma": self.sigma, "lr": self.lr, "weight_decay": self.weight_decay,
            "weight_decay_form": self.weight_decay_form,
        }  # fmt: skip
        if self.mixing == "im":
            values["im_variant"] = self.variant
            values["im_alpha"] = self.im_alpha
        if self.mixing == "eim":
            values["eim_generations"] = self.eim_generations
            values["eim_variant"] = next(k for k, v in EIM_VARIANTS.items() if v == self.variant)
        if self.mixing != "none":
            values["reeval_age"] = self.reeval_age
            values["reeval_prob"] = self.reeval_prob
        changed = {k: v for k, v in values.items() if v != PAPER_DEFAULTS[k]}
        defaults = {k: f.default for k, f in algo_option_fields(self.algo).items()}
        changed.update({f"algo.{k}": v for k, v in self.algo_options.items() if v != defaults.get(k)})
        if self.hidden != POLICY_DEFAULTS["hidden"]:
            changed["hidden"] = "x".join(map(str, self.hidden)) or "linear"
        if self.obs_norm:
            changed["obs_norm"] = self.obs_norm_warmup  # the warm-up in generations
        return ",".join(f"{k}={_format(v)}" for k, v in sorted({**changed, **cap}.items()))

    @property
    def run_name(self) -> str:
        from imix_cli.results import run_dir_name

        return run_dir_name(self.algo, self.env_name, self.mixing, self.overrides_suffix)

    @property
    def run_dir(self) -> Path:
        return Path(self.results_dir) / self.experiment / self.run_name

    def identity(self) -> dict:
        """The result-determining part of the config (compared with an existing config.yaml)."""
        return identity_of(self.config)

    def to_dict(self) -> dict:
        return asdict(self)


#: Keys in which a finished run may be continued: a larger value resumes each seed from its final
#: state (kept in its checkpoint), which gives exactly the run made with that value at once.
CONTINUABLE_KEYS = ("generations",)


def resume_identity(identity: dict) -> dict:
    """The part of an identity a run folder and its checkpoints must match to be resumed or continued."""
    return {k: v for k, v in identity.items() if k not in CONTINUABLE_KEYS}


def differing_keys(old: dict, new: dict) -> list[str]:
    """The keys whose values differ between two identities (a key missing on one side differs)."""
    return sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))


def identity_of(config: dict) -> dict:
    return {k: v for k, v in config.items() if k not in NON_IDENTITY_KEYS}


def _format(value) -> str:
    if isinstance(value, (list, tuple)):
        return "x".join(map(str, value))  # layer sizes: [16, 16] -> 16x16
    return repr(value) if isinstance(value, float) else str(value)


def _registered_cap(env_id: str) -> int | None:
    import gymnasium as gym

    try:
        return gym.spec(env_id).max_episode_steps
    except Exception:  # an id gymnasium cannot resolve has no cap of its own
        return None


# ---------------------------------------------------------------------------- validation helpers
def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _int(cfg: dict, key: str, minimum: int, label: str | None = None) -> int:
    value = cfg.get(key)
    label = label or key
    if not _is_number(value) or (isinstance(value, float) and not value.is_integer()):
        raise ConfigError(f"{label}={value!r}: must be an integer >= {minimum}")
    if value < minimum:
        raise ConfigError(f"{label}={value!r}: must be >= {minimum}")
    return int(value)


def _float(cfg: dict, key: str, low: float, low_inclusive: bool, high: float = math.inf, high_inclusive: bool = False) -> float:
    value = cfg.get(key)
    rule = f"{'>=' if low_inclusive else '>'} {low}" + ("" if high == math.inf else f" and {'<=' if high_inclusive else '<'} {high}")
    if not _is_number(value) or not math.isfinite(value):
        raise ConfigError(f"{key}={value!r}: must be a number {rule}")
    ok_low = value >= low if low_inclusive else value > low
    ok_high = value <= high if high_inclusive else value < high
    if not (ok_low and ok_high):
        raise ConfigError(f"{key}={value!r}: must be {rule}")
    return float(value)


def _bool(cfg: dict, key: str) -> bool:
    value = cfg.get(key)
    if not isinstance(value, bool):
        raise ConfigError(f"{key}={value!r}: must be true or false")
    return value


def _choice(value, key: str, choices) -> str:
    if value not in choices:
        raise ConfigError(f"{key}={value!r}: valid choices are {', '.join(choices)}")
    return value


def _name(cfg: dict, key: str) -> str:
    value = cfg.get(key)
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{key}={value!r}: must be a non-empty name")
    return value


def spec_from_config(cfg: dict, launcher: str | None = None) -> RunSpec:
    """Validate a resolved config (a plain dict, as Hydra composes it) and build the RunSpec.

    ``launcher`` is the Hydra launcher's ``_target_``: under a launcher that runs jobs in
    parallel, each job's seeds run in-process (``workers`` 1).
    """
    unknown = sorted(set(cfg) - set(TOP_LEVEL_KEYS))
    if unknown:
        raise ConfigError(f"unknown key {unknown[0]!r}; valid keys: {', '.join(TOP_LEVEL_KEYS)}")
    algo_cfg, env_cfg = cfg.get("algo") or {}, cfg.get("env") or {}
    algo = _choice(algo_cfg.get("name"), "algo", ALGO_NAMES)
    if algo == "ddpg":
        return _ddpg_spec(cfg, algo_cfg, env_cfg, launcher)
    im, eim = _bool(cfg, "im"), _bool(cfg, "eim")
    im_variant = _choice(cfg.get("im_variant"), "im_variant", IM_VARIANTS)
    eim_variant = _choice(cfg.get("eim_variant", PAPER_DEFAULTS["eim_variant"]), "eim_variant", tuple(EIM_VARIANTS))
    reeval_age = cfg.get("reeval_age")
    if reeval_age is not None:
        reeval_age = _int(cfg, "reeval_age", 1)
    reeval_prob = _float(cfg, "reeval_prob", 0.0, True, 1.0, False)
    algo_options = _algo_options(algo, algo_cfg)
    im_alpha = _float(cfg, "im_alpha", 0.0, True, 1.0, False)
    eim_generations = _int(cfg, "eim_generations", 1)
    if eim and im_variant != "paper":
        raise ConfigError(f"im_variant={im_variant}: applies to im=true only; with eim=true choose eim_variant=exact|paper")
    if im_alpha != 0.0 and not (im and not eim and im_variant == "sun2009"):
        raise ConfigError(f"im_alpha={im_alpha}: only applies with im=true im_variant=sun2009")
    mixing = "eim" if eim else ("im" if im else "none")
    variant = EIM_VARIANTS[eim_variant] if eim else (im_variant if im else None)
    if mixing == "none" and (reeval_age is not None or reeval_prob):
        raise ConfigError("reeval_age/reeval_prob: only apply with im=true or eim=true (they re-evaluate reused members)")

    env_name, env_id, max_steps = _env(env_cfg)
    policy = _policy_and_evaluator(cfg, algo, env_name, env_id, max_steps, launcher)
    workers, experiment = _workers_and_experiment(cfg, launcher, pool=policy["evaluator"] == "pool")
    config = {k: v for k, v in cfg.items() if k != "total_steps"}  # total_steps: ddpg's budget only
    popsize, sigma = _int(cfg, "popsize", 2), _float(cfg, "sigma", 0.0, False)
    if algo == "cmaes" and popsize < 3:
        raise ConfigError(f"popsize={popsize}: algo=cmaes needs popsize >= 3 (its recombination weights need at least 2 parents and one non-parent)")
    if not math.isfinite(sigma * sigma):
        raise ConfigError(f"sigma={sigma!r}: the initial variance sigma^2 overflows float64; must be < 1e154")
    _policy_size(env_name, env_id, max_steps)  # an env imix cannot evaluate: one line
    num_params = _policy_dim(env_name, env_id, max_steps, policy["hidden"])
    _check_memory(popsize, num_params, eim_generations if eim else (1 if im else 0))
    seeds = _seeds(cfg)
    if policy["stored"] is None:
        config.pop("policy", None)  # the default policy: config.yaml stays as it was before the key existed
    else:
        config["policy"] = policy["stored"]
    return RunSpec(
        algo=algo,
        env_name=env_name,
        env_id=env_id,
        env_max_steps=max_steps,
        mixing=mixing,
        variant=variant,
        im_alpha=im_alpha,
        eim_generations=eim_generations,
        reeval_age=reeval_age,
        reeval_prob=reeval_prob,
        seeds=seeds,
        generations=_int(cfg, "generations", 1),
        popsize=popsize,
        sigma=sigma,
        lr=_float(cfg, "lr", 0.0, False),
        weight_decay=_float(cfg, "weight_decay", 0.0, True),
        weight_decay_form=_choice(cfg.get("weight_decay_form"), "weight_decay_form", tuple(WEIGHT_DECAY_FORMS)),
        workers=workers,
        checkpoint_every=_int(cfg, "checkpoint_every", 0),
        eval_mean_every=_int(cfg, "eval_mean_every", 0) if "eval_mean_every" in cfg else 0,
        eval_mean_episodes=_int(cfg, "eval_mean_episodes", 1) if "eval_mean_episodes" in cfg else 5,
        progress=_bool(cfg, "progress"),
        results_dir=_name(cfg, "results_dir"),
        experiment=experiment,
        config={**config, "mixing": mixing},
        algo_options=algo_options,
        hidden=policy["hidden"],
        obs_norm=policy["obs_norm"],
        obs_norm_warmup=policy["obs_norm_warmup"],
        evaluator=policy["evaluator"],
        evaluator_workers=policy["evaluator_workers"],
        ray_address=policy["ray_address"],
    )


def _algo_options(algo: str, algo_cfg: dict) -> dict:
    """The validated ``algo.<key>`` options of an ES (:func:`algo_option_fields`), defaults filled in."""
    options = {}
    for key, f in algo_option_fields(algo).items():
        value = algo_cfg.get(key, f.default)
        if "choices" in f.metadata:
            _choice(value, f"algo.{key}", f.metadata["choices"])
        options[key] = value
    try:
        ALGORITHM_SPECS[algo].es_class().Params(**options)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"algo={algo}: {_first_line(err)}") from None
    return options


#: The largest ``seeds``: one CSV (and one progress line of work) per seed; beyond this a run is
#: a mistake (``seeds=1e9`` would spend minutes listing files before the first generation).
MAX_SEEDS = 100_000


def _seeds(cfg: dict) -> int:
    seeds = _int(cfg, "seeds", 1)
    if seeds > MAX_SEEDS:
        raise ConfigError(f"seeds={seeds}: at most {MAX_SEEDS:,} seeds per run (one CSV per seed); split the work into experiments")
    return seeds


def _policy_size(env_name: str, env_id: str, max_steps: int | None) -> int:
    """The number of policy parameters d of an env; ConfigError for an env imix cannot evaluate."""
    try:
        return _evaluator_shape(env_name if env_name in BUILTIN_ENVS else env_id, max_steps)
    except ValueError as err:
        key = "env" if env_name in BUILTIN_ENVS else "env.id"
        value = env_name if env_name in BUILTIN_ENVS else env_id
        raise ConfigError(f"{key}={value!r}: {_first_line(err).replace(repr(value) + ': ', '').replace(repr(value) + ' ', '')}") from None


_EVALUATOR_SHAPES: dict = {}


def _evaluator_shape(key: str, max_steps: int | None) -> int:
    """make_evaluator(key).num_params, cached per process (a sweep asks once per env, not per point)."""
    if (key, max_steps) not in _EVALUATOR_SHAPES:
        from imix_cli.evaluation import make_evaluator

        try:
            _EVALUATOR_SHAPES[key, max_steps] = make_evaluator(key, max_steps).num_params
        except ValueError as err:
            _EVALUATOR_SHAPES[key, max_steps] = err
    shape = _EVALUATOR_SHAPES[key, max_steps]
    if isinstance(shape, Exception):
        raise shape
    return shape


def _check_memory(popsize: int, num_params: int, archive_depth: int) -> None:
    """Refuse a population whose arrays cannot fit in this machine's memory.

    A generation holds popsize x d float64 numbers about (archive depth + 3) times over
    (samples, the archive, mixing's and the evaluator's temporaries).
    """
    needed = 8 * popsize * (num_params + 16) * (archive_depth + 3)
    try:
        available = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # not on Linux: no check
        return
    if needed > available:
        raise ConfigError(
            f"popsize={popsize}: a population of {popsize:,} x {num_params} parameters needs ~{needed / 2**30:,.1f} GiB, "
            f"more than this machine's {available / 2**30:,.1f} GiB"
        )


def _workers_and_experiment(cfg: dict, launcher: str | None, pool: bool = False) -> tuple[int, str]:
    workers, parallel = cfg.get("workers"), parallel_launcher_name(launcher)
    if workers is None:
        workers = 1 if parallel or pool else default_workers()
    else:
        workers = _int(cfg, "workers", 1)
        if parallel and workers > 1:
            raise ConfigError(f"workers={workers}: hydra/launcher={parallel} already runs jobs in parallel; use workers=1 (or leave it null)")
        if pool and workers > 1:
            raise ConfigError(
                f"workers={workers}: evaluator=pool already spreads each generation over evaluator_workers processes; use workers=1 (or leave it null)"
            )
    experiment = _name(cfg, "experiment")
    if "/" in experiment or "\\" in experiment or experiment in (".", ".."):
        raise ConfigError(f"experiment={experiment!r}: must be a plain folder name (no path separators)")
    return workers, experiment


# ------------------------------------------------------------------ policy and evaluator keys
#: ``policy.*`` defaults (conf/config.yaml): the paper's 8x8 tanh MLP without normalisation.
POLICY_DEFAULTS = {"hidden": (8, 8), "obs_norm": False, "obs_norm_warmup": 5}
EVALUATORS = ("local", "pool", "ray")
#: CMA-ES keeps a d x d covariance and eigendecomposes it (O(d^2) memory, O(d^3) time): above
#: this many parameters imix refuses it before anything runs (the CMAES class's own limit).
CMAES_MAX_DIM = CMAES_CLASS_MAX_DIM


def _policy_and_evaluator(cfg: dict, algo: str, env_name: str, env_id: str, max_steps, launcher: str | None) -> dict:
    """Validate ``policy.*``, ``evaluator``, ``evaluator_workers``, ``ray_address``; refuse CMA-ES at large d."""
    policy = cfg.get("policy")
    policy = {} if policy is None else policy
    if not isinstance(policy, dict):
        raise ConfigError(f"policy={policy!r}: must be a mapping with keys hidden, obs_norm, obs_norm_warmup")
    unknown = sorted(set(policy) - set(POLICY_DEFAULTS))
    if unknown:
        raise ConfigError(f"unknown key 'policy.{unknown[0]}'; valid policy keys: {', '.join(POLICY_DEFAULTS)}")
    hidden = policy.get("hidden", list(POLICY_DEFAULTS["hidden"]))
    if not isinstance(hidden, (list, tuple)) or not all(_is_number(h) and float(h).is_integer() and h >= 1 for h in hidden):
        raise ConfigError(f"policy.hidden={hidden!r}: must be a list of layer sizes >= 1, e.g. [64,64], or [] for a linear policy")
    hidden = tuple(int(h) for h in hidden)
    p = {f"policy.{k}": policy.get(k, v) for k, v in POLICY_DEFAULTS.items()}
    obs_norm = _bool(p, "policy.obs_norm")
    warmup = _int(p, "policy.obs_norm_warmup", 1)
    if obs_norm and env_name in BUILTIN_ENVS:
        raise ConfigError(f"policy.obs_norm=true: only on gymnasium environments (env=gym or a MuJoCo env), not the built-in env={env_name}")
    evaluator = _choice(cfg.get("evaluator", "local"), "evaluator", EVALUATORS)
    n_workers = cfg.get("evaluator_workers")
    if n_workers is not None:
        n_workers = _int(cfg, "evaluator_workers", 1)
    elif evaluator == "pool":
        n_workers = default_workers()
    address = cfg.get("ray_address")
    if address is not None and (not isinstance(address, str) or not address.strip()):
        raise ConfigError(f"ray_address={address!r}: must be an address such as auto or ray://host:10001 (or null: a local Ray)")
    if address is not None and evaluator != "ray":
        raise ConfigError(f"ray_address={address}: only used with evaluator=ray")
    if evaluator == "pool" and parallel_launcher_name(launcher):
        raise ConfigError(f"evaluator=pool: hydra/launcher={parallel_launcher_name(launcher)} already runs jobs in parallel; use evaluator=local")
    if evaluator == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ConfigError('evaluator=ray: ray is not installed; pip install "imix-cli[cluster]"') from None
    if algo == "cmaes":
        dim = _policy_dim(env_name, env_id, max_steps, hidden)
        if dim > CMAES_MAX_DIM:
            raise ConfigError(
                f"algo=cmaes: the {'x'.join(map(str, hidden)) or 'linear'} policy on {env_id} has {dim} parameters, more than "
                f"CMA-ES's limit of {CMAES_MAX_DIM} (O(d^2) memory, O(d^3) time); use algo=snes or algo=openes (diagonal), or a smaller policy.hidden"
            )
    default = hidden == POLICY_DEFAULTS["hidden"] and not obs_norm
    stored = None if default else {"hidden": list(hidden), "obs_norm": obs_norm, "obs_norm_warmup": warmup if obs_norm else None}
    return {
        "hidden": hidden, "obs_norm": obs_norm, "obs_norm_warmup": warmup if obs_norm else 0, "evaluator": evaluator,
        "evaluator_workers": n_workers or 1, "ray_address": address, "stored": stored,
    }  # fmt: skip


def _policy_dim(env_name: str, env_id: str, max_steps, hidden: tuple) -> int:
    """Number of policy parameters on this env (a gymnasium env is made once to read its spaces)."""
    from imix_cli.policies import num_params

    if env_name in BUILTIN_ENVS:  # their observation and output sizes are known without making the env
        return num_params(*ENV_SPECS[env_name].policy_dims, hidden)
    import gymnasium as gym

    try:
        probe = gym.make(env_id, **({} if max_steps is None else {"max_episode_steps": max_steps}))
    except Exception as err:
        raise ConfigError(f"env.id={env_id!r}: cannot be made ({_first_line(err)})") from None
    try:
        obs_space, act_space = probe.observation_space, probe.action_space
    finally:
        probe.close()
    out = int(act_space.n) if isinstance(act_space, gym.spaces.Discrete) else math.prod(act_space.shape or (1,))
    return num_params(math.prod(obs_space.shape or (1,)), out, hidden)


# ------------------------------------------------------------------------------ algo=ddpg
def _ddpg_spec(cfg: dict, algo_cfg: dict, env_cfg: dict, launcher: str | None) -> RunSpec:
    """algo=ddpg: ES keys are ignored; ``total_steps`` (null: the algo's per-env default) is the budget."""
    env_name, env_id, max_steps = _env(env_cfg)
    episode_cap = _continuous_env_cap(env_name, env_id, max_steps)
    settings = _ddpg_settings(algo_cfg)
    total = cfg.get("total_steps")
    if total is None:
        defaults = algo_cfg.get("default_total_steps") or {}
        total = defaults.get(env_name) if isinstance(defaults, dict) else None
        if total is None:
            raise ConfigError(f"total_steps=null: algo=ddpg has no default budget for env {env_name!r}; give total_steps=<environment steps>")
        total = _int({"algo.default_total_steps": total}, "algo.default_total_steps", 1, label=f"algo.default_total_steps.{env_name}")
    else:
        total = _int(cfg, "total_steps", 1)
    if total < episode_cap:
        raise ConfigError(f"total_steps={total}: must be >= the episode cap of {episode_cap} steps, so that every seed finishes an episode")
    workers, experiment = _workers_and_experiment(cfg, launcher)
    algo_stored = {k: v for k, v in algo_cfg.items() if k not in ("generations", "default_total_steps")}
    config = {k: v for k, v in cfg.items() if k not in ES_ONLY_KEYS}
    config.update(algo=algo_stored, total_steps=total, mixing="none")
    return RunSpec(
        algo="ddpg",
        env_name=env_name,
        env_id=env_id,
        env_max_steps=max_steps,
        mixing="none",
        variant=None,
        im_alpha=PAPER_DEFAULTS["im_alpha"],
        eim_generations=PAPER_DEFAULTS["eim_generations"],
        reeval_age=None,
        reeval_prob=0.0,
        seeds=_seeds(cfg),
        generations=0,
        popsize=PAPER_DEFAULTS["popsize"],
        sigma=PAPER_DEFAULTS["sigma"],
        lr=PAPER_DEFAULTS["lr"],
        weight_decay=PAPER_DEFAULTS["weight_decay"],
        weight_decay_form=PAPER_DEFAULTS["weight_decay_form"],
        workers=workers,
        checkpoint_every=0,
        progress=_bool(cfg, "progress"),
        results_dir=_name(cfg, "results_dir"),
        experiment=experiment,
        config=config,
        total_steps=total,
        ddpg=settings,
    )


def _continuous_env_cap(env_name: str, env_id: str, max_steps: int | None) -> int:
    """The episode length cap of a continuous-action env; ConfigError for a discrete one."""
    if env_name in BUILTIN_ENVS:
        if env_name not in CONTINUOUS_BUILTIN_ENVS:
            choices = " or env=".join(CONTINUOUS_BUILTIN_ENVS)
            raise ConfigError(f"env={env_name}: algo=ddpg needs continuous actions; use env={choices} (or env=gym env.id=<a Box-action id>)")
        return max_steps or ENV_SPECS[env_name].max_steps
    import gymnasium as gym

    try:
        probe = gym.make(env_id)
    except Exception as err:
        raise ConfigError(f"env.id={env_id!r}: cannot be made ({_first_line(err)})") from None
    try:
        box = isinstance(probe.action_space, gym.spaces.Box)
    finally:
        probe.close()
    if not box:
        raise ConfigError(f"env.id={env_id!r}: algo=ddpg needs continuous (Box) actions, the env has {type(probe.action_space).__name__} actions")
    cap = max_steps or gym.spec(env_id).max_episode_steps
    if cap is None:
        raise ConfigError(f"env.id={env_id!r} has no time limit: give env.max_steps for algo=ddpg")
    return int(cap)


def _ddpg_settings(algo_cfg: dict) -> dict:
    """The validated DDPG settings (``algo.*`` keys of conf/algo/ddpg.yaml)."""
    a = {f"algo.{k}": v for k, v in algo_cfg.items()}
    out = {}
    for key in ("actor_arch", "critic_arch"):
        value = algo_cfg.get(key)
        if not isinstance(value, (list, tuple)) or not value or not all(_is_number(v) and float(v).is_integer() and v >= 1 for v in value):
            raise ConfigError(f"algo.{key}={value!r}: must be a non-empty list of layer sizes >= 1, e.g. [8,8]")
        out[key] = [int(v) for v in value]
    for key in ("actor_lr", "critic_lr", "ou_dt"):
        out[key] = _float(a, f"algo.{key}", 0.0, False)
    out["tau"] = _float(a, "algo.tau", 0.0, False, 1.0, True)
    out["gamma"] = _float(a, "algo.gamma", 0.0, True, 1.0, True)
    out["ou_sigma"] = _float(a, "algo.ou_sigma", 0.0, True)
    out["ou_theta"] = _float(a, "algo.ou_theta", 0.0, True)
    for key, minimum in (("batch_size", 1), ("buffer_size", 1), ("learning_starts", 0), ("train_freq", 1), ("gradient_steps", 1)):
        out[key] = _int(a, f"algo.{key}", minimum)
    return out


def _env(env_cfg: dict):
    name, env_id = env_cfg.get("name"), env_cfg.get("id")
    max_steps = env_cfg.get("max_steps")
    if max_steps is not None:
        max_steps = _int(env_cfg, "max_steps", 1, label="env.max_steps")
    if not isinstance(env_id, str) or not env_id or env_id == "???":
        raise ConfigError(f"env.id={env_id!r}: give a gymnasium id, e.g. env.id=MountainCar-v0")
    if name in BUILTIN_ENVS and env_id == BUILTIN_ENVS[name]:
        return name, env_id, max_steps
    # A gymnasium id other than a built-in's: the generic (slower) path; the id names the run.
    import gymnasium as gym

    import imix_cli.envs  # noqa: F401  (registers the imix/ environments)

    try:
        gym.spec(env_id)
    except Exception as err:  # gymnasium raises several error types for unknown/deprecated ids
        reason = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ConfigError(f"env.id={env_id!r}: not a registered gymnasium environment ({reason})") from None
    from imix_cli.evaluation import missing_extra_message

    missing = missing_extra_message(env_id)  # names imix's extra, before gymnasium's generic hint
    if missing:
        raise ConfigError(missing)
    _check_env_dependencies(env_id)
    return env_id, env_id, max_steps


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
        raise ConfigError(f"env.id={env_id!r}: a dependency is missing: {_first_line(err)}") from None
    except ImportError as err:
        raise ConfigError(f"env.id={env_id!r}: cannot import its module ({_first_line(err)})") from None


# ------------------------------------------------------------------- whole command-line checks
def config_dir() -> str:
    """Where the Hydra configs are: the installed package ``imix_cli.conf`` or, in a source tree, ``conf/``."""
    import importlib.util

    spec = importlib.util.find_spec("imix_cli.conf")
    if spec is not None and spec.submodule_search_locations:
        return str(Path(list(spec.submodule_search_locations)[0]).resolve())
    return str((Path(__file__).resolve().parent.parent / "conf").resolve())


def group_options(group: str) -> list[str]:
    return sorted(p.stem for p in (Path(config_dir()) / group).glob("*.yaml"))


def validate_overrides(overrides: list[str]) -> list[RunSpec]:
    """Compose and validate the config of every point of a (possibly multirun) command line.

    Raises ConfigError (one line) on the first problem, or when two points would share a run
    folder with different configs (the second would be refused halfway through the sweep).
    Every point is checked: sweeps (``a,b``, ``range(...)``, ``glob(...)`` over ``algo``/``env``)
    are expanded here. Hydra composes the config once per combination of config-group choices
    (``algo``, ``env``, ``hydra/...``) and of ``+``/``~`` overrides; each point's plain
    ``key=value`` overrides are then applied to a copy by Hydra's own override function, so a
    point costs milliseconds instead of a full composition.
    """
    from hydra import compose, initialize_config_dir
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import Glob
    from omegaconf import OmegaConf, open_dict

    parser = OverridesParser.create()
    try:
        parsed = parser.parse_overrides(overrides)
    except Exception as err:
        raise ConfigError(f"cannot parse overrides: {_first_line(err)}") from None
    choices = []
    for override in parsed:
        key = override.key_or_group
        if override.is_sweep_override():
            if isinstance(override.value(), Glob):
                if key not in ("algo", "env"):
                    raise ConfigError(f"{override.input_line}: glob() selects options of the config groups algo and env only")
                values = override.value().filter(group_options(key))
                if not values:
                    raise ConfigError(f"{override.input_line}: matches no {key}; valid choices are {', '.join(group_options(key))}")
            else:
                values = list(override.sweep_string_iterator())
            choices.append([f"{override.get_key_element()}={v}" for v in values])
        else:
            choices.append([override.input_line])
        if key in ("algo", "env"):
            valid = group_options(key)
            for line in choices[-1]:
                value = line.split("=", 1)[1]
                if value not in valid:
                    raise ConfigError(f"{key}={value}: unknown {key}; valid choices are {', '.join(valid)}")
    parse_cache: dict = {}

    def parse_one(line: str):
        if line not in parse_cache:
            try:
                parse_cache[line] = parser.parse_overrides([line])[0]
            except Exception as err:
                raise ConfigError(f"cannot parse overrides: {_first_line(err)}") from None
        return parse_cache[line]

    specs, composed = [], {}
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=config_dir(), version_base="1.3"):
            for point in itertools.product(*choices):
                parsed_point = [parse_one(line) for line in point]
                values = [o for o in parsed_point if _is_value_override(o)]
                base = tuple(line for line, o in zip(point, parsed_point, strict=True) if not _is_value_override(o))
                try:
                    if base not in composed:  # hydra.* overrides are in base: the hydra node is done with
                        full = compose("config", overrides=list(base), return_hydra_config=True)
                        launcher = OmegaConf.select(full, "hydra.launcher._target_")
                        with open_dict(full):
                            del full["hydra"]
                        composed[base] = (full, launcher)
                    cfg, launcher = copy.deepcopy(composed[base][0]), composed[base][1]
                    ConfigLoaderImpl._apply_overrides_to_config(values, cfg)
                    plain = OmegaConf.to_container(cfg, resolve=True)
                except Exception as err:
                    raise ConfigError(_explain_compose_error(err, point)) from None
                specs.append(spec_from_config(plain, launcher))
    finally:
        GlobalHydra.instance().clear()
    _refuse_shared_folders(specs)
    return specs


def _is_value_override(override) -> bool:
    """A plain ``key=value`` of a config value (not a config group, not ``+``/``~``/``++``)."""
    key = override.key_or_group
    return (
        override.package is None and not override.is_add() and not override.is_delete() and not override.is_force_add()
        and "/" not in key and key not in ("algo", "env", "hydra") and not key.startswith("hydra.")
    )  # fmt: skip


def _refuse_shared_folders(specs: list[RunSpec]) -> None:
    """ConfigError if two points would write one run folder with different configs."""
    first: dict[Path, RunSpec] = {}
    for spec in specs:
        other = first.setdefault(spec.run_dir, spec)
        old, new = other.identity(), spec.identity()
        differing = differing_keys(old, new)
        if differing:
            changes = ", ".join(f"{k}={old.get(k)!r} / {new.get(k)!r}" for k in differing)
            raise ConfigError(
                f"two sweep points would share the folder {spec.run_dir} but differ in {changes}; "
                "sweep that key in separate commands with their own experiment="
            )


def _first_line(err: Exception) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def _explain_compose_error(err: Exception, point) -> str:
    text = str(err)
    if "not in struct" in text or "Could not override" in text or "Key '" in text and "is not in struct" in text:
        bad = next((p.split("=", 1)[0].lstrip("+~") for p in point if p.split("=", 1)[0].lstrip("+~") in text), None)
        key = bad or _first_line(err)
        return f"unknown key {key!r}; valid keys: {', '.join(TOP_LEVEL_KEYS)} (and algo.*, env.*, hydra.*)"
    missing = re.search(r"Could not find '([^']+)/([^'/]+)'", text)
    if missing:  # a config group option that does not exist, e.g. hydra/launcher=nope
        group, option = missing.groups()
        return f"{group}={option}: no such option in config group {group!r}"
    return f"bad override ({', '.join(point)}): {_first_line(err)}"
