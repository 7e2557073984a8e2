"""The registry (imix_cli/core/registry.py) and the ES parameter records (algorithms/base.py Params).

Hydra reads conf/*.yaml, so the YAML files repeat a few registry values (generation counts,
gymnasium ids, episode caps, the paper's hyper-parameters); these tests are what keeps the
two in step. Everything else reads the registry itself.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

import imix_cli.core.algorithms.base as base
from imix_cli.core.algorithms import ALGORITHMS, CEM, MIRRORED_ALGORITHMS, SNES, EvolutionStrategy, OpenES, Params, make_es
from imix_cli.core.evaluation import make_evaluator
from imix_cli.core.registry import ALGORITHM_SPECS, BUILTIN_ENVS, ENV_SPECS, ES_NAMES, MIXING_SPECS
from imix_cli.running.config.compose import PAPER_DEFAULTS, config_dir


def conf(*parts):
    return yaml.safe_load((Path(config_dir()).joinpath(*parts)).read_text())


# ------------------------------------------------------------------------ conf/ and the registry
def test_the_registry_and_the_trainers_hold_objects_not_names():
    """An ES class, a built-in's evaluator and a trainer's functions are reached through function objects a
    reader can follow, not "module:attribute" strings given to import_module (only the public API's lazy names,
    imix_cli/__init__.py, and the user's own env module, core/envs/ids.py, are imported by name)."""
    from imix_cli.running.trainers import DDPG, EVOLUTION_STRATEGY

    package = Path(__file__).resolve().parents[1] / "imix_cli"
    by_name = sorted(str(p.relative_to(package)) for p in package.rglob("*.py") if "import_module" in p.read_text())
    assert by_name == ["__init__.py", "core/envs/ids.py"]
    for name in ES_NAMES:
        assert ALGORITHM_SPECS[name].es_class() is {**ALGORITHMS, **MIRRORED_ALGORITHMS}[name]
        assert issubclass(ALGORITHM_SPECS[name].es_class(), EvolutionStrategy) and ALGORITHM_SPECS[name].es_class().name == name
    for trainer in (EVOLUTION_STRATEGY, DDPG):
        assert callable(trainer.run_seeds) and callable(trainer.needs_running)
    from imix_cli.core.evaluation import BUILTIN_EVALUATORS

    assert sorted(BUILTIN_EVALUATORS) == sorted(BUILTIN_ENVS)  # each built-in has its evaluator, and no evaluator names an unknown env
    for name in BUILTIN_ENVS:
        assert type(BUILTIN_EVALUATORS[name](None)).__name__.endswith("Evaluator")


def test_conf_algo_options_are_the_registered_algorithms_with_their_generation_counts():
    assert sorted(p.stem for p in (Path(config_dir()) / "algo").glob("*.yaml")) == sorted(ALGORITHM_SPECS)
    for name, spec in ALGORITHM_SPECS.items():
        shipped = conf("algo", f"{name}.yaml")
        assert shipped["name"] == name
        assert shipped["generations"] == spec.generations, name


def test_conf_env_options_are_the_registered_envs_plus_gym():
    assert sorted(p.stem for p in (Path(config_dir()) / "env").glob("*.yaml")) == sorted([*ENV_SPECS, "gym"])
    for name, spec in ENV_SPECS.items():
        shipped = conf("env", f"{name}.yaml")
        assert (shipped["name"], shipped["id"], shipped["max_steps"]) == (name, spec.gym_id, spec.max_steps), name


def test_conf_config_yaml_holds_the_paper_defaults_of_params_and_mixing():
    shipped = conf("config.yaml")
    assert {k: shipped[k] for k in PAPER_DEFAULTS} == PAPER_DEFAULTS
    assert {k: PAPER_DEFAULTS[k] for k in ("popsize", "sigma", "lr", "weight_decay", "weight_decay_form")} == {
        f.name: f.default for f in dataclasses.fields(Params) if f.name != "fitness_shaping"
    }


@pytest.mark.filterwarnings("ignore:.*CartPole-v0 is out of date")
def test_builtin_envs_match_their_evaluators_and_gymnasium():
    import imix_cli.core.envs  # noqa: F401  (registers imix/ ids)

    for name, gym_id in BUILTIN_ENVS.items():
        spec = ENV_SPECS[name]
        ev = make_evaluator(name)
        assert (ev.env_name, ev.max_steps, (ev.obs_dim, ev.out_dim), ev.discrete) == (name, spec.max_steps, spec.policy_dims, not spec.continuous)
        env = gym.make(gym_id)
        try:
            out = env.action_space.n if spec.policy_dims[1] > 1 else env.action_space.shape[0]
            assert (env.observation_space.shape[0], out) == spec.policy_dims, name
            assert isinstance(env.action_space, gym.spaces.Box) == spec.continuous, name
        finally:
            env.close()


def test_the_config_selects_variants_by_what_the_variant_objects_say():
    """im_variant/eim_variant -> variant comes from the Variant objects alone (selected_by, config_name): each
    value is the variant's own name but eim_variant=paper (Algorithm 3, "eim_paper"); every variant is offered."""
    from imix_cli.core.mixing import VARIANT_SPECS, VARIANTS, config_variants
    from imix_cli.running.config.compose import validate_overrides

    assert VARIANTS == ("paper", "sun2009", "exact", "conditional", "eim_paper")
    assert list(MIXING_SPECS) == ["none", "im", "eim"]
    choices = {scheme: {value: v.name for value, v in config_variants(scheme).items()} for scheme in ("im", "eim")}
    assert choices == {
        "im": {"paper": "paper", "sun2009": "sun2009", "conditional": "conditional"},
        "eim": {"exact": "exact", "conditional": "conditional", "paper": "eim_paper", "weighted": "weighted"},
    }
    assert {v.name for c in ("im", "eim") for v in config_variants(c).values()} == set(VARIANT_SPECS)
    assert all(set(v.selected_by) <= set(MIXING_SPECS) - {"none"} for v in VARIANT_SPECS.values())
    assert (PAPER_DEFAULTS["im_variant"], PAPER_DEFAULTS["eim_variant"]) == ("paper", "exact")
    for scheme, table in choices.items():
        for value, name in table.items():
            (spec,) = validate_overrides([f"{scheme}=true", f"{scheme}_variant={value}"])
            assert (spec.mixing, spec.variant) == (scheme, name)
            suffix = "" if value == PAPER_DEFAULTS[f"{scheme}_variant"] else f"-{scheme}_variant={value}"
            assert spec.run_name == f"snes-cartpole-{scheme}{suffix}"  # the folder names the config value


# -------------------------------------------------------------------------- ES parameter records
@pytest.mark.parametrize("name", ES_NAMES)
def test_every_es_is_built_from_its_params_record(name):
    cls = {**ALGORITHMS, **MIRRORED_ALGORITHMS}[name]
    assert cls is ALGORITHM_SPECS[name].es_class() and cls.name == name
    assert issubclass(cls.Params, Params) and cls.Params.__dataclass_params__.frozen
    params = cls.Params(popsize=12, sigma=0.3, weight_decay=0.0)
    a, b = cls(4, params, mean=np.ones(4)), make_es(name, 4, popsize=12, sigma=0.3, weight_decay=0.0, mean=np.ones(4))
    assert a.params == b.params == params and (a.popsize, a.sigma, a.weight_decay) == (12, 0.3, 0.0)
    samples = np.random.default_rng(0).normal(size=(12, 4))
    fitness = -np.sum(samples**2, axis=1)
    a.tell(samples, fitness)
    b.tell(samples, fitness)
    np.testing.assert_array_equal(a.mean, b.mean)
    # keywords replace fields of a given record; a record of another ES or an unknown field is refused
    assert cls(4, params, popsize=20).popsize == 20
    with pytest.raises(TypeError):
        cls(4, popsize=10, no_such_option=1)
    other = next(c for c in ALGORITHMS.values() if c is not cls)
    if not issubclass(other.Params, cls.Params):
        with pytest.raises(TypeError):
            cls(4, other.Params())


def test_params_are_checked_where_they_are_made():
    with pytest.raises(ValueError, match="popsize must be >= 2"):
        Params(popsize=1)
    with pytest.raises(ValueError, match="weight_decay_form must be one of"):
        OpenES.Params(weight_decay_form="l2")
    with pytest.raises(ValueError, match="style must be one of"):
        CEM.Params(style="textbook")
    with pytest.raises(ValueError, match="sigma_lr must be > 0"):
        SNES(3, sigma_lr=0.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        Params().popsize = 3  # type: ignore[misc]


def test_fitness_shaping_and_weight_decay_forms_are_pluggable(monkeypatch):
    """A shaping or a weight-decay form registered by name is selected by name."""
    monkeypatch.setitem(base.FITNESS_SHAPINGS, "raw", lambda values, tie_break: np.asarray(values, dtype=np.float64))

    class NoDecay(base.WeightDecayForm):
        def apply(self, samples, fitness, weight_decay, shape):
            return shape(fitness)

    monkeypatch.setitem(base.WEIGHT_DECAY_FORMS, "none", NoDecay())
    es: EvolutionStrategy = make_es("openes", 2, popsize=3, fitness_shaping="raw", weight_decay_form="none")
    np.testing.assert_array_equal(es.utilities(np.ones((3, 2)), np.array([3.0, -1.0, 2.0])), [3.0, -1.0, 2.0])


def test_algo_options_come_from_the_es_params():
    """``algo.style`` of CEM: default, choices and the folder name come from ``CEM.Params``."""
    from imix_cli.running.config.compose import ConfigError, validate_overrides

    (default,) = validate_overrides(["algo=cem"])
    assert default.algo_options == {"style": "imix"} and default.run_name == "cem-cartpole-none"
    (cemrl,) = validate_overrides(["algo=cem", "algo.style=cemrl", "eim=true"])
    assert cemrl.algo_options == {"style": "cemrl"} and cemrl.run_name == "cem-cartpole-eim-algo.style=cemrl"
    with pytest.raises(ConfigError, match=r"algo.style='textbook': valid choices are imix, cemrl"):
        validate_overrides(["algo=cem", "algo.style=textbook"])
    (snes,) = validate_overrides(["algo=snes"])
    assert snes.algo_options == {}


def test_only_envs_marked_mujoco_are_mujoco_envs(monkeypatch):
    # a preset of another gymnasium id (no compiled evaluator) is not a MuJoCo env
    from imix_cli.core import registry

    spec = registry.EnvSpec("mountaincar", "MountainCar-v0", "MountainCar", 200, -110.0)
    assert not spec.builtin and not spec.mujoco
    assert set(registry.MUJOCO_ENVS) == {"swimmer", "hopper", "halfcheetah", "walker2d", "ant"}
    assert all(registry.ENV_SPECS[name].mujoco for name in registry.MUJOCO_ENVS)
    monkeypatch.setitem(registry.ENV_SPECS, "mountaincar", spec)
    assert "MountainCar-v0" not in registry.mujoco_thresholds()


def test_imix_plot_takes_a_presets_threshold_under_the_gymnasium_id_its_runs_carry(monkeypatch):
    # runs of a preset that is not a built-in are named by the gymnasium id (env=mountaincar makes MountainCar-v0
    # runs): the EnvSpec's threshold must reach imix plot under that name, not under the config name it never sees
    from imix_cli.core import registry
    from imix_cli.plotting import data

    assert data.DEFAULT_THRESHOLDS == registry.plot_thresholds()  # what imix plot starts from
    spec = registry.EnvSpec("mountaincar", "MountainCar-v0", "MountainCar", 200, -110.0)
    monkeypatch.setitem(registry.ENV_SPECS, "mountaincar", spec)
    monkeypatch.setitem(registry.ENV_SPECS, "pendulum", registry.EnvSpec("pendulum", "Pendulum-v1", "Pendulum", 200))
    thresholds = registry.plot_thresholds()
    assert thresholds["MountainCar-v0"] == -110.0 and "mountaincar" not in thresholds
    assert "Pendulum-v1" not in thresholds  # no threshold given: none made up
    assert thresholds["Hopper-v5"] == registry.ENV_SPECS["hopper"].threshold  # MuJoCo runs are named by id too
    for name in registry.BUILTIN_ENVS:  # built-in runs carry the config name
        assert thresholds[name] == registry.ENV_SPECS[name].threshold
