"""Each `imix run` key is declared once (imix_cli/running/config/keys.py); conf/config.yaml's values, `imix run --help`'s
keys, docs/configuration.md and the checks are derived from that declaration, and these tests fail when any of them
drifts from it: a default edited in the YAML or a line edited in the docs, a key accepted but not declared, a bound
the CLI does not enforce."""

import dataclasses
import math

import pytest
import yaml

from imix_cli.core.registry import ALGORITHM_SPECS
from imix_cli.running.config.compose import ConfigError, config_dir, spec_from_config, validate_overrides
from imix_cli.running.config.keys import (
    CONFIG_YAML,
    GROUP,
    KEYS,
    NON_IDENTITY_KEYS,
    PAPER_DEFAULTS,
    POLICY_DEFAULTS,
    REFERENCE,
    TOP_LEVEL_KEYS,
    config_yaml_generated,
    plain_name,
    reference_markdown,
    yaml_value,
)

FIX = "run `python -m imix_cli.running.config.keys write` and commit"


def test_the_yaml_the_help_and_the_reference_are_generated_from_the_keys():
    assert CONFIG_YAML.read_text() == config_yaml_generated(CONFIG_YAML.read_text()), FIX
    assert REFERENCE.read_text() == reference_markdown(), FIX


def _composed_defaults() -> dict:
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from omegaconf import OmegaConf

    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=config_dir(), version_base="1.3"):
            return OmegaConf.to_container(compose("config"), resolve=False)
    finally:
        GlobalHydra.instance().clear()


def test_hydra_composes_the_declared_defaults():
    """What Hydra reads from conf/ is each key's declared default (the YAML may not be edited by hand)."""
    composed = _composed_defaults()
    flat = {k: v for k, v in composed.items() if k != "policy"} | {f"policy.{k}": v for k, v in composed["policy"].items()}
    declared = {key.name: key.default for key in KEYS if key.in_yaml}
    assert set(flat) - {"algo", "env"} == set(declared)
    assert {k: yaml_value(flat[k]) for k in declared} == {k: yaml_value(v) for k, v in declared.items()}


def test_each_algorithms_options_are_its_params_fields_and_its_yaml_holds_their_defaults():
    for name, spec in ALGORITHM_SPECS.items():
        if not spec.options:
            continue
        shipped = yaml.safe_load((CONFIG_YAML.parent / "algo" / f"{name}.yaml").read_text())
        fields = {f.name: f for f in dataclasses.fields(spec.es_class().Params)}
        for option in spec.options:
            declared = next(k for k in KEYS if k.name == f"algo.{option}")
            assert declared.doc == fields[option].metadata["doc"]
            assert yaml_value(shipped[option]) == declared.shown_default, f"conf/algo/{name}.yaml: {option}"


def test_every_key_imix_run_accepts_is_declared_and_nothing_else():
    accepted = {k for k in TOP_LEVEL_KEYS if k != "policy"} | {f"policy.{k}" for k in POLICY_DEFAULTS}
    declared = {k.name for k in KEYS if "," not in k.name and not k.name.startswith("algo.") and k.name not in ("env.id", "env.max_steps", "env.kwargs.<name>")}
    assert declared == accepted
    options = {f"algo.{o}" for spec in ALGORITHM_SPECS.values() for o in spec.options} | {"algo.generations"}
    assert {k.name for k in KEYS if k.name.startswith("algo.") and "," not in k.name} == options  # "a, b, ...": the DDPG section


def _outside(bound) -> float:
    """A value just outside ``bound``: below its low end, or at it when the low end is excluded."""
    if not bound.low_inclusive:
        return bound.low
    return bound.low - 1 if bound.integer else bound.low - 0.5


_CONTEXT = {"im_alpha": ["im=true", "im_variant=sun2009"], "min_fresh": ["eim=true"], "eim_generations": ["eim=true"]}
_CONTEXT |= {k: ["eim=true"] for k in ("reeval_age", "reeval_prob", "reeval_count")}


@pytest.mark.parametrize("key", [k for k in KEYS if k.check is not None], ids=lambda k: k.name)
def test_the_command_line_refuses_what_each_declared_check_refuses(key):
    """Derived from the declaration: a value out of a key's bound, not among its choices, or of the wrong type is
    refused in one line naming the key (and the key's default is accepted)."""
    bound, choices = getattr(key.check, "bound", None), getattr(key.check, "choices", None)
    if bound is not None:
        bad = [_outside(bound), "abc"] + ([bound.high] if bound.high != math.inf and not bound.high_inclusive else [])
        bad += [bound.low + 1.5] if bound.integer else []  # within the range, not an integer
    elif choices is not None:
        bad = ["nope"]
        assert key.default in choices()
    else:
        bad = ["[1, nope]" if key.name == "policy.hidden" else "'  '" if key.name == "ray_address" else "-7"]
    context = _CONTEXT.get(key.name, [])
    if key.name.startswith("policy.") and key.name not in ("policy.hidden", "policy.bias"):
        context = ["env=gym", "env.id=Pendulum-v1"] + (["policy.obs_norm=true"] if "obs" in key.name else [])
    for value in bad:
        with pytest.raises(ConfigError) as err:
            validate_overrides(["seeds=2", "generations=2", *context, f"{key.name}={value}"])
        message = str(err.value)
        assert message.startswith(f"{key.name}=") or f"{key.name}=" in message, message
        assert "\n" not in message


