"""One record per algorithm, per environment and per mixing scheme: what config, runner, plotting and bench read.

Every name imix knows -- ``algo=``, ``env=``, ``im``/``eim`` -- is declared here once, with what
the rest of the code needs to know about it (display label, the paper's generation count, the
plot threshold, the batched evaluator, ...); the mixing variants (``im_variant``/``eim_variant``) are
the :class:`imix_cli.core.mixing.Variant` objects of :data:`imix_cli.core.mixing.VARIANT_SPECS`, each naming the
scheme that offers it and its value there. Nothing else keeps a list of names:
:mod:`imix_cli.running.config.compose` validates against these records, :mod:`imix_cli.core.algorithms` builds an
ES from :data:`ALGORITHM_SPECS`, :mod:`imix_cli.core.evaluation` sizes a built-in's evaluator from
:data:`ENV_SPECS`, and the figures and tables take their labels from here.

This module imports nothing heavy (no numpy, no gymnasium): each ES class is reached through a
small loader function below (``_openes``, ...) that imports its module when called, so a reader
(or an IDE) follows the import from here. The environments' records are data only: the evaluation
layer, which reads them, names each built-in's compiled evaluator
(:data:`imix_cli.core.evaluation.BUILTIN_EVALUATORS`), so this module never imports it.

Adding an evolution strategy: one module under ``imix_cli/core/algorithms/`` (a subclass of
:class:`~imix_cli.core.algorithms.base.EvolutionStrategy`), one :class:`AlgorithmSpec` below and
``conf/algo/<name>.yaml``. Adding an environment with a batched evaluator: the evaluator and its
entry in :data:`imix_cli.core.evaluation.BUILTIN_EVALUATORS`, one :class:`EnvSpec` below (``builtin=True``)
and ``conf/env/<name>.yaml``; a gymnasium id needs no entry at all
(``env=gym env.id=...``), an entry only gives it a config name, a label and a threshold.

The paper's hyper-parameters shared by every ES are the defaults of
:class:`imix_cli.core.algorithms.base.Params` (``conf/config.yaml`` repeats them for Hydra;
``tests/test_registry.py`` checks that the two agree).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field


# ------------------------------------------------------------------------------ algorithms
# The ES classes, each imported when its loader is called (the classes load numpy and numba).
def _openes() -> type:
    from imix_cli.core.algorithms.openes import OpenES

    return OpenES


def _snes() -> type:
    from imix_cli.core.algorithms.snes import SNES

    return SNES


def _cem() -> type:
    from imix_cli.core.algorithms.cem import CEM

    return CEM


def _cmaes() -> type:
    from imix_cli.core.algorithms.cmaes import CMAES

    return CMAES


def _ars() -> type:
    from imix_cli.core.algorithms.ars import ARS

    return ARS


@dataclass(frozen=True)
class AlgorithmSpec:
    """An algorithm ``algo=<name>`` can run.

    Attributes
    ----------
    name : str
        The config name (``algo=<name>``, the CSVs' ``algo`` column, run folder names).
    label : str
        How figures and tables print it.
    color : str
        Its colour in every figure (Okabe-Ito, colour-blind safe).
    load_class : callable or None
        ``load_class()`` returns the :class:`~imix_cli.core.algorithms.base.EvolutionStrategy` class
        (importing its module); None for an algorithm that is not an ES (DDPG: no generations, no mixing).
    generations : int or None
        The paper's generation count (``conf/algo/<name>.yaml`` ``generations``).
    uses_lr : bool
        Whether the top-level ``lr`` (Adam's learning rate) reaches the algorithm; the
        figures print it only then.
    options : tuple of str
        The ``algo.<key>`` settings of ``conf/algo/<name>.yaml`` that are fields of the ES's
        ``Params`` (defaults, choices and checks come from there); a value other than the
        default names the run folder (``-algo.<key>=<value>``).
    """

    name: str
    label: str
    color: str
    load_class: Callable[[], type] | None = field(default=None, compare=False)
    generations: int | None = None
    uses_lr: bool = False
    options: tuple[str, ...] = ()

    @property
    def is_es(self) -> bool:
        """An evolution strategy: runs generations, can mix, one CSV row per generation."""
        return self.load_class is not None

    def es_class(self) -> type:
        """The ES class (imported now)."""
        if self.load_class is None:
            raise ValueError(f"algo={self.name} is not an evolution strategy")
        return self.load_class()


#: Okabe & Ito (2008), colour-blind safe; ``imix_cli.plotting.figures`` uses the spare ones.
OKABE_ITO = {
    "black": "#000000",
    "orange": "#E69F00",
    "sky_blue": "#56B4E9",
    "bluish_green": "#009E73",
    "yellow": "#F0E442",
    "blue": "#0072B2",
    "vermillion": "#D55E00",
    "reddish_purple": "#CC79A7",
}

#: Every algorithm, in the order figures, tables and ``imix status`` list them.
ALGORITHM_SPECS: dict[str, AlgorithmSpec] = {
    spec.name: spec
    for spec in (
        AlgorithmSpec("openes", "OpenES", OKABE_ITO["blue"], _openes, 1000, uses_lr=True),
        AlgorithmSpec("snes", "SNES", OKABE_ITO["vermillion"], _snes, 1000, uses_lr=True),
        AlgorithmSpec("cem", "CEM", OKABE_ITO["bluish_green"], _cem, 400, options=("style",)),
        AlgorithmSpec("cmaes", "CMA-ES", OKABE_ITO["reddish_purple"], _cmaes, 400, options=("step_size_control",)),
        # Augmented Random Search (Mania et al. 2018): mirrored pairs, popsize = 2 x directions, lr = its
        # step size alpha, sigma = its noise nu; per-env presets of its paper: +ars=<env> (conf/ars/)
        AlgorithmSpec("ars", "ARS", OKABE_ITO["orange"], _ars, 1000, uses_lr=True, options=("top", "alive_bonus_offset")),
        # the deep-RL baseline of section 4.3 (stable-baselines3): one CSV row per episode
        AlgorithmSpec("ddpg", "DDPG", OKABE_ITO["black"]),
    )
}

#: ``algo=`` choices, the evolution strategies among them, and the others (no generations, no
#: mixing, one CSV row per episode: only in the DDPG figure).
ALGO_NAMES = tuple(ALGORITHM_SPECS)
ES_NAMES = tuple(name for name, spec in ALGORITHM_SPECS.items() if spec.is_es)
NON_ES_NAMES = frozenset(name for name, spec in ALGORITHM_SPECS.items() if not spec.is_es)
#: The paper's four evolution strategies (section 2.1): the main grid (`make reproduce`, ``imix bench grid``).
PAPER_ES_NAMES = ("openes", "snes", "cem", "cmaes")


def algo_label(name: str) -> str:
    """The display label of ``algo=<name>`` (the name itself if unknown)."""
    spec = ALGORITHM_SPECS.get(name)
    return spec.label if spec else name


# ---------------------------------------------------------------------------- environments
@dataclass(frozen=True)
class EnvSpec:
    """An environment with a config name (``env=<name>``, ``conf/env/<name>.yaml``).

    Attributes
    ----------
    name : str
        The config name.
    gym_id : str
        The gymnasium id it is (or, for a built-in, that its evaluator reproduces).
    label : str
        How figures and tables print a built-in (runs of any other preset are named, and printed, by the
        gymnasium id).
    max_steps : int
        The default episode cap (``env.max_steps`` of its config).
    threshold : float or None
        The return that counts as solved in ``imix plot``'s to-threshold tables and figures (for a preset that is
        not a built-in, under its gymnasium id, the name its runs carry: :func:`plot_thresholds`).
    continuous : bool
        Continuous (Box) actions; the built-ins algo=ddpg accepts.
    builtin : bool
        A built-in: its batched (compiled) evaluator is the one :data:`imix_cli.core.evaluation.BUILTIN_EVALUATORS`
        holds under its name; False: gymnasium's own env through the generic evaluator (MuJoCo), and runs
        are named and labelled by the gymnasium id.
    policy_dims : (int, int) or None
        A built-in's observation size and policy output size (known without making the env).
    step_reward : (float, float) or None
        A built-in's smallest and largest reward of one step: its returns lie within
        ``max_steps`` times these (what a checkpoint read back is checked against); None: not known.
    mujoco : bool
        A MuJoCo locomotion env (the ``mujoco`` extra): in :data:`MUJOCO_ENVS`, ``imix bench mujoco``
        and ``imix plot mujoco``'s thresholds. A preset of another gymnasium id leaves it False.
    """

    name: str
    gym_id: str
    label: str
    max_steps: int
    threshold: float | None = None
    continuous: bool = False
    builtin: bool = False
    policy_dims: tuple[int, int] | None = None
    step_reward: tuple[float, float] | None = None
    mujoco: bool = False


_CARTPOLE_THRESHOLD = 195.0  # CartPole-v0's reward threshold (paper section 4.3: also the continuous ones')
_MUJOCO_STEPS = 1000  # the v5 envs' own time limit

ENV_SPECS: dict[str, EnvSpec] = {
    spec.name: spec
    for spec in (
        # CartPole-v0 semantics: CartPole-v1 dynamics (compiled), 200 steps, threshold 195
        EnvSpec("cartpole", "CartPole-v0", "CartPole", 200, _CARTPOLE_THRESHOLD,
                builtin=True, policy_dims=(4, 2), step_reward=(0.0, 1.0)),
        # Acrobot-v1 dynamics capped at 200 steps as in the paper (Acrobot-v1 itself allows 500)
        EnvSpec("acrobot", "Acrobot-v1", "Acrobot", 200, -100.0,
                builtin=True, policy_dims=(6, 3), step_reward=(-1.0, 0.0)),
        EnvSpec("continuous_cartpole", "imix/ContinuousCartPole-v0", "ContinuousCartPole", 200, _CARTPOLE_THRESHOLD,
                continuous=True, builtin=True, policy_dims=(4, 1), step_reward=(0.0, 1.0)),
        # the sparse (Hard) variant: its episode's sum is the same return as the dense one's
        EnvSpec("continuous_cartpole_hard", "imix/ContinuousCartPoleHard-v0", "ContinuousCartPoleHard", 200, _CARTPOLE_THRESHOLD,
                continuous=True, builtin=True, policy_dims=(4, 1), step_reward=(0.0, 1.0)),
        # MuJoCo v5 (the mujoco extra), thresholds: a clear sign of learning within the study's budget
        EnvSpec("swimmer", "Swimmer-v5", "Swimmer", _MUJOCO_STEPS, 50.0, continuous=True, mujoco=True),
        EnvSpec("hopper", "Hopper-v5", "Hopper", _MUJOCO_STEPS, 500.0, continuous=True, mujoco=True),
        EnvSpec("halfcheetah", "HalfCheetah-v5", "HalfCheetah", _MUJOCO_STEPS, 500.0, continuous=True, mujoco=True),
        EnvSpec("walker2d", "Walker2d-v5", "Walker2d", _MUJOCO_STEPS, 500.0, continuous=True, mujoco=True),
        EnvSpec("ant", "Ant-v5", "Ant", _MUJOCO_STEPS, 500.0, continuous=True, mujoco=True),
    )
}  # fmt: skip

#: The built-ins (batched evaluators): config name -> the gymnasium id each reproduces.
BUILTIN_ENVS = {name: spec.gym_id for name, spec in ENV_SPECS.items() if spec.builtin}
#: The built-ins with continuous (Box) actions, the only built-ins algo=ddpg accepts.
CONTINUOUS_BUILTIN_ENVS = tuple(name for name in BUILTIN_ENVS if ENV_SPECS[name].continuous)
#: The environments of the paper's main comparison (section 4.2: Figs 5-8, Table 1).
MAIN_GRID_ENVS = ("cartpole", "acrobot")
#: The MuJoCo configs: config name -> gymnasium id.
MUJOCO_ENVS = {name: spec.gym_id for name, spec in ENV_SPECS.items() if spec.mujoco}


def env_return_bounds(env_name: str, max_steps: int | None = None, alive_bonus_offset: float = 0.0) -> tuple[float, float]:
    """The returns an episode of ``env_name`` (a config name, or a gymnasium id) can have: a built-in's episode cap
    (``max_steps``, else its own) times its step rewards, each step's reward moved by ``alive_bonus_offset`` (ARS's
    training returns; 0 for the env's own return); ``(-inf, inf)`` for an env whose rewards imix does not know.
    The one source of the bounds a checkpoint's and a seed CSV's scores are checked against."""
    env = ENV_SPECS.get(env_name)
    cap = max_steps or (env.max_steps if env else None)
    if env is None or env.step_reward is None or cap is None:
        return -math.inf, math.inf
    return (env.step_reward[0] + min(alive_bonus_offset, 0.0)) * cap, (env.step_reward[1] + max(alive_bonus_offset, 0.0)) * cap


def env_label(name: str) -> str:
    """The display label of a built-in env (any other name, e.g. a gymnasium id, as is)."""
    spec = ENV_SPECS.get(name)
    return spec.label if spec and spec.builtin else name


def plot_thresholds() -> dict:
    """``imix plot``'s default thresholds, by the env name its runs carry: a built-in's config name, any other
    preset's gymnasium id (such runs are named by the id: ``env=mountaincar`` makes ``MountainCar-v0`` runs)."""
    by_id = {spec.gym_id: spec.threshold for spec in ENV_SPECS.values() if not spec.builtin and spec.threshold is not None}
    return {**by_id, **{name: ENV_SPECS[name].threshold for name in BUILTIN_ENVS}}


def mujoco_thresholds() -> dict:
    """``imix mujoco``'s default thresholds: gymnasium id -> threshold (runs are named by id)."""
    return {spec.gym_id: spec.threshold for spec in ENV_SPECS.values() if spec.mujoco}


# ---------------------------------------------------------------------------------- mixing
@dataclass(frozen=True)
class MixingSpec:
    """A mixing scheme (the CSVs' and run folders' ``mixing``: none | im | eim).

    Its variants (``im_variant=``/``eim_variant=``) are the :class:`imix_cli.core.mixing.Variant` objects that
    name the scheme in their ``selected_by`` (:func:`imix_cli.core.mixing.config_variants`).

    Attributes
    ----------
    name : str
        The name in CSVs and run folder names (and the config key that turns it on: ``im=true``).
    title : str
        A figure panel's title ("with IM").
    short : str
        Its suffix to an algorithm's label in legends ("OpenES + IM"), "" for none.
    label : str
        Its table cell.
    """

    name: str
    title: str
    short: str
    label: str


MIXING_SPECS: dict[str, MixingSpec] = {
    spec.name: spec
    for spec in (
        MixingSpec("none", "without mixing", "", "none"),
        MixingSpec("im", "with IM", " + IM", "IM"),
        MixingSpec("eim", "with EIM", " + EIM", "EIM"),
    )
}


def mixing_title(name: str) -> str:
    """A figure panel's title for ``mixing=<name>`` ("with IM")."""
    spec = MIXING_SPECS.get(name)
    return spec.title if spec else f"with {name}"


def mixing_suffix(name: str, unknown: str | None = None) -> str:
    """The suffix of an algorithm's label for ``mixing=<name>`` (" + IM"); ``unknown`` (default
    " + <name>") for a name not registered."""
    spec = MIXING_SPECS.get(name)
    if spec:
        return spec.short
    return f" + {name}" if unknown is None else unknown


def mixing_label(name: str) -> str:
    """The table cell of ``mixing=<name>`` ("IM")."""
    spec = MIXING_SPECS.get(name)
    return spec.label if spec else name


#: The ``mixing`` values, in the order figures and tables list them.
MIXING_NAMES = tuple(MIXING_SPECS)
