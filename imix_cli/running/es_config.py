"""An evolution strategy's config: mixing, the ES's hyper-parameters and ``algo.*`` options, the policy and the evaluator.

Besides each key's own check, a run the machine cannot hold is refused here: CMA-ES above
:data:`imix_cli.algorithms.cmaes.MAX_DIM` parameters, a population whose arrays exceed the memory, an env imix
cannot evaluate.
"""

from __future__ import annotations

import math

from imix_cli.algorithms import cmaes
from imix_cli.algorithms.base import PARAM_BOUNDS, WEIGHT_DECAY_FORMS
from imix_cli.generation import MIXING_BOUNDS
from imix_cli.mixing import config_variants, variant_spec
from imix_cli.processes import default_workers
from imix_cli.registry import ALGORITHM_SPECS, BUILTIN_ENVS, ENV_SPECS
from imix_cli.running.config_checks import (
    ConfigError,
    as_bool,
    as_bounded,
    as_choice,
    as_float,
    as_int,
    as_name,
    check_memory,
    env_of,
    first_line,
    gym_env_bytes,
    is_number,
    parallel_launcher_name,
    seeds_of,
    workers_and_experiment,
)
from imix_cli.running.run_spec import PAPER_DEFAULTS, POLICY_DEFAULTS, RunSpec, algo_option_fields, resolve_auto_options


def es_spec(cfg: dict, algo: str, algo_cfg: dict, env_cfg: dict, launcher: str | None) -> RunSpec:
    """The RunSpec of an evolution strategy: mixing, the ES's hyper-parameters, its policy and evaluator."""
    im, eim = as_bool(cfg, "im"), as_bool(cfg, "eim")
    im_variants, eim_variants = config_variants("im"), config_variants("eim")
    im_variant = as_choice(cfg.get("im_variant"), "im_variant", tuple(im_variants))
    eim_variant = as_choice(cfg.get("eim_variant", PAPER_DEFAULTS["eim_variant"]), "eim_variant", tuple(eim_variants))
    reeval_age = cfg.get("reeval_age")
    if reeval_age is not None:
        reeval_age = as_bounded(cfg, "reeval_age", MIXING_BOUNDS["reeval_age"])
    reeval_prob = as_bounded(cfg, "reeval_prob", MIXING_BOUNDS["reeval_prob"])
    reeval_count = as_bounded(cfg, "reeval_count", MIXING_BOUNDS["reeval_count"])
    algo_options = _algo_options(algo, algo_cfg)
    im_alpha = as_bounded(cfg, "im_alpha", MIXING_BOUNDS["alpha"])
    eim_generations = as_bounded(cfg, "eim_generations", MIXING_BOUNDS["eim_generations"])
    min_fresh = as_bounded(cfg, "min_fresh", MIXING_BOUNDS["min_fresh"])
    if eim and im_variant != PAPER_DEFAULTS["im_variant"]:
        raise ConfigError(f"im_variant={im_variant}: applies to im=true only; with eim=true choose eim_variant={'|'.join(eim_variants)}")
    mixing = "eim" if eim else ("im" if im else "none")
    algo_options = resolve_auto_options(algo, algo_options, mixing != "none")
    variant = eim_variants[eim_variant].name if eim else (im_variants[im_variant].name if im else None)
    if im_alpha != 0.0 and not (variant is not None and variant_spec(variant).uses_alpha):
        raise ConfigError(f"im_alpha={im_alpha}: only applies with im=true im_variant=sun2009")
    if mixing == "none" and min_fresh != PAPER_DEFAULTS["min_fresh"]:
        raise ConfigError(f"min_fresh={min_fresh}: only applies with im=true or eim=true (fresh members of a mixed generation)")
    if mixing == "none" and (reeval_age is not None or reeval_prob or reeval_count):
        raise ConfigError("reeval_age/reeval_prob/reeval_count: only apply with im=true or eim=true (they re-evaluate reused members)")

    env_name, env_id, max_steps = env_of(env_cfg)
    policy = _policy_and_evaluator(cfg, algo, env_name, env_id, max_steps, launcher)
    # evaluator=ray: the seeds run in the main process, which alone drives the run's one Ray runtime
    # (seed processes each started a Ray of their own, each sized to every CPU).
    spreading = policy["evaluator"] if policy["evaluator"] in ("pool", "ray") else None
    workers, experiment = workers_and_experiment(cfg, launcher, pool=spreading)
    if cfg.get("total_steps") is not None:  # silently running `generations` instead would waste the user's budget
        raise ConfigError(
            f"total_steps={cfg['total_steps']!r}: algo=ddpg's budget (environment steps); an evolution strategy (algo={algo}) runs generations= instead"
        )
    config = {k: v for k, v in cfg.items() if k != "total_steps"}  # total_steps: ddpg's budget only
    popsize, sigma = as_bounded(cfg, "popsize", PARAM_BOUNDS["popsize"]), as_bounded(cfg, "sigma", PARAM_BOUNDS["sigma"])
    if algo == "cmaes" and popsize < cmaes.MIN_POPSIZE:
        raise ConfigError(
            f"popsize={popsize}: algo=cmaes needs popsize >= {cmaes.MIN_POPSIZE} (its recombination weights need at least 2 parents and one non-parent)"
        )
    if mixing != "none" and min_fresh > popsize:
        raise ConfigError(f"min_fresh={min_fresh}: more than popsize={popsize} members")
    if not math.isfinite(sigma * sigma):
        raise ConfigError(f"sigma={sigma!r}: the initial variance sigma^2 overflows float64; must be < 1e154")
    _check_params_together(algo, popsize, algo_options)
    _policy_size(env_name, env_id, max_steps)  # an env imix cannot evaluate: one line
    num_params = _policy_dim(env_name, env_id, max_steps, policy["hidden"], policy["bias"], policy["output"])
    if algo == "cmaes" and num_params > cmaes.MAX_DIM:
        raise ConfigError(
            f"algo=cmaes: the {'x'.join(map(str, policy['hidden'])) or 'linear'} policy on {env_id} has {num_params} parameters, more than "
            f"CMA-ES's limit of {cmaes.MAX_DIM} (O(d^2) memory, O(d^3) time); use algo=snes or algo=openes (diagonal), or a smaller policy.hidden"
        )
    seeds = seeds_of(cfg)
    env_bytes = 0 if env_name in BUILTIN_ENVS else gym_env_bytes(env_id)  # the built-ins are compiled: no env objects
    archive_depth = 0 if variant is None else variant_spec(variant).depth(eim_generations)
    check_memory(popsize, num_params, archive_depth, seeds, env_bytes, env_id)
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
        min_fresh=min_fresh,
        reeval_age=reeval_age,
        reeval_prob=reeval_prob,
        reeval_count=reeval_count,
        seeds=seeds,
        generations=as_int(cfg, "generations", 1),
        popsize=popsize,
        sigma=sigma,
        lr=as_bounded(cfg, "lr", PARAM_BOUNDS["lr"]),
        weight_decay=as_bounded(cfg, "weight_decay", PARAM_BOUNDS["weight_decay"]),
        weight_decay_form=as_choice(cfg.get("weight_decay_form"), "weight_decay_form", tuple(WEIGHT_DECAY_FORMS)),
        workers=workers,
        checkpoint_every=as_int(cfg, "checkpoint_every", 0),
        checkpoint_seconds=as_float(cfg, "checkpoint_seconds", 0.0, True) if "checkpoint_seconds" in cfg else 0.0,
        eval_mean_every=as_int(cfg, "eval_mean_every", 0) if "eval_mean_every" in cfg else 0,
        eval_mean_episodes=as_int(cfg, "eval_mean_episodes", 1) if "eval_mean_episodes" in cfg else 5,
        progress=as_bool(cfg, "progress"),
        results_dir=as_name(cfg, "results_dir"),
        experiment=experiment,
        config={**config, "mixing": mixing},
        algo_options=algo_options,
        hidden=policy["hidden"],
        obs_norm=policy["obs_norm"],
        obs_norm_warmup=policy["obs_norm_warmup"],
        obs_var_floor=policy["obs_var_floor"],
        policy_bias=policy["bias"],
        policy_output=policy["output"],
        evaluator=policy["evaluator"],
        evaluator_workers=policy["evaluator_workers"],
        ray_address=policy["ray_address"],
        logger=_logger(cfg),
    )


