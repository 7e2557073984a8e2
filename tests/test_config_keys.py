"""The keys table (imix_cli/running/config_keys.py) is the one source of the configuration reference and of
`imix run --help`'s keys: both are generated from it and must be up to date, it must list every
key `imix run` accepts, and its defaults must be conf/config.yaml's."""

import yaml

from imix_cli.registry import ALGORITHM_SPECS
from imix_cli.running.config_keys import CONFIG_YAML, KEYS, REFERENCE, config_yaml_with_help, reference_markdown
from imix_cli.running.run_spec import POLICY_DEFAULTS, TOP_LEVEL_KEYS


def test_the_generated_reference_and_help_are_up_to_date():
    fix = "run `python -m imix_cli.running.config_keys write` and commit"
    assert REFERENCE.read_text() == reference_markdown(), fix
    assert CONFIG_YAML.read_text() == config_yaml_with_help(CONFIG_YAML.read_text()), fix


def test_every_key_imix_run_accepts_is_documented_and_nothing_else():
    accepted = {k for k in TOP_LEVEL_KEYS if k not in ("policy",)} | {f"policy.{k}" for k in POLICY_DEFAULTS}
    documented = {k.name for k in KEYS if "," not in k.name and not k.name.startswith("algo.") and k.name not in ("env.id", "env.max_steps")}
    assert documented == accepted
    # algo.<option>: the options every ES registers (conf/algo/<name>.yaml), and the generation count
    options = {f"algo.{o}" for spec in ALGORITHM_SPECS.values() for o in spec.options} | {"algo.generations"}
    assert {k.name for k in KEYS if k.name.startswith("algo.") and "," not in k.name} == options  # "a, b, ...": the DDPG section


def _shown(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "null"
    if isinstance(value, list):
        return "[" + ",".join(map(str, value)) + "]"
    return str(value)


def test_the_documented_defaults_are_the_configs():
    config = yaml.safe_load(CONFIG_YAML.read_text())
    shipped = {**{k: v for k, v in config.items() if k not in ("defaults", "hydra", "policy")}, **{f"policy.{k}": v for k, v in config["policy"].items()}}
    documented = {k.name: k.default for k in KEYS}
    assert {k: _shown(v) for k, v in shipped.items()} == {k: documented[k] for k in shipped}
