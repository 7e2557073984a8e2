"""Every ``imix run`` key, declared once: its default, its check, its doc and its roles.

Why one table: a key written in several places (conf/config.yaml, a docs table, the ``--help`` template, the
checks, the RunSpec, the lists of the keys that name a run folder or must match to resume) drifts. Here each key is
one :class:`RunKey` record, as pycma declares each option once in ``CMAOptions``, and everything else is derived:

- the top-level values of ``conf/config.yaml`` (Hydra composes from that file; ``python -m
  imix_cli.running.config.keys write`` regenerates it from this table, with the ``Keys:`` block of ``imix run --help``
  and the configuration reference ``docs/configuration.md``; tests/test_config_keys.py fails when one of them drifts);
- the checks: :func:`read_keys` checks every key that has a ``check`` (:mod:`imix_cli.running.config.es_config` then checks
  the keys together); the numeric bounds are the library's own (:data:`imix_cli.core.algorithms.base.PARAM_BOUNDS`,
  :data:`imix_cli.core.mixing.generation.MIXING_BOUNDS`), so ``imix run`` and the constructors refuse the same values; the
  mixing keys' defaults are the library's one declaration of them (:data:`imix_cli.core.mixing.MIXING_DEFAULTS`), so
  ``imix_cli.mix`` and ``MixingES`` run the rule ``imix run`` runs;
- the RunSpec's fields (``spec``), a run's folder name (``names_folder``), what a resume must match (``identity``)
  and what algo=ddpg ignores (``es_only``): :data:`TOP_LEVEL_KEYS`, :data:`PAPER_DEFAULTS`, :data:`NON_IDENTITY_KEYS`,
  :data:`ES_ONLY_KEYS`, :data:`POLICY_DEFAULTS`.

The options of one algorithm (``algo.style``, ``algo.top``, ...) are fields of that algorithm's ``Params``
(:func:`imix_cli.running.config.run_spec.algo_option_fields`) with their doc in the field's metadata; the env keys
(``env.id``, ``env.max_steps``) are set by the env group (conf/env/*.yaml). Adding a key: one :class:`RunKey` here,
then the code that uses it.
"""

from __future__ import annotations

import sys
import textwrap
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from imix_cli.core.algorithms.base import PARAM_BOUNDS, WEIGHT_DECAY_FORMS, Params
from imix_cli.core.mixing import MIXING_DEFAULTS, config_variants, variant_spec
from imix_cli.core.mixing.generation import MIXING_BOUNDS
from imix_cli.running.config.checks import ConfigError, as_bool, as_bounded, as_choice, as_float, as_int, as_name, experiment_of, seeds_of


# ----------------------------------------------------------------------------------- checks
# Each check reads ``cfg[key]`` and returns the checked value, or raises ConfigError naming the key (config_checks).
def flag(cfg: dict, key: str) -> bool:
    return as_bool(cfg, key)


def plain_name(cfg: dict, key: str) -> str:
    return as_name(cfg, key)


def integer(minimum: int) -> Callable:
    return lambda cfg, key: as_int(cfg, key, minimum)


def number(low: float, low_inclusive: bool) -> Callable:
    return lambda cfg, key: as_float(cfg, key, low, low_inclusive)


def bounded(bound) -> Callable:
    """A :class:`~imix_cli.core.bounds.Bound` of the library's: the CLI and the constructors check the same numbers.
    The check keeps it as ``.bound`` (tests/test_config_keys.py tries a value out of it for every such key)."""
    check = lambda cfg, key: as_bounded(cfg, key, bound)  # noqa: E731
    check.bound = bound
    return check


def choice(choices: Callable[[], tuple]) -> Callable:
    """One of ``choices()`` (called when checked: a registry the table need not import at start-up); kept as ``.choices``."""
    check = lambda cfg, key: as_choice(cfg.get(key), key, tuple(choices()))  # noqa: E731
    check.choices = choices
    return check


def optional(check: Callable) -> Callable:
    """``null`` or what ``check`` accepts."""
    wrapped = lambda cfg, key: None if cfg.get(key) is None else check(cfg, key)  # noqa: E731
    wrapped.__dict__.update(check.__dict__)
    return wrapped


