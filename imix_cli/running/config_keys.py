"""Every ``imix run`` key, its default and what it means: the one table the documentation is made from.

Why one table: a key documented in several places (a README table, the YAML comments, the
``--help`` template, docstrings) drifts. Here each key has one record; from it
``python -m imix_cli.running.config_keys write`` generates the configuration reference of the docs site
(``docs/configuration.md``) and the ``Keys:`` block of ``imix run --help`` (in ``conf/config.yaml``),
and tests/test_config_keys.py checks that both are up to date, that every key ``imix run``
accepts is here, and that the defaults are ``conf/config.yaml``'s. The checks themselves live
with the config (:mod:`imix_cli.running.config_checks`, :mod:`imix_cli.running.es_config`); the library's
parameter records document their fields for the library (:class:`imix_cli.algorithms.base.Params`).
"""

from __future__ import annotations

import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Key:
    name: str  # as on the command line (policy.hidden, env.id, ...)
    default: str  # as shown (the YAML value, or what a null means)
    short: str  # one line for `imix run --help`
    doc: str  # the reference's text (Markdown)
    section: str


#: The sections of the reference, in order.
SECTIONS = ("what to run", "mixing", "the evolution strategy", "the policy", "where episodes run", "run and output", "DDPG")

KEYS = (
    # ---------------------------------------------------------------- what to run
    Key("algo", "snes", "openes | snes | cem | cmaes | ars | ddpg",
        "`openes`, `snes`, `cem`, `cmaes`, `ars` (Augmented Random Search: docs/ars.md), `ddpg` (stable-baselines3; "
        "continuous-action envs only, the `ddpg` extra)", "what to run"),
    Key("algo.generations", "1000 / 400", "the paper's generation count of the algorithm",
        "the paper's generation count of the algorithm (openes, snes: 1000; cem, cmaes: 400); the default of `generations`", "what to run"),
    Key("algo.style", "imix", "algo=cem only: imix | cemrl",
        "`algo=cem` only: `imix` (maximum-likelihood variance + decaying extra variance) or `cemrl` (the authors' sepCEM: log "
        "weights, variance about the old mean scaled by 1/K)", "what to run"),
    Key("algo.step_size_control", "auto", "algo=cmaes only: csa | tpa | auto (tpa with im/eim, csa without)",
        "`algo=cmaes` only: `csa` (pycma's cumulative step-size adaptation), `tpa` (two-point adaptation: two extra "
        "fresh episodes per generation along the last move of the mean; its signal does not come from reused members), "
        "`auto` (`tpa` with `im`/`eim`, `csa` without); docs/research/bias.md", "what to run"),
    Key("algo.top", "null", "algo=ars only: b, the best directions a step uses (null: all)",
        "`algo=ars` only: b, the number of best directions a step uses (ARS V1-t/V2-t); `null` = all N = popsize/2", "what to run"),
    Key("algo.alive_bonus_offset", "0.0", "algo=ars only: added to each step's reward in training",
        "`algo=ars` only: added to every step's reward during training (ARS's shift; `-1` cancels Hopper's and Walker2d's survival "
        "bonus, as `+ars=hopper` does); the CSV's population columns hold these training returns, `mean_policy_score` the env's "
        "own", "what to run"),
    Key("env", "cartpole", "cartpole | acrobot | continuous_cartpole[_hard] | MuJoCo | gym",
        "`cartpole` (CartPole-v0 semantics, 200 steps), `acrobot` (Acrobot-v1 dynamics, capped at 200 steps as in the paper), "
        "`continuous_cartpole`, `continuous_cartpole_hard` (paper section 4.3), `swimmer`, `hopper`, `halfcheetah`, `walker2d`, "
        "`ant` (MuJoCo v5, the `mujoco` extra), `gym` (any gymnasium id)", "what to run"),
    Key("env.id", "per env", "gymnasium id (env=gym: any registered id)",
        "gymnasium id; with `env=gym`, e.g. `env.id=CartPole-v1`, any registered id runs through the generic (slower) path. "
        "Giving a built-in env another id (`env=cartpole env.id=CartPole-v1`) keeps the built-in's `env.max_steps`, and says so "
        "in one line; `env=gym env.id=...` takes the id's own time limit", "what to run"),
    Key("env.max_steps", "per env", "episode cap (null: the environment's own limit)",
        "episode cap; `null` = the environment's own limit", "what to run"),
    Key("seeds", "25", "runs seeds 0..seeds-1", "runs seeds `0 … seeds-1` (at most 100,000)", "what to run"),
    Key("generations", "${algo.generations}", "generations per seed (1000 openes/snes, 400 cem/cmaes)",
        "generations per seed", "what to run"),
    # ---------------------------------------------------------------- mixing
    Key("im", "false", "importance mixing with the previous generation",
        "importance mixing with the previous generation (variant `im_variant`)", "mixing"),
    Key("eim", "false", "extended importance mixing over eim_generations generations",
        "multi-generation mixing over `eim_generations` generations (variant `eim_variant`; implies mixing)", "mixing"),
    Key("im_variant", "paper", "paper (Algorithm 2) | sun2009 | conditional, with im=true",
        "with `im=true`: `paper` (Algorithm 2), `sun2009` (Sun et al. 2009) or `conditional` (Sun et al.'s rule with each "
        "member taken given the ES's move it took part in: the research notes, \"Reused returns and the search\")", "mixing"),
    Key("eim_variant", "exact", "exact (unbiased over chains) | conditional | paper (Algorithm 3), with eim=true",
        "with `eim=true`: `exact` (imix's rule, unbiased over chains of generations), `conditional` (each member of the "
        "previous generation taken given the ES's move: unbiased inside the loop under neutral fitness, worse for CMA-ES "
        "on CartPole) or `paper` (the paper's Algorithm 3, biased over chains: for reproduction). `exact` and `conditional` "
        "are the library's variants of the same names (`imix_cli.mixing.VARIANT_SPECS`); `paper` is its `eim_paper`, "
        "because its `paper` is Algorithm 2 (`im_variant=paper`)", "mixing"),
    Key("im_alpha", "0.0", "sun2009's minimal refresh rate in [0, 1)", "`sun2009`'s minimal refresh rate α ∈ [0, 1)", "mixing"),
    Key("eim_generations", "3", "K, archived generations eim reuses from", "K, the archived generations `eim` reuses from", "mixing"),
    Key("min_fresh", "1", "with mixing: fresh members per generation, at least (no fixed point)",
        "with `im=true` or `eim=true`: at least this many members of every generation are fresh, in slots drawn at random "
        "independently of the members, so the generation keeps its law (`0`: the rules alone). Without it a distribution "
        "that stops moving reuses every member and an ES whose update depends only on its members and their returns (CEM, "
        "CMA-ES) repeats its update: a fixed point (the research notes, \"Reused returns and the search\")", "mixing"),
    Key("reeval_age", "null", "re-evaluate reused members whose return is older (generations)",
        "re-evaluate a reused member whose stored return is more than this many generations old (`null`: never; a remedy "
        "for the selection bias of stored returns, see the research notes)", "mixing"),
    Key("reeval_prob", "0.0", "re-evaluate each reused member with this probability",
        "re-evaluate each reused member with this probability", "mixing"),
    Key("reeval_count", "0", "re-evaluate this many reused members per generation; calibrate the others on them",
        "re-evaluate this many reused members (at random) every generation, and tell the ES the other stored returns "
        "calibrated on those (stored, fresh) pairs: fresh ≈ α + β·stored, β ∈ [0, 1] (the research notes, \"Reused returns "
        "and the search\")", "mixing"),
    # ---------------------------------------------------------------- the evolution strategy
    Key("popsize", "50", "population size N (>= 2; >= 3 for cmaes)", "population size N (≥ 2; ≥ 3 for CMA-ES)", "the evolution strategy"),
    Key("sigma", "0.25", "initial standard deviation (> 0)", "initial standard deviation; initial covariance σ²I (> 0)", "the evolution strategy"),
    Key("lr", "0.01", "Adam learning rate of openes/snes (> 0)",
        "Adam learning rate of OpenES and SNES (> 0; β1 = 0.99, β2 = 0.999 as in the paper)", "the evolution strategy"),
    Key("weight_decay", "0.05", "weight-decay coefficient (>= 0)", "weight-decay coefficient w (≥ 0)", "the evolution strategy"),
    Key("weight_decay_form", "estool", "estool: ranks - w mean(theta^2) | paper: fitness - w|theta|^2",
        "`estool`: centred ranks − w·mean(θ²) (the authors' code, which produced the paper's curves); `paper`: fitness − "
        "w‖θ‖² before ranking (the paper's text)", "the evolution strategy"),
    # ---------------------------------------------------------------- the policy
    Key("policy.hidden", "[8,8]", "tanh hidden layer sizes ([] = linear policy)", "tanh hidden layer sizes; `[]` = linear policy", "the policy"),
    Key("policy.obs_norm", "false", "observation normalisation (gymnasium envs), frozen after the warm-up",
        "normalise observations (gymnasium envs), statistics frozen after the warm-up (honest reuse)", "the policy"),
    Key("policy.obs_norm_warmup", "5", "warm-up generations, without mixing, that gather the statistics",
        "generations that gather the statistics, without mixing, before they freeze", "the policy"),
    Key("policy.obs_var_floor", "0.01", "lower bound of each observation coordinate's variance (ARS: 1e-8)",
        "lower bound (> 0) of each observation coordinate's variance in the normaliser: 0.01 (Salimans et al. 2017) "
        "keeps a coordinate that barely moved during the warm-up from being blown up; the ARS presets set 1e-8, ARS's "
        "own (on Hopper 0.01 cost ARS V2-t two thirds of its return: docs/ars.md)", "the policy"),
    Key("policy.bias", "true", "false: no biases, the ES searches the weights only (ARS)",
        "`false`: the policy has no biases and the ES searches its weights only (ARS's linear policy a = M s); saved "
        "policies keep the usual layout with zero biases", "the policy"),
    Key("policy.output", "tanh", "continuous actions: tanh | clip (ARS)",
        "continuous actions: `tanh` (squashed onto the action bounds) or `clip` (the outputs clipped to them: ARS's linear "
        "policy, sb3-contrib's `ARSLinearPolicy`); gymnasium/MuJoCo envs with continuous actions only", "the policy"),
    # ---------------------------------------------------------------- where episodes run
    Key("evaluator", "local", "local | pool (a generation over all cores) | ray",
        "`local`, `pool` (each generation's episodes over `evaluator_workers` processes), `ray` (Ray actors)", "where episodes run"),
    Key("evaluator_workers", "null", "processes (pool) or actors (ray); null: all cores / CPUs",
        "processes (pool) or actors (ray); `null` = all cores / every CPU of the Ray cluster", "where episodes run"),
    Key("ray_address", "null", "evaluator=ray: ray.init address (null: a local Ray)",
        "`evaluator=ray`: `ray.init(address=...)`; `null` = a local Ray, `auto` = this machine's cluster", "where episodes run"),
    Key("workers", "null", "processes for the seeds (null: all cores)",
        "processes for the seeds; `null` = all cores. Results do not depend on it", "where episodes run"),
    # ---------------------------------------------------------------- run and output
    Key("checkpoint_every", "50", "generations between checkpoints (0: none)",
        "save each seed's state every N generations (0 = never); a killed run resumes there", "run and output"),
    Key("checkpoint_seconds", "30", "... and at least this many seconds apart (0: every time)",
        "a periodic checkpoint falls due every `checkpoint_every` generations once at least this many seconds of the seed's "
        "wall time have passed since its last one (0 = at every `checkpoint_every`). A killed run loses at most about this "
        "long, plus `checkpoint_every` generations, per seed; a run of cheap generations (the main job: ~0.2 ms a "
        "generation) no longer spends a fifth of its time writing checkpoints. A seed's final state is always saved",
        "run and output"),
    Key("eval_mean_every", "10", "measure the distribution mean's return every N generations (0: never)",
        "every N generations, measure the return of the distribution mean θ (the policy one deploys) on fresh episodes: CSV "
        "`mean_policy_score`, the θ column of the summary, dots in the convergence figures (0 = never)", "run and output"),
    Key("eval_mean_episodes", "5", "... on this many fresh episodes (not counted as evaluations)",
        "episodes per such measurement; counted in `mean_policy_episodes`, never in `evaluations` or `env_steps`", "run and output"),
    Key("progress", "true", "progress bar", "progress bar", "run and output"),
    Key("logger", "none", "none | tensorboard | mlflow | wandb: the CSV rows also to a tracker",
        "`none`, `tensorboard`, `mlflow`, `wandb`: each generation's CSV row also goes to that tracker (the extra of the same "
        "name); the CSV stays the record. See the getting-started guide, \"Tracking\"", "run and output"),
    Key("results_dir", "results", "output root", "output root", "run and output"),
    Key("experiment", "default", "sub-folder of results_dir", "sub-folder of `results_dir`", "run and output"),
    # ---------------------------------------------------------------- DDPG
    Key("total_steps", "null", "algo=ddpg only: environment steps per seed",
        "`algo=ddpg` only: environment steps per seed; `null` = 200 000 on `continuous_cartpole`, 1 000 000 on "
        "`continuous_cartpole_hard` (the paper's). `algo=ddpg` ignores the ES keys", "DDPG"),
    Key("algo.actor_lr, algo.critic_lr, algo.tau, ...", "paper values", "DDPG settings (conf/algo/ddpg.yaml)",
        "DDPG settings, each documented in `conf/algo/ddpg.yaml`", "DDPG"),
)  # fmt: skip