def _logger(cfg: dict) -> str:
    """``logger``: a tracker whose package is installed (imix_cli.running.tracking)."""
    from imix_cli.running.tracking import LOGGERS, missing_logger_package

    logger = as_choice(cfg.get("logger", "none"), "logger", tuple(LOGGERS))
    missing = missing_logger_package(logger)
    if missing:
        raise ConfigError(missing)
    return logger


def _algo_options(algo: str, algo_cfg: dict) -> dict:
    """The ``algo.<key>`` options of an ES (:func:`algo_option_fields`), defaults filled in, those with choices
    checked; the ES's Params checks them all with the run's popsize (:func:`_check_params_together`)."""
    options = {}
    for key, f in algo_option_fields(algo).items():
        value = algo_cfg.get(key, f.default)
        if "choices" in f.metadata:
            as_choice(value, f"algo.{key}", f.metadata["choices"])
        options[key] = value
    return options


def _check_params_together(algo: str, popsize: int, algo_options: dict) -> None:
    """The ES's Params with popsize and its ``algo.*`` options together (ARS: an even popsize, top <= popsize/2)."""
    try:
        ALGORITHM_SPECS[algo].es_class().Params(popsize=popsize, **algo_options)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"algo={algo}: {first_line(err)}") from None


def _policy_size(env_name: str, env_id: str, max_steps: int | None) -> int:
    """The number of policy parameters d of an env; ConfigError for an env imix cannot evaluate."""
    try:
        return _evaluator_shape(env_name if env_name in BUILTIN_ENVS else env_id, max_steps)
    except ValueError as err:
        key = "env" if env_name in BUILTIN_ENVS else "env.id"
        value = env_name if env_name in BUILTIN_ENVS else env_id
        raise ConfigError(f"{key}={value!r}: {first_line(err).replace(repr(value) + ': ', '').replace(repr(value) + ' ', '')}") from None


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


