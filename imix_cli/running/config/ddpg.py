"""algo=ddpg's config: its settings (conf/algo/ddpg.yaml), its budget ``total_steps`` and a continuous-action env.

The evolution strategies' top-level keys (:data:`imix_cli.running.config.keys.ES_ONLY_KEYS`) are ignored
and left out of its config.yaml; the RunSpec's ES fields keep their defaults.
"""

from __future__ import annotations

from imix_cli.core.envs.ids import plain_env_id
from imix_cli.core.registry import BUILTIN_ENVS, CONTINUOUS_BUILTIN_ENVS, ENV_SPECS
from imix_cli.running.config.checks import ConfigError, as_float, as_int, env_of, first_line, is_number, workers_of
from imix_cli.running.config.keys import ES_ONLY_KEYS, read_keys
from imix_cli.running.config.run_spec import RunSpec


#: The one line algo=ddpg gives where its extra is not installed (a plain `make install` leaves it out).
def ddpg_spec(cfg: dict, algo: str, algo_cfg: dict, env_cfg: dict, launcher: str | None) -> RunSpec:
    """algo=ddpg: ES keys are ignored; ``total_steps`` (null: the algo's per-env default) is the budget."""
    env_name, env_id, max_steps = env_of(env_cfg)
    if env_cfg.get("kwargs"):  # stable-baselines3 makes its own env: the constructor arguments would not reach it
        raise ConfigError("env.kwargs: an evolution strategy's key (algo=ddpg makes its env without constructor arguments)")
    episode_cap = _continuous_env_cap(env_name, env_id, max_steps)
    settings = _ddpg_settings(algo_cfg)
    total = cfg.get("total_steps")
    if total is None:
        defaults = algo_cfg.get("default_total_steps") or {}
        total = defaults.get(env_name) if isinstance(defaults, dict) else None
        if total is None:
            raise ConfigError(f"total_steps=null: algo=ddpg has no default budget for env {env_name!r}; give total_steps=<environment steps>")
        total = as_int({"algo.default_total_steps": total}, "algo.default_total_steps", 1, label=f"algo.default_total_steps.{env_name}")
    else:
        total = as_int(cfg, "total_steps", 1)
    if total < episode_cap:
        raise ConfigError(f"total_steps={total}: must be >= the episode cap of {episode_cap} steps, so that every seed finishes an episode")
    checked = read_keys(cfg, ("seeds", "workers", "progress", "results_dir", "experiment"))  # the keys it shares with the ES
    algo_stored = {k: v for k, v in algo_cfg.items() if k not in ("generations", "default_total_steps")}
    config = {k: v for k, v in cfg.items() if k not in ES_ONLY_KEYS}
    config.update(algo=algo_stored, total_steps=total, mixing="none")
    return RunSpec(
        algo=algo,
        env_name=env_name,
        env_id=env_id,
        env_max_steps=max_steps,
        seeds=checked["seeds"],
        workers=workers_of(checked["workers"], launcher),
        progress=checked["progress"],
        results_dir=checked["results_dir"],
        experiment=checked["experiment"],
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
        raise ConfigError(f"env.id={env_id!r}: cannot be made ({first_line(err)})") from None
    try:
        box = isinstance(probe.action_space, gym.spaces.Box)
    finally:
        probe.close()
    if not box:
        raise ConfigError(f"env.id={env_id!r}: algo=ddpg needs continuous (Box) actions, the env has {type(probe.action_space).__name__} actions")
    cap = max_steps or gym.spec(plain_env_id(env_id)).max_episode_steps
    if cap is None:
        raise ConfigError(f"env.id={env_id!r} has no time limit: give env.max_steps for algo=ddpg")
    return int(cap)


def _ddpg_settings(algo_cfg: dict) -> dict:
    """The validated DDPG settings (``algo.*`` keys of conf/algo/ddpg.yaml)."""
    a = {f"algo.{k}": v for k, v in algo_cfg.items()}
    out = {}
    for key in ("actor_arch", "critic_arch"):
        value = algo_cfg.get(key)
        if not isinstance(value, (list, tuple)) or not value or not all(is_number(v) and float(v).is_integer() and v >= 1 for v in value):
            raise ConfigError(f"algo.{key}={value!r}: must be a non-empty list of layer sizes >= 1, e.g. [8,8]")
        out[key] = [int(v) for v in value]
    for key in ("actor_lr", "critic_lr", "ou_dt"):
        out[key] = as_float(a, f"algo.{key}", 0.0, False)
    out["tau"] = as_float(a, "algo.tau", 0.0, False, 1.0, True)
    out["gamma"] = as_float(a, "algo.gamma", 0.0, True, 1.0, True)
    out["ou_sigma"] = as_float(a, "algo.ou_sigma", 0.0, True)
    out["ou_theta"] = as_float(a, "algo.ou_theta", 0.0, True)
    for key, minimum in (("batch_size", 1), ("buffer_size", 1), ("learning_starts", 0), ("train_freq", 1), ("gradient_steps", 1)):
        out[key] = as_int(a, f"algo.{key}", minimum)
    return out