def _seeds(cfg: dict, key: str) -> int:
    return seeds_of(cfg)


def _hidden(cfg: dict, key: str) -> tuple:
    from imix_cli.running.config.checks import is_number

    hidden = cfg.get(key)
    if not isinstance(hidden, (list, tuple)) or not all(is_number(h) and float(h).is_integer() and h >= 1 for h in hidden):
        raise ConfigError(f"{key}={hidden!r}: must be a list of layer sizes >= 1, e.g. [64,64], or [] for a linear policy")
    return tuple(int(h) for h in hidden)


def _ray_address(cfg: dict, key: str) -> str | None:
    address = cfg.get(key)
    if address is not None and (not isinstance(address, str) or not address.strip()):
        raise ConfigError(f"{key}={address!r}: must be an address such as auto or ray://host:10001 (or null: a local Ray)")
    return address


def _logger(cfg: dict, key: str) -> str:
    """A tracker whose package is installed (:mod:`imix_cli.running.files.tracking`)."""
    from imix_cli.running.files.tracking import LOGGERS, missing_logger_package

    logger = as_choice(cfg.get(key), key, tuple(LOGGERS))
    missing = missing_logger_package(logger)
    if missing:
        raise ConfigError(missing)
    return logger


def _evaluators() -> tuple:
    from imix_cli.core.evaluation.parallel import EVALUATORS

    return EVALUATORS


def _outputs() -> tuple:
    from imix_cli.core.evaluation.policies import OUTPUTS

    return OUTPUTS


# ------------------------------------------------------------------------------------ the record
#: ``RunKey.default`` of a key its config group sets (``algo``, ``env.id``, ...): not a value of conf/config.yaml.
GROUP = "<group>"


@dataclass(frozen=True)
class RunKey:
    """One key of ``imix run``: everything the rest of imix knows of it."""

    name: str  # as on the command line (policy.hidden, env.id, ...)
    default: object  # its value in conf/config.yaml (Python); GROUP: set by a config group
    short: str  # one line for `imix run --help` and the YAML comment
    doc: str  # the reference's text (Markdown)
    section: str
    check: Callable | None = None  # (cfg, key) -> the checked value, ConfigError naming the key; None: see `checked_by`
    checked_by: str = ""  # where a key without a `check` is checked (it needs other keys or the launcher)
    spec: bool = False  # the checked value is the RunSpec field of the same name
    names_folder: str = ""  # a value other than the default names the run folder: "always" | "mixing" | "im" | "eim" (with that mixing)
    identity: bool = True  # the value changes results: a run folder's config.yaml must match it to be resumed
    es_only: bool = True  # algo=ddpg ignores it (and leaves it out of its config.yaml)
    absent: object = None  # the value read when a config lacks the key (a config written before the key existed)
    shown: str | None = None  # the default as documented, when not the YAML value ("1000 / 400", "per env")

    @property
    def in_yaml(self) -> bool:
        return self.default is not GROUP

    def names_folder_with(self, mixing: str) -> bool:
        """Whether a value other than the default names the folder of a run with this ``mixing`` (none | im | eim)."""
        return self.names_folder in ("always", mixing) or (self.names_folder == "mixing" and mixing != "none")

    @property
    def shown_default(self) -> str:
        return self.shown if self.shown is not None else yaml_value(self.default)


