"""The run's specification: :class:`RunSpec` and a run's identity (the keys themselves: :mod:`imix_cli.running.config.keys`).

:func:`imix_cli.running.config.compose.spec_from_config` builds a RunSpec from a validated config; the run
folder, the checkpoints and the summary compare runs by their identity (:func:`identity_of`:
the result-determining keys of config.yaml) and decide what may be resumed or continued
(:data:`CONTINUABLE_KEYS`, :func:`resume_identity`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass, field
from pathlib import Path

from imix_cli.core.ddpg.settings import PAPER_SETTINGS
from imix_cli.core.mixing import variant_spec
from imix_cli.core.registry import ALGORITHM_SPECS, BUILTIN_ENVS, ENV_SPECS
from imix_cli.running.config.keys import BY_NAME, KEYS, NON_IDENTITY_KEYS, PAPER_DEFAULTS, POLICY_DEFAULTS


def algo_option_fields(algo: str) -> dict:
    """The ``algo.<key>`` options of an ES (conf/algo/<name>.yaml): key -> its field of the ES's Params."""
    spec = ALGORITHM_SPECS[algo]
    if not spec.options:
        return {}
    by_name = {f.name: f for f in dataclasses.fields(spec.es_class().Params)}
    return {key: by_name[key] for key in spec.options}


def run_default(option_field):
    """An ``algo.<key>`` option's default in ``imix run``: its field's ``metadata["run_default"]`` where the class's
    own default serves a plain ask/tell loop instead (CMA-ES's ``step_size_control``), else the field's default.
    The same with and without mixing, so that ``eim=false,true`` changes the mixing alone."""
    return option_field.metadata.get("run_default", option_field.default)


def _key(name: str):
    """A RunSpec field that is ``imix run``'s key ``name``: its default is the key's (:data:`~imix_cli.running.config.keys.BY_NAME`),
    read from the table, never written again here (tests/test_defaults.py compares every field with its key)."""
    return field(default=BY_NAME[name].default, metadata={"key": name})


#: The settings of algo=ddpg (conf/algo/ddpg.yaml, paper section 4.3). A DDPG run folder's name
#: carries, as ``-key=value,...``, the ones that differ from these.
DDPG_DEFAULTS = PAPER_SETTINGS


