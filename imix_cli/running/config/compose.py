"""Configuration: Hydra's composition of ``imix run``'s command line into validated RunSpecs.

``imix run`` composes ``conf/config.yaml`` (+ the ``algo`` and ``env`` groups) with Hydra;
:func:`spec_from_config` then checks every value and returns an immutable
:class:`~imix_cli.running.config.run_spec.RunSpec` that the runner consumes. Errors are
:class:`~imix_cli.running.config.checks.ConfigError` with a one-line message that names the offending
key; the CLI prints it and exits with status 2 before anything is written.

:func:`validate_overrides` does the same for a whole command line -- every point of a
``-m`` sweep, however many -- before Hydra starts, so a bad value in the 10th sweep point is
reported before the first point runs.

The checks live by concern: :mod:`imix_cli.running.config.keys` (each key declared once: its default, its own
check, its roles), :mod:`imix_cli.running.config.checks` (typed values, seeds, workers, the env, memory),
:mod:`imix_cli.running.config.es_config` (an evolution strategy's keys together: mixing, policy, evaluator),
:mod:`imix_cli.running.config.ddpg` (algo=ddpg), :mod:`imix_cli.running.config.run_spec` (the RunSpec and a run's identity).
The names other modules import from here are re-exported.
"""

from __future__ import annotations

import contextlib
import copy
import itertools
import json
import os
import re
from pathlib import Path

from imix_cli.core.registry import ALGO_NAMES, ALGORITHM_SPECS, BUILTIN_ENVS
from imix_cli.messages import MissingExtraError, shown_value
from imix_cli.running.config.checks import ConfigError, as_choice, first_line
from imix_cli.running.config.ddpg import ddpg_spec
from imix_cli.running.config.es_config import es_spec
from imix_cli.running.config.keys import PAPER_DEFAULTS, POLICY_DEFAULTS, TOP_LEVEL_KEYS, did_you_mean
from imix_cli.running.config.run_spec import DDPG_DEFAULTS, RunSpec, algo_option_fields, differing_keys
from imix_cli.running.config.search import SWEEPER_KEYS, check_search_settings, check_trial_config, is_search, probe_values
from imix_cli.running.files.safe_yaml import MAX_YAML_BYTES, BadYamlError, check_yaml_file, check_yaml_text