def test_the_declared_roles_are_the_runs():
    """``identity``: only keys declared as never changing results may differ on resume; ``names_folder``: exactly the
    keys compared with the paper's defaults when a folder is named."""
    spec = validate_overrides(["eim=true", "seeds=2", "generations=2"])[0]
    assert set(spec.identity()) == set(spec.config) - set(NON_IDENTITY_KEYS)
    for key in KEYS:
        if key.in_yaml and "." not in key.name:
            assert (key.name in spec.identity()) == key.identity or key.name in ("total_steps", "policy"), key.name
    assert set(PAPER_DEFAULTS) == {k.name for k in KEYS if k.names_folder}
    renamed = validate_overrides(["eim=true", "popsize=10", "eim_generations=5", "seeds=2", "generations=2"])[0]
    assert renamed.run_name == f"{spec.run_name}-eim_generations=5,popsize=10"
    assert GROUP not in PAPER_DEFAULTS.values()


def test_a_config_without_the_newer_keys_reads_them_as_declared_absent():
    """A config written before a key existed (a --config-name YAML of its time) runs as it did then."""
    composed = validate_overrides(["seeds=2", "generations=2"])[0].config
    old = {k: v for k, v in composed.items() if k not in ("checkpoint_seconds", "eval_mean_every", "eval_mean_episodes", "logger", "mixing")}
    spec = spec_from_config(old)
    declared = {key.name: key.absent for key in KEYS}
    assert (spec.checkpoint_seconds, spec.eval_mean_every, spec.eval_mean_episodes, spec.logger) == (
        declared["checkpoint_seconds"], declared["eval_mean_every"], declared["eval_mean_episodes"], declared["logger"])  # fmt: skip


def _other_value(key):
    """A valid value of ``key`` other than its default, read from its declared check."""
    bound, choices = getattr(key.check, "bound", None), getattr(key.check, "choices", None)
    if choices is not None:
        return next(c for c in choices() if c != key.default)
    if bound is None:  # a flag, a name, a plain integer or number
        return str(not key.default).lower() if isinstance(key.default, bool) else f"{key.default}2" if key.check is plain_name else 3
    if key.default is None:
        return bound.low
    return key.default + 1 if bound.integer else key.default + (0.5 if bound.high == math.inf else (bound.high - key.default) / 2)


_MIXING = {"always": [], "mixing": ["eim=true"], "im": ["im=true"], "eim": ["eim=true"]}


@pytest.mark.parametrize("key", [k for k in KEYS if k.names_folder], ids=lambda k: k.name)
def test_a_key_declared_to_name_the_folder_names_it_with_its_mixing_only(key):
    context = _MIXING[key.names_folder] + (["im_variant=sun2009"] if key.name == "im_alpha" else [])
    value = _other_value(key)
    base = validate_overrides(["seeds=2", "generations=2", *context])[0]
    changed = validate_overrides(["seeds=2", "generations=2", *context, f"{key.name}={value}"])[0]
    assert f"{key.name}=" in changed.run_name and f"{key.name}=" not in base.run_name, changed.run_name
    if key.names_folder != "always":  # another mixing: the key does not apply, or does not name the folder
        other = {"im": ["eim=true"], "eim": ["im=true"], "mixing": []}[key.names_folder]
        try:
            elsewhere = validate_overrides(["seeds=2", "generations=2", *other, f"{key.name}={value}"])[0]
        except ConfigError:
            return  # refused where it does not apply (min_fresh, reeval_*, im_alpha without mixing)
        assert f"{key.name}=" not in elsewhere.run_name


@pytest.mark.parametrize("key", [k for k in KEYS if k.check is not None and not k.names_folder and not k.name.startswith("policy.")], ids=lambda k: k.name)
def test_a_key_not_declared_to_name_the_folder_leaves_it(key):
    if key.name in ("im", "eim", "evaluator", "ray_address", "logger", "results_dir", "experiment"):
        pytest.skip("names the folder's mixing part, needs an extra, or names a folder above the run's")
    value = _other_value(key)
    base = validate_overrides(["seeds=2", "generations=2", "eim=true"])[0]
    assert validate_overrides(["seeds=2", "generations=2", "eim=true", f"{key.name}={value}"])[0].run_name == base.run_name