def yaml_value(value) -> str:
    """``value`` as conf/config.yaml writes it (flow style: ``[8, 8]``, ``null``, ``true``)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "null"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(map(yaml_value, value)) + "]"
    return str(value)


#: The sections of the reference, in order.
SECTIONS = ("what to run", "mixing", "the evolution strategy", "the policy", "where episodes run", "run and output", "DDPG")


_NOT_RESULTS = {"identity": False}  # never changes a run's results: a resume need not match it
_EVERY_ALGO = {"es_only": False}  # read by algo=ddpg too

#: The keys, in conf/config.yaml's order (the group keys first; the reference sorts them into :data:`SECTIONS`).
KEYS = (
    # ---------------------------------------------------------------- set by the config groups
    RunKey("algo", GROUP, "openes | snes | cem | cmaes | ars | ddpg",
           "`openes`, `snes`, `cem`, `cmaes`, `ars` (Augmented Random Search: docs/ars.md), `ddpg` (stable-baselines3; "
           "continuous-action envs only, the `ddpg` extra)", "what to run", shown="snes", es_only=False),
    RunKey("algo.generations", GROUP, "the paper's generation count of the algorithm",
           "the paper's generation count of the algorithm (openes, snes: 1000; cem, cmaes: 400); the default of `generations`",
           "what to run", shown="1000 / 400"),
    RunKey("env", GROUP, "cartpole | acrobot | continuous_cartpole[_hard] | MuJoCo | gym",
           "`cartpole` (CartPole-v0 semantics, 200 steps), `acrobot` (Acrobot-v1 dynamics, capped at 200 steps as in the paper), "
           "`continuous_cartpole`, `continuous_cartpole_hard` (paper section 4.3), `swimmer`, `hopper`, `halfcheetah`, `walker2d`, "
           "`ant` (MuJoCo v5, the `mujoco` extra), `gym` (any gymnasium id)", "what to run", shown="cartpole", es_only=False),
    RunKey("env.id", GROUP, "gymnasium id (env=gym: any registered id)",
           "gymnasium id; with `env=gym`, e.g. `env.id=CartPole-v1`, any registered id runs through the generic (slower) path. "
           "Giving a built-in env another id (`env=cartpole env.id=CartPole-v1`) keeps the built-in's `env.max_steps`, and says so "
           "in one line; `env=gym env.id=...` takes the id's own time limit", "what to run", shown="per env", es_only=False),
    RunKey("env.max_steps", GROUP, "episode cap (null: the environment's own limit)", "episode cap; `null` = the environment's own limit",
           "what to run", shown="per env", es_only=False),
    RunKey("env.kwargs.<name>", GROUP, "a gymnasium env's constructor argument (+env.kwargs.continuous=true)",
           "a constructor argument of a gymnasium env, given to `gym.make` (`env=gym env.id=LunarLander-v3 +env.kwargs.continuous=true`, "
           "`+env.kwargs.ctrl_cost_weight=0.1` on a MuJoCo env, which then runs on gymnasium); checked against the env's constructor "
           "before any seed runs, recorded in config.yaml and in the run folder's name (`-env.continuous=True`). Not for the built-in "
           "compiled envs, nor algo=ddpg", "what to run", shown="none"),
    # ---------------------------------------------------------------- conf/config.yaml
    RunKey("im", False, "importance mixing with the previous generation",
           "importance mixing with the previous generation (variant `im_variant`)", "mixing", flag),
    RunKey("eim", False, "extended importance mixing over eim_generations generations; on noisy returns OpenES/SNES re-tell "
           "the same noise (eim_variant=conditional there: docs/research/bias.md, \"Noisy returns told again\")",
           "multi-generation mixing over `eim_generations` generations (variant `eim_variant`; implies mixing). Where "
           "returns are noisy (random starts, stochastic dynamics) and the noise is large next to the differences between "
           "members, OpenES and SNES with `exact` mixing tell the same stored noise generation after generation (consecutive "
           "gradient estimates 0.92 alike under pure noise) and θ follows it further (1.7× the drift): θ can end worse "
           "than without mixing, at equal episodes too; `eim_variant=conditional` cuts that echo to 0.15 (docs/research/bias.md, "
           "\"Noisy returns told again\")", "mixing", flag),
    RunKey("im_variant", variant_spec(MIXING_DEFAULTS.im_variant).config_name, "paper (Algorithm 2) | sun2009 | conditional, with im=true",
           "with `im=true`: `paper` (Algorithm 2), `sun2009` (Sun et al. 2009) or `conditional` (Sun et al.'s rule with each "
           "member taken given the ES's move it took part in: the research notes, \"Reused returns and the search\")", "mixing",
           choice(lambda: config_variants("im")), names_folder="im"),
    RunKey("eim_variant", variant_spec(MIXING_DEFAULTS.variant).config_name,
           "exact (unbiased over chains) | conditional | paper (Algorithm 3) | weighted (snes, openes), with eim=true",
           "with `eim=true`: `exact` (imix's rule, unbiased over chains of generations), `conditional` (each member of the "
           "previous generation taken given the ES's move: unbiased inside the loop under neutral fitness, worse for CMA-ES "
           "on CartPole), `paper` (the paper's Algorithm 3, biased over chains: for reproduction) or `weighted` (not mixing: "
           "the fresh members of the last `eim_generations` generations weighted into the update by importance weights, "
           "self-normalised, fewer fresh draws as their effective sample size allows; SNES and OpenES only; it reuses less "
           "than `exact` where consecutive distributions overlap little: docs/research/reuse_modes.md). `exact` and `conditional` "
           "are the library's variants of the same names (`imix_cli.core.mixing.VARIANT_SPECS`); `paper` is its `eim_paper`, "
           "because its `paper` is Algorithm 2 (`im_variant=paper`)", "mixing",
           choice(lambda: config_variants("eim")), names_folder="eim", absent=variant_spec(MIXING_DEFAULTS.variant).config_name),
    RunKey("im_alpha", MIXING_DEFAULTS.alpha, "sun2009's minimal refresh rate in [0, 1)", "`sun2009`'s minimal refresh rate α ∈ [0, 1)",
           "mixing", bounded(MIXING_BOUNDS["alpha"]), spec=True, names_folder="im"),
    RunKey("eim_generations", MIXING_DEFAULTS.eim_generations, "K, archived generations eim reuses from",
           "K, the archived generations `eim` reuses from", "mixing", bounded(MIXING_BOUNDS["eim_generations"]), spec=True, names_folder="eim"),
    RunKey("min_fresh", MIXING_DEFAULTS.min_fresh, "with mixing: fresh members per generation, at least (no fixed point)",
           "with `im=true` or `eim=true`: at least this many members of every generation are fresh, in slots drawn at random "
           "independently of the members, so the generation keeps its law (`0`: the rules alone). Without it a distribution "
           "that stops moving reuses every member and an ES whose update depends only on its members and their returns (CEM, "
           "CMA-ES) repeats its update: a fixed point (the research notes, \"Reused returns and the search\"). `algo=ars` leaves it "
           "unused: every mirror of its pairs is evaluated, so no generation is reused whole", "mixing",
           bounded(MIXING_BOUNDS["min_fresh"]), spec=True, names_folder="mixing"),
    RunKey("reeval_age", MIXING_DEFAULTS.reeval_age, "re-evaluate reused members whose return is older (generations)",
           "re-evaluate a reused member whose stored return is more than this many generations old (`null`: never; a remedy "
           "for the selection bias of stored returns, see the research notes)", "mixing",
           optional(bounded(MIXING_BOUNDS["reeval_age"])), spec=True, names_folder="mixing"),
    RunKey("reeval_prob", MIXING_DEFAULTS.reeval_prob, "re-evaluate each reused member with this probability",
           "re-evaluate each reused member with this probability", "mixing", bounded(MIXING_BOUNDS["reeval_prob"]), spec=True, names_folder="mixing"),
    RunKey("reeval_count", MIXING_DEFAULTS.reeval_count, "re-evaluate this many reused members per generation; calibrate the others on them",
           "re-evaluate this many reused members (at random) every generation, and tell the ES the other stored returns "
           "calibrated on those (stored, fresh) pairs: fresh ≈ α + β·stored, β ∈ [0, 1] (the research notes, \"Reused returns "
           "and the search\")", "mixing", bounded(MIXING_BOUNDS["reeval_count"]), spec=True, names_folder="mixing"),
    RunKey("seeds", 25, "runs seeds 0..seeds-1", "runs seeds `0 … seeds-1` (at most 100,000)", "what to run", _seeds, spec=True,
           **_NOT_RESULTS, **_EVERY_ALGO),
    RunKey("generations", "${algo.generations}", "generations per seed (1000 openes/snes, 400 cem/cmaes)", "generations per seed",
           "what to run", integer(1), spec=True),
    RunKey("total_steps", None, "algo=ddpg only: environment steps per seed",
           "`algo=ddpg` only: environment steps per seed; `null` = 200 000 on `continuous_cartpole`, 1 000 000 on "
           "`continuous_cartpole_hard` (the paper's). `algo=ddpg` ignores the ES keys", "DDPG",
           checked_by="imix_cli.running.config.ddpg (an evolution strategy refuses any value: imix_cli.running.config.es_config)", **_EVERY_ALGO),
    RunKey("popsize", Params.popsize, "population size N (>= 2; >= 3 for cmaes)", "population size N (≥ 2; ≥ 3 for CMA-ES)",
           "the evolution strategy", bounded(PARAM_BOUNDS["popsize"]), spec=True, names_folder="always"),
    RunKey("sigma", Params.sigma, "initial standard deviation (> 0)", "initial standard deviation; initial covariance σ²I (> 0)",
           "the evolution strategy", bounded(PARAM_BOUNDS["sigma"]), spec=True, names_folder="always"),
    RunKey("lr", Params.lr, "Adam learning rate of openes/snes (> 0)",
           "Adam learning rate of OpenES and SNES (> 0; β1 = 0.99, β2 = 0.999 as in the paper)", "the evolution strategy",
           bounded(PARAM_BOUNDS["lr"]), spec=True, names_folder="always"),
    RunKey("weight_decay", Params.weight_decay, "weight-decay coefficient (>= 0)", "weight-decay coefficient w (≥ 0)",
           "the evolution strategy", bounded(PARAM_BOUNDS["weight_decay"]), spec=True, names_folder="always"),
    RunKey("weight_decay_form", Params.weight_decay_form, "estool: ranks - w mean(theta^2) | paper: fitness - w|theta|^2",
           "`estool`: centred ranks − w·mean(θ²) (the authors' code, which produced the paper's curves); `paper`: fitness − "
           "w‖θ‖² before ranking (the paper's text)", "the evolution strategy", choice(lambda: WEIGHT_DECAY_FORMS), spec=True,
           names_folder="always"),
    RunKey("workers", None, "processes for the seeds (null: all cores)",
           "processes for the seeds; `null` = all cores. Results do not depend on it", "where episodes run",
           optional(integer(1)), **_NOT_RESULTS, **_EVERY_ALGO),  # its default and limit: config_checks.workers_of (the launcher, the evaluator)
    RunKey("checkpoint_every", 50, "generations between checkpoints (0: none)",
           "save each seed's state every N generations (0 = never); a killed run resumes there", "run and output",
           integer(0), spec=True, **_NOT_RESULTS),
    RunKey("checkpoint_seconds", 30, "... and at least this many seconds apart (0: every time)",
           "a periodic checkpoint falls due every `checkpoint_every` generations once at least this many seconds of the seed's "
           "wall time have passed since its last one (0 = at every `checkpoint_every`). A killed run loses at most about this "
           "long, plus `checkpoint_every` generations, per seed; a run of cheap generations (the main job: ~0.2 ms a "
           "generation) no longer spends a fifth of its time writing checkpoints. A seed's final state is always saved",
           "run and output", number(0.0, True), spec=True, absent=0.0, **_NOT_RESULTS),
    RunKey("eval_mean_every", 10, "measure the distribution mean's return every N generations (0: never)",
           "every N generations, measure the return of the distribution mean θ (the policy one deploys) on fresh episodes: CSV "
           "`mean_policy_score`, the θ column of the summary, dots in the convergence figures (0 = never)", "run and output",
           integer(0), spec=True, absent=0, **_NOT_RESULTS, **_EVERY_ALGO),  # its own random stream: results do not change
    RunKey("eval_mean_episodes", 5, "... on this many fresh episodes (not counted as evaluations)",
           "episodes per such measurement; counted in `mean_policy_episodes`, never in `evaluations` or `env_steps`", "run and output",
           integer(1), spec=True, absent=5, **_NOT_RESULTS, **_EVERY_ALGO),
    RunKey("progress", True, "progress bar", "progress bar", "run and output", flag, spec=True, **_NOT_RESULTS, **_EVERY_ALGO),
    RunKey("logger", "none", "none | tensorboard | mlflow | wandb: the CSV rows also to a tracker",
           "`none`, `tensorboard`, `mlflow`, `wandb`: each generation's CSV row also goes to that tracker (the extra of the same "
           "name); the CSV stays the record. See the getting-started guide, \"Tracking\"", "run and output", _logger, spec=True,
           absent="none", **_NOT_RESULTS),  # a tracker only copies the CSV's rows
    RunKey("results_dir", "results", "output root", "output root", "run and output", plain_name, spec=True, **_NOT_RESULTS, **_EVERY_ALGO),
    RunKey("experiment", "default", "sub-folder of results_dir", "sub-folder of `results_dir`", "run and output", experiment_of,
           spec=True, **_NOT_RESULTS, **_EVERY_ALGO),
    RunKey("policy.hidden", (8, 8), "tanh hidden layer sizes ([] = linear policy)", "tanh hidden layer sizes; `[]` = linear policy",
           "the policy", _hidden, absent=(8, 8), shown="[8,8]"),
    RunKey("policy.obs_norm", False, "observation normalisation (gymnasium envs), frozen after the warm-up",
           "normalise observations (gymnasium envs), statistics frozen after the warm-up (honest reuse) unless "
           "`policy.obs_norm_freeze=false`", "the policy", flag, absent=False),
    RunKey("policy.obs_norm_warmup", 5, "warm-up generations, without mixing, that gather the statistics",
           "generations that gather the statistics, without mixing, before they freeze (or, with `policy.obs_norm_freeze=false`, "
           "before mixing starts)", "the policy", integer(1), absent=5),
    RunKey("policy.obs_norm_freeze", True, "false: the statistics keep updating after the warm-up",
           "`true`: the normaliser's statistics freeze after the warm-up; `false`: they keep absorbing every generation's "
           "observations (as ARS V2), and with mixing every archived member is re-expressed as the same policy under the new "
           "statistics and its generation's distribution as the pushforward, so reuse stays exact; with `im`/`eim` this needs "
           "`policy.bias=true` (policies.py, \"Observation normalisation\")", "the policy", flag, absent=True),
    RunKey("policy.obs_var_floor", 0.01, "lower bound of each observation coordinate's variance (ARS: 1e-8)",
           "lower bound (> 0) of each observation coordinate's variance in the normaliser: 0.01 (Salimans et al. 2017) "
           "keeps a coordinate that barely moved during the warm-up from being blown up; the ARS presets set 1e-8, ARS's "
           "own (on Hopper 0.01 cost ARS V2-t two thirds of its return: docs/ars.md)", "the policy", number(0.0, False), absent=0.01),
    RunKey("policy.bias", True, "false: no biases, the ES searches the weights only (ARS)",
           "`false`: the policy has no biases and the ES searches its weights only (ARS's linear policy a = M s); saved "
           "policies keep the usual layout with zero biases", "the policy", flag, absent=True),
    RunKey("policy.output", "tanh", "continuous actions: tanh | clip (ARS)",
           "continuous actions: `tanh` (squashed onto the action bounds) or `clip` (the outputs clipped to them: ARS's linear "
           "policy, sb3-contrib's `ARSLinearPolicy`); gymnasium/MuJoCo envs with continuous actions only", "the policy",
           choice(_outputs), absent="tanh"),
    RunKey("evaluator", "local", "local | pool (a generation over all cores) | ray",
           "`local`, `pool` (each generation's episodes over `evaluator_workers` processes), `ray` (Ray actors)", "where episodes run",
           choice(_evaluators), spec=True, absent="local", **_NOT_RESULTS),  # where episodes run never changes their results
    RunKey("evaluator_workers", None, "processes (pool) or actors (ray); null: all cores / CPUs",
           "processes (pool) or actors (ray); `null` = all cores / every CPU of the Ray cluster", "where episodes run",
           optional(integer(1)), **_NOT_RESULTS),
    RunKey("ray_address", None, "evaluator=ray: ray.init address (null: a local Ray)",
           "`evaluator=ray`: `ray.init(address=...)`; `null` = a local Ray, `auto` = this machine's cluster", "where episodes run",
           _ray_address, spec=True, **_NOT_RESULTS),
    RunKey("algo.actor_lr, algo.critic_lr, algo.tau, ...", GROUP, "DDPG settings (conf/algo/ddpg.yaml)",
           "DDPG settings, each documented in `conf/algo/ddpg.yaml`", "DDPG", shown="paper values", es_only=False),
)  # fmt: skip


def _algo_option_keys() -> tuple:
    """``algo.<option>`` of each ES that has options: a field of its ``Params``, documented in the field's metadata
    (``short``, ``doc``); its default in ``imix run`` (:func:`imix_cli.running.config.run_spec.run_default`: conf/algo/<name>.yaml's)."""
    import dataclasses

    from imix_cli.core.registry import ALGORITHM_SPECS

    keys = []
    for algo, spec in ALGORITHM_SPECS.items():
        fields = {f.name: f for f in dataclasses.fields(spec.es_class().Params)} if spec.options else {}
        for option in spec.options:
            f = fields[option]
            shown = yaml_value(f.metadata.get("run_default", f.default))
            keys.append(RunKey(f"algo.{option}", GROUP, f"algo={algo} only: {f.metadata['short']}", f.metadata["doc"], "what to run", shown=shown))
    return tuple(keys)


KEYS = (*KEYS[:2], *_algo_option_keys(), *KEYS[2:])

#: Every key by name.
BY_NAME = {key.name: key for key in KEYS}

# ------------------------------------------------------------------------------- derived lists
#: The top-level keys of a composed config (``policy`` holds the ``policy.*`` keys).
TOP_LEVEL_KEYS = ("algo", "env", *dict.fromkeys(key.name.split(".")[0] for key in KEYS if key.in_yaml))

#: ``policy.*`` defaults: the paper's 8x8 tanh MLP without normalisation, with biases, continuous actions squashed by tanh.
POLICY_DEFAULTS = {key.name.removeprefix("policy."): key.default for key in KEYS if key.name.startswith("policy.")}

#: The keys whose value, when not the paper's (these defaults, section 4.1), names the run folder as ``-key=value,...``
#: (:attr:`imix_cli.running.config.run_spec.RunSpec.overrides_suffix`): sweep points get folders of their own.
PAPER_DEFAULTS = {key.name: key.default for key in KEYS if key.names_folder}

#: Top-level keys that never change a run's results: the rest of config.yaml must match to resume.
NON_IDENTITY_KEYS = tuple(dict.fromkeys(key.name.split(".")[0] for key in KEYS if key.in_yaml and not key.identity))

#: Top-level keys of the evolution strategies only: algo=ddpg ignores them and leaves them out of its config.yaml.
ES_ONLY_KEYS = tuple(dict.fromkeys(key.name.split(".")[0] for key in KEYS if key.in_yaml and key.es_only))


def read_keys(cfg: dict, names) -> dict:
    """``{name: checked value}`` for each key of ``names`` that has a check, in the table's order; ``cfg`` is a
    composed config with the ``policy.*`` keys flat (``"policy.hidden"``). A key ``cfg`` lacks reads as its ``absent``
    value. The first bad value is a ConfigError naming its key."""
    wanted = set(names)
    values = {}
    for key in KEYS:
        if key.name in wanted and key.check is not None:
            values[key.name] = key.check({key.name: cfg.get(key.name, key.absent)}, key.name)
    return values


def key_names() -> tuple:
    """Every key :data:`KEYS` names, one by one (``algo.actor_lr, algo.critic_lr, ...`` gives each it lists)."""
    return tuple(part for key in KEYS for part in key.name.split(", ") if part != "...")


def did_you_mean(key: str, candidates=None) -> str:
    """``"; did you mean 'algo.style'?"`` for a mistyped ``key``: the closest of ``candidates`` (default: the keys of
    :data:`KEYS`) by :func:`difflib.get_close_matches`; ``""`` if none is close. Appended to an unknown key's one line."""
    import difflib

    close = difflib.get_close_matches(key, list(key_names() if candidates is None else candidates), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


# ---------------------------------------------------------------------- the files made from it
ROOT = Path(__file__).resolve().parents[3]
REFERENCE = ROOT / "docs" / "configuration.md"
CONFIG_YAML = ROOT / "conf" / "config.yaml"
_VALUES_START, _VALUES_END = "  - override hydra/hydra_logging: none\n\n", "\n\nhydra:\n"
_HELP_START, _HELP_END = "      Keys:\n", "\n\n      Output:"


def reference_markdown() -> str:
    """``docs/configuration.md``: one table per section."""
    lines = [
        "# Configuration reference",
        "",
        "<!-- generated by `python -m imix_cli.running.config.keys write` from imix_cli/running/config/keys.py: edit that table, not this page -->",
        "",
        "Configs are Hydra YAML files in `conf/` (shipped inside the package). Choose a group option with `group=option`",
        "(`algo=cem`, `env=acrobot`), set a key with `key=value`. Defaults are the paper's setting. From Python, the same",
        "keys are keyword arguments of `imix_cli.run(...)` (see [the library](library.md)).",
        "",
        "Bad input never produces a traceback: an unknown key, group option or bad value gives one line naming it and exit",
        "status 2, before anything is written, for every point of a sweep. Contradictory flags are errors:",
        "`eim=true im_variant=sun2009`, `im_alpha` without `im=true im_variant=sun2009`, `reeval_*` without mixing.",
        "",
        "A value other than the default of a key marked *names the folder* appears in the run folder's name",
        "(`snes-cartpole-eim-popsize=10`), so the points of a sweep get folders of their own; a key marked *any value*",
        "never changes a run's results, so a run may be resumed with another value of it. The `policy.*` keys, the `algo.*`",
        "options and `env.max_steps` name the folder too, in a form of their own (`hidden=16x16`, `algo.style=cemrl`).",
    ]
    for section in SECTIONS:
        lines += ["", f"## {section[0].upper()}{section[1:]}", "", "| key | default | meaning |", "|---|---|---|"]
        for key in KEYS:
            if key.section == section:
                lines.append(f"| `{key.name}` | `{key.shown_default}` | {key.doc.replace('|', '&#124;')}{_roles(key)} |")
    return "\n".join(lines) + "\n"


def _roles(key: RunKey) -> str:
    if key.names_folder:
        return "; *names the folder*" + ("" if key.names_folder == "always" else f" (with `{key.names_folder}`)".replace("`mixing`", "mixing"))
    return "" if key.identity or not key.in_yaml else "; *any value* (resume)"


def help_block() -> str:
    """The ``Keys:`` lines of ``imix run --help`` (indented as the template in conf/config.yaml)."""
    out = []
    for key in KEYS:
        if key.name.startswith(("algo", "env")):
            continue  # the template lists the groups and their keys above
        head = f"        {key.name}={'...' if str(key.default).startswith('${') else key.shown_default}"
        width = max(len(head) + 1, 31)
        body = textwrap.wrap(key.short, 100 - width) or [""]
        out.append(f"{head:<{width}}{body[0]}")
        out += [f"{'':<{width}}{line}" for line in body[1:]]
    return "\n".join(out)


def yaml_values() -> str:
    """The key lines of conf/config.yaml: each key's default and, as its comment, its short doc."""
    out = []
    for key in KEYS:
        if not key.in_yaml:
            continue
        group, _, leaf = key.name.rpartition(".")
        if group and f"{group}:" not in (line.split(" ")[0] for line in out):
            out.append(f"{group + ':':<24}# the {group}.* keys")
        line = f"{'  ' * bool(group)}{leaf}: {yaml_value(key.default)}"
        out.append(f"{line:<23} # {key.short}")
    return "\n".join(out)


def _between(text: str, start: str, end: str, new: str) -> str:
    head = text.index(start) + len(start)
    return text[:head] + new + text[text.index(end, head) :]


def config_yaml_generated(text: str) -> str:
    """conf/config.yaml's ``text`` with its key values and ``--help``'s Keys block made from :data:`KEYS`."""
    return _between(_between(text, _VALUES_START, _VALUES_END, yaml_values()), _HELP_START, _HELP_END, help_block())


def write() -> list[Path]:
    """Regenerate conf/config.yaml's keys, the help block and the reference page; return the files that changed."""
    changed = []
    for path, text in ((REFERENCE, reference_markdown()), (CONFIG_YAML, config_yaml_generated(CONFIG_YAML.read_text()))):
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
            changed.append(path)
    return changed


if __name__ == "__main__":
    if sys.argv[1:] != ["write"]:
        sys.exit("usage: python -m imix_cli.running.config.keys write   (regenerates conf/config.yaml's keys, imix run --help's and docs/configuration.md)")
    for path in write():
        print(f"wrote {path}")