def key_names() -> tuple:
    """Every key :data:`KEYS` names, one by one (``algo.actor_lr, algo.critic_lr, ...`` gives each it lists)."""
    return tuple(part for key in KEYS for part in key.name.split(", ") if part != "...")


def did_you_mean(key: str, candidates=None) -> str:
    """``"; did you mean 'algo.style'?"`` for a mistyped ``key``: the closest of ``candidates`` (default: the keys of
    :data:`KEYS`) by :func:`difflib.get_close_matches`; ``""`` if none is close. Appended to an unknown key's one line."""
    import difflib

    close = difflib.get_close_matches(key, list(key_names() if candidates is None else candidates), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "docs" / "configuration.md"
CONFIG_YAML = ROOT / "conf" / "config.yaml"
_HELP_START, _HELP_END = "      Keys:\n", "\n\n      Output:"


def reference_markdown() -> str:
    """``docs/configuration.md``: one table per section."""
    lines = [
        "# Configuration reference",
        "",
        "<!-- generated by `python -m imix_cli.running.config_keys write` from imix_cli/running/config_keys.py: edit that table, not this page -->",
        "",
        "Configs are Hydra YAML files in `conf/` (shipped inside the package). Choose a group option with `group=option`",
        "(`algo=cem`, `env=acrobot`), set a key with `key=value`. Defaults are the paper's setting. From Python, the same",
        "keys are keyword arguments of `imix_cli.run(...)` (see [the library](library.md)).",
        "",
        "Bad input never produces a traceback: an unknown key, group option or bad value gives one line naming it and exit",
        "status 2, before anything is written, for every point of a sweep. Contradictory flags are errors:",
        "`eim=true im_variant=sun2009`, `im_alpha` without `im=true im_variant=sun2009`, `reeval_*` without mixing.",
    ]
    for section in SECTIONS:
        lines += ["", f"## {section[0].upper()}{section[1:]}", "", "| key | default | meaning |", "|---|---|---|"]
        for key in KEYS:
            if key.section == section:
                lines.append(f"| `{key.name}` | `{key.default}` | {key.doc.replace('|', '&#124;')} |")
    return "\n".join(lines) + "\n"


def help_block() -> str:
    """The ``Keys:`` lines of ``imix run --help`` (indented as the template in conf/config.yaml)."""
    out = []
    for key in KEYS:
        if key.name.startswith(("algo", "env")):
            continue  # the template lists the groups and their keys above
        head = f"        {key.name}={'...' if key.default.startswith('${') else key.default}"
        width = max(len(head) + 1, 31)
        body = textwrap.wrap(key.short, 100 - width) or [""]
        out.append(f"{head:<{width}}{body[0]}")
        out += [f"{'':<{width}}{line}" for line in body[1:]]
    return "\n".join(out)


def config_yaml_with_help(text: str) -> str:
    start = text.index(_HELP_START) + len(_HELP_START)
    return text[:start] + help_block() + text[text.index(_HELP_END) :]


def write() -> list[Path]:
    """Regenerate the reference page and the help block; return the files that changed."""
    changed = []
    for path, text in ((REFERENCE, reference_markdown()), (CONFIG_YAML, config_yaml_with_help(CONFIG_YAML.read_text()))):
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
            changed.append(path)
    return changed


if __name__ == "__main__":
    if sys.argv[1:] != ["write"]:
        sys.exit("usage: python -m imix_cli.running.config_keys write   (regenerates docs/configuration.md and imix run --help's keys)")
    for path in write():
        print(f"wrote {path}")
