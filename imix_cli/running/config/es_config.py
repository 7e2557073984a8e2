"""An evolution strategy's config: mixing, the ES's hyper-parameters and ``algo.*`` options, the policy and the evaluator.

Besides each key's own check, a run the machine cannot hold is refused here: CMA-ES above
:data:`imix_cli.core.algorithms.cmaes.MAX_DIM` parameters, a population whose arrays exceed the memory, an env imix
cannot evaluate.
"""

from __future__ import annotations

import math

from imix_cli.core.algorithms import cmaes
from imix_cli.core.mixing import config_variants, variant_spec
from imix_cli.core.processes import default_workers
from imix_cli.core.registry import ALGORITHM_SPECS, BUILTIN_ENVS, ENV_SPECS
from imix_cli.messages import install_extra
from imix_cli.running.config.checks import (
    ConfigError,
    as_choice,
    check_memory,
    env_kwargs_of,
    env_of,
    first_line,
    gym_env_bytes,
    parallel_launcher_name,
    workers_of,
)
from imix_cli.running.config.keys import KEYS, PAPER_DEFAULTS, POLICY_DEFAULTS, read_keys
from imix_cli.running.config.run_spec import RunSpec, algo_option_fields, run_default


def _check_weighted(algo: str, checked: dict) -> None:
    """``eim_variant=weighted`` weights members into an update that is a sum over them (imix_cli.core.mixing.weighted_reuse)."""
    from imix_cli.core.algorithms import ALGORITHMS, MIRRORED_ALGORITHMS

    cls = {**ALGORITHMS, **MIRRORED_ALGORITHMS}.get(algo)
    if cls is None or not cls.weights_utilities or cls.generation_scheme is not None:
        able = ",".join(name for name, c in ALGORITHMS.items() if c.weights_utilities)
        raise ConfigError(f"eim_variant=weighted: algo={algo}'s update does not take weighted members; use algo={able}, or eim_variant=exact")
    if checked["reeval_age"] is not None or checked["reeval_prob"] or checked["reeval_count"]:
        raise ConfigError("reeval_age/reeval_prob/reeval_count: apply to mixing variants only, not eim_variant=weighted (it re-evaluates nothing)")