def _policy_and_evaluator(cfg: dict, algo: str, env_name: str, env_id: str, max_steps, launcher: str | None) -> dict:
    """Validate ``policy.*``, ``evaluator``, ``evaluator_workers``, ``ray_address``."""
    policy = cfg.get("policy")
    policy = {} if policy is None else policy
    if not isinstance(policy, dict):
        raise ConfigError(f"policy={policy!r}: must be a mapping with keys {', '.join(POLICY_DEFAULTS)}")
    unknown = sorted(set(policy) - set(POLICY_DEFAULTS))
    if unknown:
        raise ConfigError(f"unknown key 'policy.{unknown[0]}'; valid policy keys: {', '.join(POLICY_DEFAULTS)}")
    hidden = policy.get("hidden", list(POLICY_DEFAULTS["hidden"]))
    if not isinstance(hidden, (list, tuple)) or not all(is_number(h) and float(h).is_integer() and h >= 1 for h in hidden):
        raise ConfigError(f"policy.hidden={hidden!r}: must be a list of layer sizes >= 1, e.g. [64,64], or [] for a linear policy")
    hidden = tuple(int(h) for h in hidden)
    p = {f"policy.{k}": policy.get(k, v) for k, v in POLICY_DEFAULTS.items()}
    obs_norm = as_bool(p, "policy.obs_norm")
    warmup = as_int(p, "policy.obs_norm_warmup", 1)
    var_floor = as_float(p, "policy.obs_var_floor", 0.0, False)
    if obs_norm and env_name in BUILTIN_ENVS:
        raise ConfigError(f"policy.obs_norm=true: only on gymnasium environments (env=gym or a MuJoCo env), not the built-in env={env_name}")
    from imix_cli.policies import OUTPUTS

    bias = as_bool(p, "policy.bias")
    output = as_choice(p["policy.output"], "policy.output", OUTPUTS)
    if output != "tanh" and env_name in BUILTIN_ENVS:
        raise ConfigError(f"policy.output={output}: only on gymnasium environments with continuous actions (a MuJoCo env), not the built-in env={env_name}")
    from imix_cli.parallel_evaluation import EVALUATORS

    evaluator = as_choice(cfg.get("evaluator", "local"), "evaluator", EVALUATORS)
    n_workers = cfg.get("evaluator_workers")
    if n_workers is not None:
        n_workers = as_int(cfg, "evaluator_workers", 1)
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
    # config.yaml keeps the policy keys only if one differs from the default, and bias/output only if
    # they do: a run's identity (and folder) stays what it was before these keys existed.
    extra = {k: v for k, v in (("bias", bias), ("output", output)) if v != POLICY_DEFAULTS[k]}
    if obs_norm and var_floor != POLICY_DEFAULTS["obs_var_floor"]:
        extra["obs_var_floor"] = var_floor
    default = hidden == POLICY_DEFAULTS["hidden"] and not obs_norm and not extra
    stored = None if default else {"hidden": list(hidden), "obs_norm": obs_norm, "obs_norm_warmup": warmup if obs_norm else None, **extra}
    return {
        "hidden": hidden, "obs_norm": obs_norm, "obs_norm_warmup": warmup if obs_norm else 0, "bias": bias, "output": output,
        "obs_var_floor": var_floor if obs_norm else POLICY_DEFAULTS["obs_var_floor"],
        "evaluator": evaluator, "evaluator_workers": n_workers or 1, "ray_address": address, "stored": stored,
    }  # fmt: skip


def _policy_dim(env_name: str, env_id: str, max_steps, hidden: tuple, bias: bool = True, output: str = "tanh") -> int:
    """Number of parameters the ES searches on this env: the policy's, or its weights' with
    ``policy.bias=false`` (a gymnasium env is made once to read its spaces)."""
    from imix_cli.policies import searched_params

    if env_name in BUILTIN_ENVS:  # their observation and output sizes are known without making the env
        return searched_params(*ENV_SPECS[env_name].policy_dims, hidden, bias)
    import gymnasium as gym

    try:
        probe = gym.make(env_id, **({} if max_steps is None else {"max_episode_steps": max_steps}))
    except Exception as err:
        raise ConfigError(f"env.id={env_id!r}: cannot be made ({first_line(err)})") from None
    try:
        obs_space, act_space = probe.observation_space, probe.action_space
    finally:
        probe.close()
    discrete = isinstance(act_space, gym.spaces.Discrete)
    if discrete and output != "tanh":
        raise ConfigError(f"policy.output={output}: {env_id} has discrete actions (the argmax of the outputs); only continuous actions are clipped")
    out = int(act_space.n) if discrete else math.prod(act_space.shape or (1,))
    return searched_params(math.prod(obs_space.shape or (1,)), out, hidden, bias)