@dataclass(frozen=True, kw_only=True)
class RunSpec:
    """Everything a run needs, validated. Built by :func:`imix_cli.running.config.compose.spec_from_config` (keyword arguments only).

    A field that is a key of ``imix run`` (``_key``) defaults to that key's default in the key table
    (:mod:`imix_cli.running.config.keys`); the fields without a default are given by every caller; the few other
    defaults say why they are not a key's.
    """

    algo: str
    env_name: str  # config name ("cartpole", "acrobot") or the gymnasium id of a generic env
    env_id: str
    env_max_steps: int | None
    env_kwargs: tuple = ()  # env.kwargs.*: the gymnasium env's constructor arguments, (key, value) pairs sorted by key
    seeds: int
    workers: int
    progress: bool
    results_dir: str
    experiment: str
    # The evolution strategies' keys; an algorithm that is not an ES (DDPG) leaves them at these
    # defaults (the keys'; no generations, no mixing), which it never reads:
    mixing: str = "none"  # none | im | eim: from the keys im and eim (both false by default)
    variant: str | None = None  # mix() variant: paper | sun2009 | exact | conditional | eim_paper; None without mixing
    im_alpha: float = _key("im_alpha")
    eim_generations: int = _key("eim_generations")
    min_fresh: int = _key("min_fresh")  # with mixing: fresh members per generation, at least (mixing.mix)
    reeval_age: int | None = _key("reeval_age")  # re-evaluate a reused member whose return is older than this (None: never)
    reeval_prob: float = _key("reeval_prob")  # ... and any reused member with this probability
    reeval_count: int = _key("reeval_count")  # ... and this many reused members per generation, calibrating the other stored returns
    generations: int = 0  # the key's default is the algorithm's (${algo.generations}); DDPG runs total_steps, no generations
    popsize: int = _key("popsize")
    sigma: float = _key("sigma")
    lr: float = _key("lr")
    weight_decay: float = _key("weight_decay")
    weight_decay_form: str = _key("weight_decay_form")
    checkpoint_every: int = _key("checkpoint_every")
    checkpoint_seconds: float = _key("checkpoint_seconds")  # a periodic checkpoint at most this often (RunWriter)
    config: dict = field(repr=False, compare=False)  # the resolved config, written as config.yaml
    algo_options: dict = field(default_factory=dict, compare=False)  # per-ES options (algo.style of cem)
    # algo=ddpg only:
    total_steps: int | None = _key("total_steps")  # environment steps of each seed
    ddpg: dict | None = field(default=None, compare=False)  # validated conf/algo/ddpg.yaml settings
    # The ES policy and where its episodes run (see imix_cli.running.config.es_config):
    hidden: tuple = _key("policy.hidden")  # tanh hidden layer sizes, () = linear
    obs_norm: bool = _key("policy.obs_norm")  # observation normalisation, frozen after the warm-up
    obs_norm_warmup: int = _key("policy.obs_norm_warmup")  # generations of statistics (mixing off) before it freezes; with obs_norm only
    obs_norm_freeze: bool = _key("policy.obs_norm_freeze")  # false: the statistics keep updating, the archive is re-expressed
    obs_var_floor: float = _key("policy.obs_var_floor")  # lower bound of each observation coordinate's variance
    policy_bias: bool = _key("policy.bias")  # false = the ES searches the weights only, biases stay 0 (ARS's a = M s)
    policy_output: str = _key("policy.output")  # continuous actions tanh-squashed or clipped (imix_cli.core.evaluation.policies)
    evaluator: str = _key("evaluator")  # local | pool | ray (imix_cli.core.evaluation.parallel)
    evaluator_workers: int | None = _key("evaluator_workers")  # processes (pool) or actors (ray); None: every core / CPU
    ray_address: str | None = _key("ray_address")  # ray.init(address=...) for evaluator=ray
    # The return of the distribution mean theta (the policy one deploys), measured on
    # eval_mean_episodes fresh episodes every eval_mean_every generations (0: never); these episodes
    # are counted apart (CSV column mean_policy_episodes), never in evaluations or env_steps.
    eval_mean_every: int = _key("eval_mean_every")
    eval_mean_episodes: int = _key("eval_mean_episodes")
    logger: str = _key("logger")  # none | tensorboard | mlflow | wandb: a copy of the CSV's rows (imix_cli.running.files.tracking)

    @property
    def evaluator_key(self) -> str:
        """What :func:`imix_cli.core.evaluation.make_evaluator` takes: a built-in name or a gymnasium id."""
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
        cap.update({f"env.{k}": v for k, v in self.env_kwargs})  # a constructor argument changes the env: it names the folder
        if not ALGORITHM_SPECS[self.algo].is_es:
            changed = {k: v for k, v in (self.ddpg or {}).items() if k in DDPG_DEFAULTS and v != DDPG_DEFAULTS[k]}
            return ",".join(f"{k}={_format(v)}" for k, v in sorted({**changed, **cap}.items()))
        values = {key.name: self._folder_value(key.name) for key in KEYS if key.names_folder_with(self.mixing)}
        changed = {k: v for k, v in values.items() if v != PAPER_DEFAULTS[k]}
        defaults = {k: run_default(f) for k, f in algo_option_fields(self.algo).items()}
        changed.update({f"algo.{k}": v for k, v in self.algo_options.items() if v != defaults.get(k)})
        if self.hidden != POLICY_DEFAULTS["hidden"]:
            changed["hidden"] = "x".join(map(str, self.hidden)) or "linear"
        if self.obs_norm:
            changed["obs_norm"] = self.obs_norm_warmup  # the warm-up in generations
            if self.obs_var_floor != POLICY_DEFAULTS["obs_var_floor"]:
                changed["obs_var_floor"] = self.obs_var_floor
            if self.obs_norm_freeze != POLICY_DEFAULTS["obs_norm_freeze"]:
                changed["obs_norm_freeze"] = self.obs_norm_freeze
        if not self.policy_bias:
            changed["bias"] = False
        if self.policy_output != POLICY_DEFAULTS["output"]:
            changed["output"] = self.policy_output
        return ",".join(f"{k}={_format(v)}" for k, v in sorted({**changed, **cap}.items()))

    @property
    def run_name(self) -> str:
        from imix_cli.running.files.results import run_dir_name

        return run_dir_name(self.algo, self.env_name, self.mixing, self.overrides_suffix)

    @property
    def run_dir(self) -> Path:
        return Path(self.results_dir) / self.experiment / self.run_name

    def _folder_value(self, key: str):
        """A key's value as it names the folder: the RunSpec field of its name, the variant by its config name."""
        return variant_spec(self.variant).config_name if key.endswith("_variant") else getattr(self, key)

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

    from imix_cli.core.envs.ids import plain_env_id

    try:
        return gym.spec(plain_env_id(env_id)).max_episode_steps
    except Exception:  # an id gymnasium cannot resolve has no cap of its own
        return None