def es_spec(cfg: dict, algo: str, algo_cfg: dict, env_cfg: dict, launcher: str | None) -> RunSpec:
    """The RunSpec of an evolution strategy: every key checked by its own check (:func:`read_keys`), then together
    (mixing, the ES's hyper-parameters, its policy and evaluator, the machine's limits)."""
    flat = {k: v for k, v in cfg.items() if k != "policy"} | {f"policy.{k}": v for k, v in _policy_keys(cfg).items()}
    checked = read_keys(flat, KEYS_READ)
    im, eim = checked["im"], checked["eim"]
    im_variants, eim_variants = config_variants("im"), config_variants("eim")
    algo_options = _algo_options(algo, algo_cfg)
    if eim and checked["im_variant"] != PAPER_DEFAULTS["im_variant"]:
        raise ConfigError(f"im_variant={checked['im_variant']}: applies to im=true only; with eim=true choose eim_variant={'|'.join(eim_variants)}")
    mixing = "eim" if eim else ("im" if im else "none")
    variant = eim_variants[checked["eim_variant"]].name if eim else (im_variants[checked["im_variant"]].name if im else None)
    if checked["im_alpha"] != 0.0 and not (variant is not None and variant_spec(variant).uses_alpha):
        raise ConfigError(f"im_alpha={checked['im_alpha']}: only applies with im=true im_variant=sun2009")
    if mixing == "none" and checked["min_fresh"] != PAPER_DEFAULTS["min_fresh"]:
        raise ConfigError(f"min_fresh={checked['min_fresh']}: only applies with im=true or eim=true (fresh members of a mixed generation)")
    if mixing == "none" and (checked["reeval_age"] is not None or checked["reeval_prob"] or checked["reeval_count"]):
        raise ConfigError("reeval_age/reeval_prob/reeval_count: only apply with im=true or eim=true (they re-evaluate reused members)")
    if variant is not None and variant_spec(variant).weights:
        _check_weighted(algo, checked)

    env_name, env_id, max_steps = env_of(env_cfg)
    env_kwargs = env_kwargs_of(env_cfg, env_name, env_id)
    policy = _policy_and_evaluator(checked, env_name, launcher)
    if mixing != "none" and not policy["obs_norm_freeze"] and not policy["policy_bias"]:
        raise ConfigError(
            f"policy.obs_norm_freeze=false with {mixing}=true and policy.bias=false: a change of the observation mean cannot be re-expressed "
            "in a policy without biases, so reuse would not be exact; use policy.bias=true (or policy.obs_norm_freeze=true)"
        )
    # evaluator=ray: the seeds run in the main process, which alone drives the run's one Ray runtime
    # (seed processes each started a Ray of their own, each sized to every CPU).
    spreading = checked["evaluator"] if checked["evaluator"] in ("pool", "ray") else None
    workers = workers_of(checked["workers"], launcher, pool=spreading)
    if cfg.get("total_steps") is not None:  # silently running `generations` instead would waste the user's budget
        raise ConfigError(
            f"total_steps={cfg['total_steps']!r}: algo=ddpg's budget (environment steps); an evolution strategy (algo={algo}) runs generations= instead"
        )
    config = {k: v for k, v in cfg.items() if k != "total_steps"}  # total_steps: ddpg's budget only
    popsize, min_fresh = checked["popsize"], checked["min_fresh"]
    if algo == "cmaes" and popsize < cmaes.MIN_POPSIZE:
        raise ConfigError(
            f"popsize={popsize}: algo=cmaes needs popsize >= {cmaes.MIN_POPSIZE} (its recombination weights need at least 2 parents and one non-parent)"
        )
    if mixing != "none" and min_fresh > popsize:
        raise ConfigError(f"min_fresh={min_fresh}: more than popsize={popsize} members")
    if not math.isfinite(checked["sigma"] * checked["sigma"]):
        raise ConfigError(f"sigma={checked['sigma']!r}: the initial variance sigma^2 overflows float64; must be < 1e154")
    _check_params_together(algo, popsize, algo_options)
    _policy_size(env_name, env_id, max_steps, env_kwargs)  # an env imix cannot evaluate: one line
    num_params = _policy_dim(env_name, env_id, max_steps, policy["hidden"], policy["policy_bias"], policy["policy_output"], env_kwargs)
    if algo == "cmaes" and num_params > cmaes.MAX_DIM:
        raise ConfigError(
            f"algo=cmaes: the {'x'.join(map(str, policy['hidden'])) or 'linear'} policy on {env_id} has {num_params} parameters, more than "
            f"CMA-ES's limit of {cmaes.MAX_DIM} (O(d^2) memory, O(d^3) time); use algo=snes or algo=openes (diagonal), or a smaller policy.hidden"
        )
    env_bytes = 0 if env_name in BUILTIN_ENVS else gym_env_bytes(env_id)  # the built-ins are compiled: no env objects
    archive_depth = 0 if variant is None else variant_spec(variant).depth(checked["eim_generations"])
    check_memory(popsize, num_params, archive_depth, checked["seeds"], env_bytes, env_id)
    stored = policy.pop("stored")
    if stored is None:
        config.pop("policy", None)  # the default policy: config.yaml stays as it was before the key existed
    else:
        config["policy"] = stored
    return RunSpec(
        algo=algo,
        env_name=env_name,
        env_id=env_id,
        env_max_steps=max_steps,
        env_kwargs=env_kwargs,
        mixing=mixing,
        variant=variant,
        workers=workers,
        config={**config, "mixing": mixing},
        algo_options=algo_options,
        **{key.name: checked[key.name] for key in KEYS if key.spec},
        **policy,
    )


