"""Configuration: Hydra's composition of ``imix run``'s command line into validated RunSpecs.

``imix run`` composes ``conf/config.yaml`` (+ the ``algo`` and ``env`` groups) with Hydra;
:func:`spec_from_config` then checks every value and returns an immutable
:class:`~imix_cli.running.run_spec.RunSpec` that the runner consumes. Errors are
:class:`~imix_cli.running.config_checks.ConfigError` with a one-line message that names the offending
key; the CLI prints it and exits with status 2 before anything is written.

:func:`validate_overrides` does the same for a whole command line -- every point of a
``-m`` sweep, however many -- before Hydra starts, so a bad value in the 10th sweep point is
reported before the first point runs.

The checks live by concern: :mod:`imix_cli.running.config_checks` (typed keys, seeds, workers, the
env), :mod:`imix_cli.running.es_config` (an evolution strategy's keys, policy and evaluator),
:mod:`imix_cli.ddpg.config` (algo=ddpg), :mod:`imix_cli.running.run_spec` (the RunSpec, the keys and
a run's identity). The names other modules import from here are re-exported.
"""

from __future__ import annotations

import copy
import itertools
import json
import re
from pathlib import Path

from imix_cli.ddpg.config import ddpg_spec
from imix_cli.registry import ALGO_NAMES, ALGORITHM_SPECS, BUILTIN_ENVS
from imix_cli.running.config_checks import ConfigError, as_choice, first_line
from imix_cli.running.es_config import es_spec
from imix_cli.running.run_spec import DDPG_DEFAULTS, PAPER_DEFAULTS, TOP_LEVEL_KEYS, RunSpec, differing_keys

__all__ = [
    "BUILTIN_ENVS",
    "DDPG_DEFAULTS",
    "PAPER_DEFAULTS",
    "ConfigError",
    "RunSpec",
    "config_dir",
    "group_options",
    "point_key",
    "spec_from_config",
    "validate_overrides",
]


def spec_from_config(cfg: dict, launcher: str | None = None) -> RunSpec:
    """Validate a resolved config (a plain dict, as Hydra composes it) and build the RunSpec.

    ``launcher`` is the Hydra launcher's ``_target_``: under a launcher that runs jobs in
    parallel, each job's seeds run in-process (``workers`` 1).
    """
    unknown = sorted(set(cfg) - set(TOP_LEVEL_KEYS))
    if unknown:
        raise ConfigError(f"unknown key {unknown[0]!r}; valid keys: {', '.join(TOP_LEVEL_KEYS)}")
    algo_cfg, env_cfg = cfg.get("algo") or {}, cfg.get("env") or {}
    algo = as_choice(algo_cfg.get("name"), "algo", ALGO_NAMES)
    build = es_spec if ALGORITHM_SPECS[algo].is_es else ddpg_spec
    spec = build(cfg, algo, algo_cfg, env_cfg, launcher)
    _check_folder_names(spec)
    return spec


#: The longest file or folder name (bytes) of the file systems imix writes to (ext4, xfs, btrfs, APFS, NTFS).
NAME_MAX = 255


def _check_folder_names(spec: RunSpec) -> None:
    """ConfigError if the experiment's or the run's folder name is longer than a file system allows (a sweep
    point would fail with "File name too long" only when its turn comes, after earlier points ran)."""
    for label, name in (("experiment", spec.experiment), ("run folder", spec.run_name)):
        size = len(name.encode())
        if size > NAME_MAX:
            why = " (it names the hyper-parameters that differ from the paper's)" if label == "run folder" else ""
            shown = name if len(name) <= 90 else name[:90] + "..."
            raise ConfigError(f"{label} name {shown!r} is {size} bytes, more than the {NAME_MAX} a file name may have{why}; use shorter values")


def config_dir() -> str:
    """Where the Hydra configs are: the installed package ``imix_cli.conf`` or, in a source tree, ``conf/``."""
    import importlib.util

    spec = importlib.util.find_spec("imix_cli.conf")
    if spec is not None and spec.submodule_search_locations:
        return str(Path(list(spec.submodule_search_locations)[0]).resolve())
    return str((Path(__file__).resolve().parents[2] / "conf").resolve())


def group_options(group: str) -> list[str]:
    return sorted(p.stem for p in (Path(config_dir()) / group).glob("*.yaml"))


def point_key(plain: dict, launcher: str | None) -> str:
    """What identifies one composed point: its resolved config (a plain dict) and the launcher's ``_target_``,
    the two inputs of :func:`spec_from_config`."""
    return json.dumps([plain, launcher], sort_keys=True, default=repr)


