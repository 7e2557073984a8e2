"""One default per setting. The mixing defaults are declared once (imix_cli.core.mixing.MIXING_DEFAULTS) and every
`imix run` key once (imix_cli/running/config/keys.py); these tests compare what each consumer actually defaults to --
mix(), MixingES, MixingSettings, the RunSpec -- with the key table, so a default written again anywhere and edited
there fails here: a library user calling imix_cli.mix gets the rule `imix run eim=true` runs."""

import dataclasses
import inspect

import numpy as np

from imix_cli.core.mixing import MIXING_DEFAULTS, DiagonalGaussian, config_variants, mix
from imix_cli.core.mixing.ask_tell import MixingES
from imix_cli.core.mixing.generation import MixingSettings
from imix_cli.running.config.keys import BY_NAME

#: The numeric mixing keys of `imix run` -> the name the library gives the same setting.
MIXING_KEYS = {
    "im_alpha": "alpha",
    "eim_generations": "eim_generations",
    "min_fresh": "min_fresh",
    "reeval_age": "reeval_age",
    "reeval_prob": "reeval_prob",
    "reeval_count": "reeval_count",
}


def _same(a, b) -> bool:
    """Equal and of one type (0 is not 0.0, 1 is not True): a default is the key's value, not one that compares equal."""
    return type(a) is type(b) and a == b


def _signature_defaults(fn) -> dict:
    return {n: p.default for n, p in inspect.signature(fn).parameters.items() if p.default is not inspect.Parameter.empty}


def _key_defaults() -> dict:
    """The CLI's defaults by the library's names; ``variant``: the one ``eim=true`` runs (``eim_variant``'s default)."""
    values = {library: BY_NAME[key].default for key, library in MIXING_KEYS.items()}
    values["variant"] = config_variants("eim")[BY_NAME["eim_variant"].default].name
    return values


def test_mix_mixing_es_and_mixing_settings_default_to_the_key_table():
    keys = _key_defaults()
    mix_defaults = _signature_defaults(mix)
    for name in ("variant", "alpha", "eim_generations", "min_fresh"):
        assert _same(mix_defaults[name], keys[name]), f"mix({name}={mix_defaults[name]!r}) but imix run's default is {keys[name]!r}"
    es_defaults = _signature_defaults(MixingES.__init__)
    for name, value in keys.items():
        assert _same(es_defaults[name], value), f"MixingES({name}={es_defaults[name]!r}) but imix run's default is {value!r}"
    settings = {f.name: f.default for f in dataclasses.fields(MixingSettings)}
    assert settings["variant"] is None  # no mixing, as imix run without im/eim
    assert not BY_NAME["im"].default and not BY_NAME["eim"].default
    for name, value in keys.items():
        if name != "variant":
            assert _same(settings[name], value), f"MixingSettings.{name}={settings[name]!r} but imix run's default is {value!r}"


def test_the_run_spec_mixing_fields_default_to_the_key_table():
    from imix_cli.running.config.run_spec import RunSpec

    fields = {f.name: f.default for f in dataclasses.fields(RunSpec)}
    for key in MIXING_KEYS:
        assert _same(fields[key], BY_NAME[key].default), f"RunSpec.{key}={fields[key]!r} but the key's default is {BY_NAME[key].default!r}"


def test_the_key_table_reads_the_one_declaration():
    for key, library in MIXING_KEYS.items():
        assert _same(BY_NAME[key].default, getattr(MIXING_DEFAULTS, library)), key
    assert config_variants("eim")[BY_NAME["eim_variant"].default].name == MIXING_DEFAULTS.variant
    assert config_variants("im")[BY_NAME["im_variant"].default].name == MIXING_DEFAULTS.im_variant


def test_a_library_user_gets_the_rule_without_a_fixed_point():
    """mix() with its defaults on a distribution that did not move: the rules alone would reuse every member (a fixed
    point for CEM and CMA-ES); imix run's minimal refresh keeps ``min_fresh`` of them fresh."""
    rng = np.random.default_rng(0)
    dist = DiagonalGaussian(np.zeros(3), np.ones(3))
    archive = [mix(dist, [], 20, rng)]
    g = mix(dist, archive, 20, rng)
    assert g.reused == 20 - MIXING_DEFAULTS.min_fresh >= 0 and MIXING_DEFAULTS.min_fresh >= 1


#: RunSpec fields with a default that is no key's, and why (every other defaulted field is a key's: ``_key``).
NOT_A_KEY = {
    "mixing": "from the keys im and eim (false: none)",
    "variant": "from im/eim and im_variant/eim_variant (no mixing: None)",
    "generations": "the key's default is the algorithm's (${algo.generations}); DDPG runs total_steps",
    "algo_options": "the algo.* options, from the ES's Params",
    "ddpg": "algo=ddpg's settings, from conf/algo/ddpg.yaml",
    "env_kwargs": "the env.kwargs.<name> family: a gymnasium constructor's arguments, none by default",
}


def _checked_default(key):
    """What ``imix run`` makes of the key's default: its check's value (``checkpoint_seconds``' 30 is 30.0)."""
    return key.check({key.name: key.default}, key.name) if key.check is not None else key.default


def test_every_run_spec_default_is_its_keys():
    """Each RunSpec field with a default names its key (``_key``) and defaults to what ``imix run`` makes of that key's
    default; each key the RunSpec holds (``spec=True``) is the field of its name. The five fields that once defaulted to
    something else (checkpoint_every 0 vs 50, checkpoint_seconds 0 vs 30, eval_mean_every 0 vs 10, obs_norm_warmup 0 vs 5,
    evaluator_workers 1 vs null) are among them."""
    from imix_cli.running.config.run_spec import RunSpec

    fields = {f.name: f for f in dataclasses.fields(RunSpec)}
    for f in fields.values():
        has_default = f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
        if not has_default:
            continue  # given by every caller (es_config, ddpg)
        if f.name in NOT_A_KEY:
            assert "key" not in f.metadata, f.name
            continue
        assert "key" in f.metadata, f"RunSpec.{f.name} has a default of its own ({f.default!r}): make it _key(<its key>) or say why in NOT_A_KEY"
        key = BY_NAME[f.metadata["key"]]
        want = _checked_default(key)
        assert f.default == want and isinstance(f.default, bool) == isinstance(want, bool), (
            f"RunSpec.{f.name}={f.default!r} but imix run's default of {key.name} is {want!r}"
        )
    for key in BY_NAME.values():
        if key.spec:
            f = fields[key.name]
            assert f.default is dataclasses.MISSING or f.metadata.get("key") == key.name or key.name in NOT_A_KEY, key.name


def test_the_run_spec_of_the_default_config_holds_the_field_defaults():
    """The RunSpec ``imix run`` builds from the default config equals, field by field, the RunSpec defaults (but what
    the launcher or the env resolve): the CLI and a RunSpec made in Python start from the same values."""
    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.config.run_spec import RunSpec

    (spec,) = validate_overrides([])
    for f in dataclasses.fields(RunSpec):
        if "key" in f.metadata:
            assert getattr(spec, f.name) == f.default, f.name