#: The keys :func:`es_spec` checks one by one (all but ``total_steps``, algo=ddpg's, which an ES refuses).
KEYS_READ = tuple(key.name for key in KEYS if key.check is not None)


def _algo_options(algo: str, algo_cfg: dict) -> dict:
    """The ``algo.<key>`` options of an ES (:func:`algo_option_fields`), defaults filled in, those with choices
    checked; the ES's Params checks them all with the run's popsize (:func:`_check_params_together`)."""
    options = {}
    for key, f in algo_option_fields(algo).items():
        value = algo_cfg.get(key, run_default(f))
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


def _policy_size(env_name: str, env_id: str, max_steps: int | None, env_kwargs: tuple = ()) -> int:
    """The number of policy parameters d of an env; ConfigError for an env imix cannot evaluate."""
    try:
        return _evaluator_shape(env_name if env_name in BUILTIN_ENVS else env_id, max_steps, env_kwargs)
    except ValueError as err:
        key = "env" if env_name in BUILTIN_ENVS else "env.id"
        value = env_name if env_name in BUILTIN_ENVS else env_id
        raise ConfigError(f"{key}={value!r}: {first_line(err).replace(repr(value) + ': ', '').replace(repr(value) + ' ', '')}") from None


_EVALUATOR_SHAPES: dict = {}


def _evaluator_shape(key: str, max_steps: int | None, env_kwargs: tuple = ()) -> int:
    """make_evaluator(key).num_params, cached per process (a sweep asks once per env, not per point)."""
    cached = (key, max_steps, repr(env_kwargs))
    if cached not in _EVALUATOR_SHAPES:
        from imix_cli.core.evaluation import UserEnvError, make_evaluator

        try:
            _EVALUATOR_SHAPES[cached] = make_evaluator(key, max_steps, env_kwargs=dict(env_kwargs)).num_params
        except ValueError as err:
            _EVALUATOR_SHAPES[cached] = ValueError(str(err))
        except UserEnvError as err:
            # the env's own code broke: with env.kwargs given, the arguments are the likely cause (bad input, exit 2);
            # without, it is the env's failure (exit 1, as when it breaks in an episode)
            if not env_kwargs:
                raise
            _EVALUATOR_SHAPES[cached] = ValueError(str(err))
    shape = _EVALUATOR_SHAPES[cached]
    if isinstance(shape, Exception):
        raise shape
    return shape


def _policy_keys(cfg: dict) -> dict:
    """``cfg["policy"]``: a mapping of the ``policy.*`` keys only, each it lacks at its default."""
    policy = cfg.get("policy")
    policy = {} if policy is None else policy
    if not isinstance(policy, dict):
        raise ConfigError(f"policy={policy!r}: must be a mapping with keys {', '.join(POLICY_DEFAULTS)}")
    unknown = sorted(set(policy) - set(POLICY_DEFAULTS))
    if unknown:
        raise ConfigError(f"unknown key 'policy.{unknown[0]}'; valid policy keys: {', '.join(POLICY_DEFAULTS)}")
    return policy