def validate_overrides(overrides: list[str], validated: dict | None = None, values: dict | None = None) -> list[RunSpec]:
    """Compose and validate the config of every point of a (possibly multirun) command line.

    ``validated``, if given, receives each point's RunSpec under its :func:`point_key`: ``imix run`` hands
    them to the Hydra task, which runs them without validating its point a second time.

    ``values``: dotted key -> Python value (the keyword arguments of :func:`imix_cli.run`), set on every
    point after ``overrides`` as values, never read as override syntax: ``experiment="a,b"`` is one folder
    named ``a,b``, not a sweep, and ``"${...}"`` is that text, not an interpolation (:func:`_set_values`).

    Raises ConfigError (one line) on the first problem, or when two points would share a run
    folder with different configs (the second would be refused halfway through the sweep).
    Every point is checked: sweeps (``a,b``, ``range(...)``, ``glob(...)`` over ``algo``/``env``)
    are expanded here. Hydra composes the config once per combination of config-group choices
    (``algo``, ``env``, ``hydra/...``) and of ``+``/``~`` overrides; each point's plain
    ``key=value`` overrides are then applied to a copy by Hydra's own override function, so a
    point costs milliseconds instead of a full composition (:func:`_apply_values`, public
    OmegaConf API only).
    """
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import Glob
    from omegaconf import OmegaConf, open_dict

    set_values = dict(values or {})
    # algo and env choose config files: a name of conf/algo or conf/env, composed like the command line's
    overrides = [*overrides, *(_group_choice(key, set_values.pop(key)) for key in ("algo", "env") if key in set_values)]
    for key in set_values:
        if not isinstance(key, str) or not _DOTTED_KEY.match(key) or key.split(".")[0] == "hydra":
            raise ConfigError(f"unknown key {key!r}; valid keys: {', '.join(TOP_LEVEL_KEYS)} (and algo.*, env.*)")
    parser = OverridesParser.create()
    try:
        parsed = parser.parse_overrides(overrides)
    except Exception as err:
        raise ConfigError(f"cannot parse overrides: {first_line(err)}") from None
    choices = []
    for override in parsed:
        key = override.key_or_group
        if override.is_sweep_override():
            if isinstance(override.value(), Glob):
                if key not in ("algo", "env"):
                    raise ConfigError(f"{override.input_line}: glob() selects options of the config groups algo and env only")
                values = override.value().filter(group_options(key))
                if not values:
                    raise ConfigError(f"{override.input_line}: matches no {key}; valid choices are {', '.join(group_options(key))}")
            else:
                values = list(override.sweep_string_iterator())
            choices.append([f"{override.get_key_element()}={v}" for v in values])
        else:
            choices.append([override.input_line])
        if key in ("algo", "env"):
            valid = group_options(key)
            for line in choices[-1]:
                value = line.split("=", 1)[1]
                if value not in valid:
                    raise ConfigError(f"{key}={value}: unknown {key}; valid choices are {', '.join(valid)}")
    parse_cache: dict = {}

    def parse_one(line: str):
        if line not in parse_cache:
            try:
                parse_cache[line] = parser.parse_overrides([line])[0]
            except Exception as err:
                raise ConfigError(f"cannot parse overrides: {first_line(err)}") from None
        return parse_cache[line]

    specs, composed = [], {}
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=config_dir(), version_base="1.3"):
            for point in itertools.product(*choices):
                parsed_point = [parse_one(line) for line in point]
                point_values = [o for o in parsed_point if _is_value_override(o)]
                base = tuple(line for line, o in zip(point, parsed_point, strict=True) if not _is_value_override(o))
                try:
                    if base not in composed:  # hydra.* overrides are in base: the hydra node is done with
                        full = compose("config", overrides=list(base), return_hydra_config=True)
                        launcher = OmegaConf.select(full, "hydra.launcher._target_")
                        with open_dict(full):
                            del full["hydra"]
                        composed[base] = (full, launcher)
                    cfg, launcher = copy.deepcopy(composed[base][0]), composed[base][1]
                    _apply_values(point_values, cfg)
                    _set_values(set_values, cfg)
                    plain = OmegaConf.to_container(cfg, resolve=True)
                except ConfigError:
                    raise
                except Exception as err:
                    raise ConfigError(_explain_compose_error(err, point)) from None
                specs.append(spec_from_config(plain, launcher))
                if validated is not None:
                    validated[point_key(plain, launcher)] = specs[-1]
    finally:
        GlobalHydra.instance().clear()
    _refuse_shared_folders(specs)
    return specs