__all__ = [
    "BUILTIN_ENVS",
    "DDPG_DEFAULTS",
    "PAPER_DEFAULTS",
    "ConfigError",
    "RunSpec",
    "bounded_config_reads",
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
    unknown = sorted(map(str, set(cfg) - set(TOP_LEVEL_KEYS)))
    if unknown:
        raise ConfigError(f"unknown key {shown_value(unknown[0])}{did_you_mean(unknown[0], all_keys())}; valid keys: {', '.join(TOP_LEVEL_KEYS)}")
    algo_cfg, env_cfg = cfg.get("algo") or {}, cfg.get("env") or {}
    for group, given in (("algo", algo_cfg), ("env", env_cfg)):  # a YAML's `algo: 4`: a value where a config group goes
        if not isinstance(given, dict):
            raise ConfigError(f"{group}={shown_value(given)}: must be a config of the {group} group (one of {', '.join(group_options(group))})")
    algo = as_choice(algo_cfg.get("name"), "algo", ALGO_NAMES)
    _refuse_unknown_nested_keys(algo, algo_cfg, env_cfg)
    build = es_spec if ALGORITHM_SPECS[algo].is_es else ddpg_spec
    spec = build(cfg, algo, algo_cfg, env_cfg, launcher)
    _check_folder_names(spec)
    return spec


#: The keys of the ``env`` group (conf/env/*.yaml): every env config has the first three; ``env.kwargs`` (the env's
#: constructor arguments, ``+env.kwargs.continuous=true``) is added on the command line.
ENV_KEYS = ("name", "id", "max_steps", "kwargs")


def algo_keys(algo: str) -> tuple:
    """The ``algo.<key>`` keys algorithm ``algo`` reads (conf/algo/<algo>.yaml): its name, its generation count and
    its options; for ddpg its settings (:data:`DDPG_DEFAULTS`) and per-env budgets."""
    if not ALGORITHM_SPECS[algo].is_es:
        return ("name", "generations", "default_total_steps", *DDPG_DEFAULTS)
    return ("name", "generations", *algo_option_fields(algo))


def _refuse_unknown_nested_keys(algo: str, algo_cfg, env_cfg) -> None:
    """ConfigError naming an ``algo.<key>`` or ``env.<key>`` no code reads (``+algo.stlye=x``, ``+env.max_step=5``, or
    a key in a ``--config-name`` YAML): such a key was recorded in config.yaml and silently ignored, so the run was
    not the one asked for. An option of another algorithm (``algo=snes +algo.style=cemrl``) names the one it is for."""
    for group, given, valid in (("algo", algo_cfg, algo_keys(algo)), ("env", env_cfg, ENV_KEYS)):
        if not isinstance(given, dict):
            raise ConfigError(f"{group}={shown_value(given)}: must be a config of the {group} group (one of {', '.join(group_options(group))})")
        unknown = [k for k in given if k not in valid]
        if not unknown:
            continue
        key = f"{group}.{unknown[0]}"
        owners = [name for name in ALGO_NAMES if group == "algo" and unknown[0] in algo_keys(name)]
        if owners:
            raise ConfigError(f"{key}: applies to algo={' | '.join(owners)} only, not algo={algo}")
        for_algo = f" of algo={algo}" if group == "algo" else ""
        raise ConfigError(f"unknown key {shown_value(key)}{did_you_mean(key, all_keys())}; valid {group} keys{for_algo}: {', '.join(valid)}")


def unknown_key_message(key: str) -> str:
    """The one line for a key ``imix run`` does not have, the closest key of the table suggested
    (:func:`~imix_cli.running.config.keys.did_you_mean`): ``imix run popsze=10`` (a command line, a ``--config-name``
    YAML) and the library's ``imix_cli.run(popsze=10)`` / ``Experiment(sigmaa=...)`` say the same."""
    shown = f"{key[:100]!r}{'...' if len(key) > 100 else ''}"
    return f"unknown key {shown}{did_you_mean(key, all_keys())}; valid keys: {', '.join(TOP_LEVEL_KEYS)} (and algo.*, env.*, policy.*, hydra.*)"


def all_keys() -> tuple:
    """Every key ``imix run`` reads, dotted (``seeds``, ``policy.hidden``, ``env.max_steps``, ``algo.style`` ...): what a
    mistyped key is compared with for its "did you mean" (:func:`~imix_cli.running.config.keys.did_you_mean`)."""
    nested = {"algo": sorted({k for name in ALGO_NAMES for k in algo_keys(name)}), "env": ENV_KEYS, "policy": tuple(POLICY_DEFAULTS)}
    return (*TOP_LEVEL_KEYS, *(f"{group}.{k}" for group, keys in nested.items() for k in keys))


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
    return str((Path(__file__).resolve().parents[3] / "conf").resolve())


def group_options(group: str, config_dirs: tuple = ()) -> list[str]:
    """The options of config group ``group``: the YAML files of ``<dir>/<group>/`` for imix's conf/ (or ``config_dirs``,
    the folders a command line composes from: ``--config-path``, ``--config-dir``)."""
    return sorted({p.stem for folder in (config_dirs or (config_dir(),)) for p in (Path(folder) / group).glob("*.yaml")})


def point_key(plain: dict, launcher: str | None) -> str:
    """What identifies one composed point: its resolved config (a plain dict) and the launcher's ``_target_``,
    the two inputs of :func:`spec_from_config`."""
    return json.dumps([plain, launcher], sort_keys=True, default=repr)


def validate_overrides(
    overrides: list[str], validated: dict | None = None, values: dict | None = None, config_name: str = "config", config_dirs: tuple = ()
) -> list[RunSpec]:
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

    ``config_name`` and ``config_dirs`` are the command line's ``--config-name`` and its folders (the primary one --
    imix's conf/ or ``--config-path`` -- then ``--config-dir``): the config validated is the one Hydra will run, a
    hostile or mistyped YAML included. ``hydra.job.chdir=true`` is refused (:func:`_refuse_hydra_settings`), and so are ``hydra.callbacks``; a
    ``${hydra:...}`` interpolation (``results_dir=${hydra:runtime.cwd}/results``) resolves as in the run.
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
        if isinstance(key, str) and _DOTTED_KEY.match(key) is None and key.split(".")[0] != "hydra":
            raise ConfigError(unknown_key_message(key))  # `"seeds=1,2": 3` -- as the command line words an unknown key
        if not isinstance(key, str) or key.split(".")[0] == "hydra":
            raise ConfigError(f"unknown key {shown_value(key)}: a keyword names a key of imix run (algo.*, env.*, policy.*, ...), not Hydra's settings")
    parser = OverridesParser.create()
    try:
        parsed = parser.parse_overrides(overrides)
    except Exception as err:
        raise _unparsable(err, overrides, parser) from None
    choices = []
    search = uses_search_sweeper(parsed)
    searched = [o.input_line for o in parsed if search and o.is_sweep_override()]
    for override in parsed:
        key = override.key_or_group
        if override.is_sweep_override():
            if search and not isinstance(override.value(), Glob):  # hydra/sweeper=optuna: a search space, probed
                choices.append([f"{override.get_key_element()}={override_value_text(v)}" for v in probe_values(override)])
            elif isinstance(override.value(), Glob):
                if key not in ("algo", "env"):
                    raise ConfigError(f"{_shown(override.input_line)}: glob() selects options of the config groups algo and env only")
                values = override.value().filter(group_options(key, config_dirs))
                if not values:
                    raise ConfigError(f"{_shown(override.input_line)}: matches no {key}; valid choices are {', '.join(group_options(key, config_dirs))}")
            else:
                try:
                    values = list(override.sweep_string_iterator())
                except Exception as err:  # interval(): a sweeper plugin's search space, which -m cannot enumerate
                    why = f"{_shown(override.input_line)}: {_shown(first_line(err), 200)}"
                    raise ConfigError(f"{why}; imix run -m enumerates a,b,c, range() and glob() sweeps (hydra/sweeper=optuna searches interval())") from None
            if not search or isinstance(override.value(), Glob):
                choices.append([f"{override.get_key_element()}={v}" for v in values])
        else:
            choices.append([override.input_line])
        if key in ("algo", "env"):
            if override.is_delete():
                raise ConfigError(f"{_shown(override.input_line)}: the {key} group cannot be removed; choose an option with {key}=<option>")
            valid = group_options(key, config_dirs)
            for line in choices[-1]:
                value = line.split("=", 1)[1]
                if value not in valid:
                    raise ConfigError(f"{key}={_shown(value)}: unknown {key}; valid choices are {', '.join(valid)}")
    parse_cache: dict = {}

    def parse_one(line: str):
        if line not in parse_cache:
            try:
                parse_cache[line] = parser.parse_overrides([line])[0]
            except Exception as err:
                raise _unparsable(err, [line], parser) from None
        return parse_cache[line]

    specs = []
    holder, search = _search_order(config_name, config_dirs)
    files = _config_files_state((holder, *config_dirs))
    with contextlib.ExitStack() as hydra_session:  # Hydra is started on the first composition this call needs, if any
        started = False
        for point in itertools.product(*choices):
            parsed_point = [parse_one(line) for line in point]
            point_values = [o for o in parsed_point if _is_value_override(o)]
            base = tuple(line for line, o in zip(point, parsed_point, strict=True) if not _is_value_override(o))
            key = (config_name, holder, tuple(search), base, os.getcwd(), files)  # hydra.* overrides are in base
            try:
                if key not in _COMPOSED:
                    if not started:
                        started = True
                        GlobalHydra.instance().clear()
                        hydra_session.callback(GlobalHydra.instance().clear)
                        hydra_session.enter_context(bounded_config_reads())  # every config file Hydra reads, checked first
                        hydra_session.enter_context(initialize_config_dir(config_dir=holder, version_base="1.3"))
                    full = compose(config_name, overrides=[*search, *base], return_hydra_config=True)
                    launcher = OmegaConf.select(full, "hydra.launcher._target_")
                    _refuse_hydra_settings(full)
                    if is_search(OmegaConf.select(full, "hydra.sweeper._target_")):  # the search's own keys (hydra.sweeper.*)
                        check_search_settings(OmegaConf.to_container(full.hydra.sweeper, resolve=True))
                    with_hydra = copy.deepcopy(full)
                    with open_dict(full):
                        del full["hydra"]
                    if len(_COMPOSED) >= _COMPOSED_MAX:
                        _COMPOSED.clear()
                    _COMPOSED[key] = (full, launcher, with_hydra)
                full, launcher, with_hydra = _COMPOSED[key]
                cfg = copy.deepcopy(full)
                _apply_values(point_values, cfg)
                _set_values(set_values, cfg)
                plain = _resolved(cfg, with_hydra)
            except (ConfigError, MissingExtraError):
                raise
            except BadYamlError as err:  # a config file refused by the bounded loader (bounded_config_reads): it names the file
                raise ConfigError(str(err)) from None
            except Exception as err:
                raise ConfigError(_explain_compose_error(err, point)) from None
            try:
                specs.append(spec_from_config(plain, launcher))
            except ConfigError as err:  # a value the search space can take, refused: say which space it came from
                space = next((line for line in searched if str(err).startswith(line.split("=", 1)[0].lstrip("+~") + "=")), None)
                raise ConfigError(f"{err} (a value of the search space {_shown(space)})" if space else str(err)) from None
            if is_search(OmegaConf.select(with_hydra, "hydra.sweeper._target_")):
                check_trial_config(specs[-1], check_search_settings(OmegaConf.to_container(with_hydra.hydra.sweeper, resolve=True)))
            if validated is not None:
                validated[point_key(plain, launcher)] = specs[-1]
    _refuse_shared_folders(specs)
    return specs


@contextlib.contextmanager
def bounded_config_reads():
    """While in this context, every YAML file Hydra reads passes imix's bounded loader first
    (:mod:`imix_cli.running.files.safe_yaml`): the primary config, what its ``defaults`` pull from conf/, a
    ``--config-dir`` or ``--config-path`` folder or a ``hydra.searchpath`` -- whichever file, at whichever depth, Hydra
    hands it to ``OmegaConf.load`` (public API), the one place every config read goes through. A file refused (an alias
    bomb, nesting too deep, a Python tag, more than 1 MiB) raises :class:`~imix_cli.running.files.safe_yaml.BadYamlError`
    naming it, before OmegaConf expands anything (a bomb of nine anchors ran Hydra for minutes into gigabytes). At most
    1 MiB + 1 byte of a file is read for the check. ``OmegaConf.load`` is itself again on leaving."""
    from omegaconf import OmegaConf

    original = OmegaConf.load

    def load(file_):
        if isinstance(file_, (str, os.PathLike)):
            check_yaml_file(file_)
        elif getattr(file_, "read", None) is not None and getattr(file_, "seek", None) is not None:
            name = getattr(file_, "name", None) or "a config file"
            text = file_.read(MAX_YAML_BYTES + 1)
            file_.seek(0)
            if isinstance(text, bytes):
                try:
                    text = text.decode("utf-8")
                except UnicodeDecodeError as err:
                    raise BadYamlError(f"{name}: not UTF-8 text (byte {err.start})") from None
            check_yaml_text(text, name)
        return original(file_)

    OmegaConf.load = load
    try:
        yield
    finally:
        OmegaConf.load = original


#: Hydra's compositions by (config name, folders, overrides other than plain values, working folder, the config files'
#: state): Hydra composes in ~0.1-0.2 s, and a process validates the same bases again and again (a library caller's
#: runs, the test suite, the command-line fuzzer). Editing, adding or removing a YAML file changes the key.
_COMPOSED: dict = {}
_COMPOSED_MAX = 256


def _config_files_state(folders) -> tuple:
    """(path, size, mtime) of every YAML file under ``folders``: what a composition read, to know when it is stale."""
    state = []
    for folder in dict.fromkeys(folders):
        for path in _yaml_files(folder):
            try:
                info = path.stat()
            except OSError:
                continue
            state.append((str(path), info.st_size, info.st_mtime_ns))
    return tuple(state)


def _yaml_files(folder, depth: int = 3, limit: int = 10_000) -> list[Path]:
    """The YAML files of a config folder, as Hydra lays them out (``config.yaml``, ``algo/snes.yaml``,
    ``hydra/launcher/joblib.yaml``): at most ``depth`` levels down and ``limit`` files, unreadable folders skipped -- a
    ``--config-path /`` is not a walk of the whole file system."""
    found, root = [], str(folder)
    for here, subfolders, names in os.walk(root, onerror=lambda err: None):
        level = here[len(root) :].count(os.sep)
        if level + 1 >= depth:
            subfolders[:] = []
        found += [Path(here) / name for name in sorted(names) if name.endswith(".yaml")]
        if len(found) >= limit:
            break
    return sorted(found[:limit])


def _search_order(config_name: str, config_dirs: tuple) -> tuple[str, list]:
    """Where to compose ``config_name`` from, through Hydra's public API, as the run composes it: the folder that holds the
    primary config, then (``hydra.searchpath`` overrides) the others.

    The run searches imix's conf/ (or ``--config-path``) first, then each ``--config-dir``; the public API cannot put a
    folder after the primary one, so a config in a ``--config-dir`` is composed from there, the others searched after it.
    The two orders compose the same config unless a file of a ``--config-dir`` has the path of one in conf/ -- which the
    run would silently ignore: that is refused (one line naming it)."""
    primary, *extra = config_dirs or (config_dir(),)
    own = {p.relative_to(primary) for p in _yaml_files(primary)}
    for folder in extra:
        shadowed = sorted(str(p.relative_to(folder)) for p in _yaml_files(folder) if p.relative_to(folder) in own)
        if shadowed:
            raise ConfigError(f"--config-dir {folder}: {shadowed[0]} has the name of imix's own {Path(primary) / shadowed[0]}, which Hydra "
                              "would use instead; rename it (and pick it with --config-name or group=option)")  # fmt: skip
    name = config_name.removesuffix(".yaml") + ".yaml"
    holder = next((folder for folder in (primary, *extra) if _is_file(Path(folder) / name)), primary)
    others = [folder for folder in (primary, *extra) if folder != holder]
    return holder, ([f"hydra.searchpath=[{','.join(_quoted('file://' + folder) for folder in others)}]"] if others else [])


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except OSError:  # a name too long for the file system (a fuzzed --config-name): no such config
        return False


def _quoted(text: str) -> str:
    """``text`` as a quoted string of Hydra's override grammar (a folder with spaces, commas or quotes in its name)."""
    return "'" + text.replace("\\", "\\\\").replace("'", "\\'") + "'"


def _refuse_hydra_settings(full) -> None:
    """ConfigError for Hydra settings imix does not honour, on the command line or in a ``--config-name`` YAML.

    ``hydra.job.chdir=true`` is refused rather than honoured: imix writes under ``results_dir`` relative to where the
    command starts, as the summary and the other commands (plot, status, eval) read it; a job that changed its working
    directory to Hydra's job folder wrote its results elsewhere than the summary said, and a re-run recomputed instead
    of resuming. ``hydra.callbacks`` instantiate any class a YAML names (``_target_: os.system``): a config received
    from someone else would run code before the first line of imix's."""
    from omegaconf import OmegaConf

    if OmegaConf.select(full, "hydra.job.chdir") is True:
        raise ConfigError("hydra.job.chdir=true: not supported; imix writes under results_dir from where it starts "
                          "(set results_dir=/some/path to put results elsewhere)")  # fmt: skip
    if OmegaConf.select(full, "hydra.callbacks"):
        raise ConfigError(f"hydra.callbacks ({', '.join(map(str, OmegaConf.select(full, 'hydra.callbacks')))}): imix runs no Hydra callbacks "
                          "(a callback runs any code its config names); remove them from the config")  # fmt: skip


def _resolved(cfg, with_hydra) -> dict:
    """``cfg`` as a plain dict with its interpolations resolved, ``${hydra:...}`` ones included: the run resolves them with
    Hydra's config set (``results_dir=${hydra:runtime.cwd}/results`` is a path a user may well give), so they resolve
    here against this composition's hydra node (``with_hydra``: the composed config with it; its ``hydra.runtime.cwd`` is
    the current folder, as in the run)."""
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    previous = HydraConfig.instance().cfg
    # First without Hydra's config (setting it copies the whole hydra node: a third of a validation's time, which
    # a 2,000-point sweep pays per point); with none set, a ${hydra:...} fails to resolve instead of reading a stale one.
    HydraConfig.instance().cfg = None
    try:
        try:
            return OmegaConf.to_container(cfg, resolve=True)
        except OmegaConfBaseException:
            HydraConfig.instance().set_config(with_hydra)
            return OmegaConf.to_container(cfg, resolve=True)
    finally:
        HydraConfig.instance().cfg = previous


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
        raise ConfigError(f"{group}={shown_value(value)}: unknown {group}; valid choices are {', '.join(valid)}")
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
        raise ConfigError(f"{key}={shown_value(v)}: a {type(v).__name__} is not a value of the config (give a str, number, bool, None or list)")

    for key, v in values.items():
        try:
            OmegaConf.update(cfg, key, plain(key, v), merge=True)
        except (ConfigAttributeError, ConfigKeyError):
            raise ConfigError(unknown_key_message(key)) from None  # the command line's line: one did-you-mean (issue 47, case 6)
        except OmegaConfBaseException as err:
            raise ConfigError(f"{key}={shown_value(v)}: {first_line(err)}") from None


def _unparsable(err: Exception, lines: list, parser) -> ConfigError:
    """The one line for an override Hydra's grammar cannot read: the override named, and -- for a value that is not
    quoted -- the quoted form to type. Hydra's unquoted values are plain words and numbers (ASCII letters, digits and a
    few signs): ``experiment=é`` came out as "LexerNoViableAltException: experiment=é", ``experiment=a)b`` as
    "mismatched input ')'"."""
    culprit = None
    for line in lines:
        try:
            parser.parse_overrides([line])
        except Exception:  # noqa: BLE001 - any parse error: this is the override to name
            culprit = line
            break
    reason = first_line(err)
    lexer = "LexerNoViableAltException" in reason
    if culprit is None or "=" not in culprit:
        return ConfigError(f"cannot parse overrides: {_shown(reason, 200)}")
    key, value = culprit.split("=", 1)
    why = "a character Hydra's override grammar has no rule for" if lexer else _shown(reason, 200)
    if value[:1] in ("'", '"') or not key or len(culprit) > 200 or not culprit.isprintable():
        return ConfigError(f"{_shown(culprit)}: cannot be read ({why})")
    whole = f'"{key}={_quoted(value)}"'
    if "," in value:  # a sweep: each value quoted that is not a plain word or number
        each = ",".join(v if re.fullmatch(r"[A-Za-z0-9_.+-]+", v) else _quoted(v) for v in value.split(","))
        return ConfigError(f'{culprit}: cannot be read unquoted ({why}); quote each value, for the shell too: "{key}={each}" (or {whole}: one value)')
    return ConfigError(f"{culprit}: cannot be read unquoted ({why}); quote the value, for the shell too: {whole}")


def uses_search_sweeper(parsed) -> bool:
    """Whether parsed overrides choose imix's Optuna sweeper (``hydra/sweeper=optuna``): their search spaces are then
    probed (:func:`imix_cli.running.config.search.probe_values`), not enumerated."""
    return any(o.key_or_group == "hydra/sweeper" and not o.is_sweep_override() and o.value() == "optuna" for o in parsed)


def override_value_text(value) -> str:
    """A Python value back as an override's value text: ``true``, ``null``, ``0.25``, a plain word, else quoted."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "null"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, str) and not re.fullmatch(r"[A-Za-z0-9_.+-]+", value):
        return _quoted(value)
    return str(value)


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
            changes = ", ".join(f"{k}={shown_value(old.get(k))} / {shown_value(new.get(k))}" for k in differing)
            raise ConfigError(
                f"two sweep points would share the folder {spec.run_dir} but differ in {changes}; "
                "sweep that key in separate commands with their own experiment="
            )


def _explain_compose_error(err: Exception, point) -> str:
    text = str(err)
    sweeper_key = re.search(r"(hydra\.sweeper\.[A-Za-z0-9_]+)", text) if "hydra/sweeper=optuna" in point else None
    if sweeper_key and ("not in struct" in text or "Could not override" in text):
        return f"unknown key {sweeper_key.group(1)}; valid keys of hydra/sweeper=optuna: {', '.join(SWEEPER_KEYS[1:])}"
    if "not in struct" in text or "Could not override" in text or "Key '" in text and "is not in struct" in text:
        return unknown_key_message(_unknown_key_of(text, point) or first_line(err))
    missing = re.search(r"Could not find '([^']+)/([^'/]+)'", text)
    if missing:  # a config group option that does not exist, e.g. hydra/launcher=nope
        group, option = missing.groups()
        return f"{_shown(group)}={_shown(option)}: no such option in config group {_shown(group)}"
    return f"bad override ({', '.join(map(_shown, point))}): {_shown(first_line(err), 200)}"


def _shown(text: str, limit: int = 100) -> str:
    """``text`` as a message shows a user's input: as is if short and printable, else quoted with its newlines and
    control characters escaped and cut at ``limit`` characters -- the message stays one readable line."""
    if text.isprintable() and len(text) <= limit:
        return text
    return repr(text[:limit]) + ("..." if len(text) > limit else "")


def _unknown_key_of(text: str, point) -> str | None:
    """The key a "not in struct" / "Could not override" error is about: the full key the message quotes (Hydra's
    ``full_key: algo.stlye``, our ``Could not override 'algo.stlye'``), else the longest key of the point's overrides the
    message mentions -- the longest, so that ``algo.stlye`` is named rather than ``algo``, which the message also contains."""
    quoted = re.search(r"full_key: (\S+)", text) or re.search(r"Could not override '([^']+)'", text)
    if quoted:
        return quoted.group(1)
    keys = sorted((p.split("=", 1)[0].lstrip("+~") for p in point), key=len, reverse=True)
    return next((k for k in keys if k and k in text), None)