def _policy_and_evaluator(checked: dict, env_name: str, launcher: str | None) -> dict:
    """The checked ``policy.*``, ``evaluator``, ``evaluator_workers``, ``ray_address`` (``checked``) together: the RunSpec's
    policy and evaluator fields, and ``stored``, the policy keys config.yaml keeps (None: the default policy)."""
    hidden, obs_norm = checked["policy.hidden"], checked["policy.obs_norm"]
    warmup, var_floor = checked["policy.obs_norm_warmup"], checked["policy.obs_var_floor"]
    if obs_norm and env_name in BUILTIN_ENVS:
        raise ConfigError(f"policy.obs_norm=true: only on gymnasium environments (env=gym or a MuJoCo env), not the built-in env={env_name}")
    bias, output = checked["policy.bias"], checked["policy.output"]
    if output != "tanh" and env_name in BUILTIN_ENVS:
        raise ConfigError(f"policy.output={output}: only on gymnasium environments with continuous actions (a MuJoCo env), not the built-in env={env_name}")
    evaluator, n_workers, address = checked["evaluator"], checked["evaluator_workers"], checked["ray_address"]
    if n_workers is None and evaluator == "pool":
        n_workers = default_workers()
    if address is not None and evaluator != "ray":
        raise ConfigError(f"ray_address={address}: only used with evaluator=ray")
    if evaluator == "pool" and parallel_launcher_name(launcher):
        raise ConfigError(f"evaluator=pool: hydra/launcher={parallel_launcher_name(launcher)} already runs jobs in parallel; use evaluator=local")
    if evaluator == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ConfigError(f"evaluator=ray: ray is not installed; {install_extra('cluster')}") from None
    # config.yaml keeps the policy keys only if one differs from the default, and bias/output only if
    # they do: a run's identity (and folder) stays what it was before these keys existed.
    extra = {k: v for k, v in (("bias", bias), ("output", output)) if v != POLICY_DEFAULTS[k]}
    if obs_norm and var_floor != POLICY_DEFAULTS["obs_var_floor"]:
        extra["obs_var_floor"] = var_floor
    freeze = checked["policy.obs_norm_freeze"]
    if freeze != POLICY_DEFAULTS["obs_norm_freeze"]:
        if not obs_norm:
            raise ConfigError(f"policy.obs_norm_freeze={str(freeze).lower()}: applies with policy.obs_norm=true only (the normaliser's statistics)")
        extra["obs_norm_freeze"] = freeze
    default = hidden == POLICY_DEFAULTS["hidden"] and not obs_norm and not extra
    stored = None if default else {"hidden": list(hidden), "obs_norm": obs_norm, "obs_norm_warmup": warmup if obs_norm else None, **extra}
    return {
        "hidden": hidden, "obs_norm": obs_norm, "obs_norm_warmup": warmup, "obs_norm_freeze": freeze, "policy_bias": bias, "policy_output": output,
        "obs_var_floor": var_floor if obs_norm else POLICY_DEFAULTS["obs_var_floor"], "evaluator_workers": n_workers, "stored": stored,
    }  # fmt: skip


def _policy_dim(env_name: str, env_id: str, max_steps, hidden: tuple, bias: bool = True, output: str = "tanh", env_kwargs: tuple = ()) -> int:
    """Number of parameters the ES searches on this env: the policy's, or its weights' with
    ``policy.bias=false`` (a gymnasium env is made once to read its spaces)."""
    from imix_cli.core.evaluation.policies import searched_params

    if env_name in BUILTIN_ENVS:  # their observation and output sizes are known without making the env
        return searched_params(*ENV_SPECS[env_name].policy_dims, hidden, bias)
    import gymnasium as gym

    try:
        probe = gym.make(env_id, **dict(env_kwargs), **({} if max_steps is None else {"max_episode_steps": max_steps}))
    except Exception as err:
        given = f" with {', '.join(f'{k}={v!r}' for k, v in env_kwargs)}" if env_kwargs else ""
        raise ConfigError(f"env.id={env_id!r}: cannot be made{given} ({first_line(err)})") from None
    try:
        obs_space, act_space = probe.observation_space, probe.action_space
    finally:
        probe.close()
    discrete = isinstance(act_space, gym.spaces.Discrete)
    if discrete and output != "tanh":
        raise ConfigError(f"policy.output={output}: {env_id} has discrete actions (the argmax of the outputs); only continuous actions are clipped")
    out = int(act_space.n) if discrete else math.prod(act_space.shape or (1,))
    return searched_params(math.prod(obs_space.shape or (1,)), out, hidden, bias)