def _apply_values(values, cfg) -> None:
    """Set each plain ``key=value`` override (see :func:`_is_value_override`) on the composed ``cfg``, as Hydra's
    own composition sets a task override: ``OmegaConf.update(..., merge=True)``, the struct flag refusing a key the
    config does not have. The errors say what Hydra's say, so :func:`_explain_compose_error` reads both alike."""
    from omegaconf import OmegaConf
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException

    for override in values:
        try:
            OmegaConf.update(cfg, override.key_or_group, override.value(), merge=True)
        except (ConfigAttributeError, ConfigKeyError):
            raise ValueError(f"Could not override '{override.key_or_group}'.") from None
        except OmegaConfBaseException:
            raise ValueError(f"Error merging override {override.input_line}") from None


_DOTTED_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


def _group_choice(group: str, value) -> str:
    """``group=value`` for a config group chosen by a keyword (``algo="snes"``); ConfigError unless it names one of its options."""
    valid = group_options(group)
    if not isinstance(value, str) or value not in valid:
        raise ConfigError(f"{group}={value!r}: unknown {group}; valid choices are {', '.join(valid)}")
    return f"{group}={value}"


def _set_values(values: dict, cfg) -> None:
    """Set each ``key: value`` of ``values`` on the composed ``cfg`` as a value: strings with their ``${`` escaped
    (OmegaConf's ``\\${``, a backslash run before it doubled), so that resolving the config leaves them as given;
    numpy scalars as Python's. ConfigError naming the key if the config has no such key or the value is of no type
    a config holds."""
    from omegaconf import OmegaConf
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException

    def plain(key, v):
        if isinstance(v, str):
            return re.sub(r"(\\*)\$\{", lambda m: m.group(1) * 2 + "\\${", v)
        if isinstance(v, (list, tuple)):
            return [plain(key, x) for x in v]
        if v is None or isinstance(v, (bool, int, float)):
            return v
        if type(v).__module__ == "numpy" and hasattr(v, "item"):  # np.int64(5), np.float32(0.1)
            return plain(key, v.item())
        raise ConfigError(f"{key}={v!r}: a {type(v).__name__} is not a value of the config (give a str, number, bool, None or list)")

    for key, v in values.items():
        try:
            OmegaConf.update(cfg, key, plain(key, v), merge=True)
        except (ConfigAttributeError, ConfigKeyError):
            raise ConfigError(f"unknown key {key!r}; valid keys: {', '.join(TOP_LEVEL_KEYS)} (and algo.*, env.*)") from None
        except OmegaConfBaseException as err:
            raise ConfigError(f"{key}={v!r}: {first_line(err)}") from None


def _is_value_override(override) -> bool:
    """A plain ``key=value`` of a config value (not a config group, not ``+``/``~``/``++``)."""
    key = override.key_or_group
    return (
        override.package is None and not override.is_add() and not override.is_delete() and not override.is_force_add()
        and "/" not in key and key not in ("algo", "env", "hydra") and not key.startswith("hydra.")
    )  # fmt: skip


def _refuse_shared_folders(specs: list[RunSpec]) -> None:
    """ConfigError if two points would write one run folder with different configs."""
    first: dict[Path, RunSpec] = {}
    for spec in specs:
        other = first.setdefault(spec.run_dir, spec)
        old, new = other.identity(), spec.identity()
        differing = differing_keys(old, new)
        if differing:
            changes = ", ".join(f"{k}={old.get(k)!r} / {new.get(k)!r}" for k in differing)
            raise ConfigError(
                f"two sweep points would share the folder {spec.run_dir} but differ in {changes}; "
                "sweep that key in separate commands with their own experiment="
            )


def _explain_compose_error(err: Exception, point) -> str:
    text = str(err)
    if "not in struct" in text or "Could not override" in text or "Key '" in text and "is not in struct" in text:
        bad = next((p.split("=", 1)[0].lstrip("+~") for p in point if p.split("=", 1)[0].lstrip("+~") in text), None)
        key = bad or first_line(err)
        return f"unknown key {key!r}; valid keys: {', '.join(TOP_LEVEL_KEYS)} (and algo.*, env.*, hydra.*)"
    missing = re.search(r"Could not find '([^']+)/([^'/]+)'", text)
    if missing:  # a config group option that does not exist, e.g. hydra/launcher=nope
        group, option = missing.groups()
        return f"{group}={option}: no such option in config group {group!r}"
    return f"bad override ({', '.join(point)}): {first_line(err)}"
