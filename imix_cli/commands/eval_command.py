"""``imix eval``: the saved policies of every seed, evaluated on fresh episodes.

Why: training scores are the population's on the episodes it was trained on; the number to
report for a learned policy is its return on episodes it never saw. This reads the policy files
of each run (:mod:`imix_cli.running.files.policy_files`), runs ``episodes`` episodes per seed with the batched
evaluator the run trained with, prints mean ± 95 % CI over seeds per run and writes
``<run>/eval.csv`` (one row per seed and ``which``).

Fresh episode seeds: seed ``k``'s evaluation episodes take their seeds from
``SeedSequence(k, spawn_key=(EVAL_STREAM,))``. Training draws from ``SeedSequence(k).spawn(2)``
(spawn keys (0,) and (1,)) and DDPG from seed ``k`` itself, so the evaluation stream is a
different, independent stream; its 63-bit episode seeds coincide with a training episode's with
probability below 1e-12 per run. Same files and arguments, same numbers (deterministic by seed).
"""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path

import numpy as np

from imix_cli.keyvalue import UsageError, at_least, folder_name, help_requested, one_of, parse_key_values

HELP = """\
usage: imix eval [key=value ...]

Evaluate the saved policies (policy_<k>_<which>.npz) of every seed of every run of an
experiment on fresh episodes (seeds disjoint from training), print mean ± 95 % CI over
seeds per run, and write <run>/eval.csv.

keys:
  results_dir=PATH   folder holding the experiments (default: results)
  experiment=NAME    experiment to evaluate (default: default)
  run=NAME           only this run folder (default: every run with policy files)
  episodes=N         episodes per seed, >= 1 (default: 100)
  which=mean|best    mean: the final search-distribution mean; best: the best-ever member
                     (default: mean)
  import=MODULE[,..] modules to import for runs of your own env (env.id=MODULE:Id): a policy
                     file never makes imix import a module you did not name here
"""

#: Spawn key of the evaluation episode stream (ASCII "eval"); training uses spawn keys 0 and 1.
EVAL_STREAM = 0x6576616C

EVAL_COLUMNS = (
    "run", "seed", "which", "episodes", "mean_return", "std_return", "min_return", "max_return",
    "mean_steps", "train_generation", "train_return", "config_hash",
)  # fmt: skip

_POLICY_FILE = re.compile(r"^policy_(\d+)_(mean|best)\.npz$")
_NOT_RUNS = {"figures"}


def _modules(key: str, value: str) -> tuple:
    from imix_cli.core.envs.ids import EnvIdError, user_modules

    try:
        return user_modules(value)
    except EnvIdError as err:
        raise UsageError(str(err)) from None


#: The keys that choose policy files, shared by ``imix eval`` and ``imix render``: defaults and checks.
#: ``import``: the modules the user allows a policy's ``module:Id`` env id to name (imix_cli.core.envs.ids).
POLICY_KEYS = {"results_dir": "results", "experiment": "default", "run": None, "which": "mean", "import": ()}
POLICY_KEY_CHECKS = {"experiment": folder_name, "run": folder_name, "which": one_of("mean", "best"), "import": _modules}

#: ``episodes=`` at most: evaluation runs in batches (memory does not grow with it), but 10 million
#: episodes per seed already take hours; more is a typo (``1e9``), refused in one line.
MAX_EPISODES = 10_000_000
#: Episodes evaluated at once: their parameter copies take at most ~64 MB.
_BATCH_BYTES = 64 << 20
_MAX_BATCH = 10_000


def run_folders(results_dir, experiment: str, run: str | None = None) -> list[Path]:
    """The run folders of an experiment (or just ``run``); UsageError (status 1) if there are none."""
    exp_dir = Path(results_dir) / experiment
    if not exp_dir.is_dir():
        raise UsageError(f"no experiment at {exp_dir} (check results_dir= and experiment=)", 1)
    folders = sorted(p for p in exp_dir.iterdir() if p.is_dir() and p.name not in _NOT_RUNS and not p.name.startswith((".", "_")))
    if run is not None:
        if not (exp_dir / run).is_dir():
            names = ", ".join(p.name for p in folders) or "none"
            raise UsageError(f"bad value for run: {run!r} is not a run folder of {exp_dir} (runs: {names})", 1)
        folders = [exp_dir / run]
    return folders


def policy_files(run_dir: Path, which: str) -> dict:
    """seed -> path of ``policy_<seed>_<which>.npz`` in ``run_dir``."""
    found = {}
    for path in Path(run_dir).iterdir():
        match = _POLICY_FILE.match(path.name)
        if match and match.group(2) == which:
            found[int(match.group(1))] = path
    return dict(sorted(found.items()))


def eval_episode_seeds(seed: int, episodes: int) -> np.ndarray:
    """The episode seeds of seed ``seed``'s evaluation: the first ``episodes`` draws of its eval stream."""
    rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(EVAL_STREAM,)))
    return rng.integers(0, np.iinfo(np.int64).max, size=int(episodes), dtype=np.int64)


def policy_env(header: dict, allowed_modules=(), where: str = "policy file") -> str:
    """The env a policy acts in, as :func:`imix_cli.core.evaluation.make_evaluator` takes it: a built-in's
    name, or a registered gymnasium id (plain, without ``module:``). A ``module:Id`` in the file is
    refused unless the user named that module (``import=``): files never import code."""
    from imix_cli.core.envs.ids import EnvIdError, file_env_id
    from imix_cli.core.registry import BUILTIN_ENVS
    from imix_cli.running.files.policy_files import PolicyFileError

    name = header["env_name"]
    if ":" in header["env_id"] or name not in BUILTIN_ENVS:  # a module named in the file: refused unless the user named it
        try:
            plain = file_env_id(header["env_id"], allowed_modules, where)
        except EnvIdError as err:
            raise PolicyFileError(str(err)) from None
        if name not in BUILTIN_ENVS:
            return plain
    if name in BUILTIN_ENVS:
        if header["env_id"] != BUILTIN_ENVS[name]:
            raise PolicyFileError(f"{where}: header env_id={header['env_id']!r} is not env_name={name}'s ({BUILTIN_ENVS[name]})")
        return name


def episode_cap(header: dict, env: str, run_dir=None) -> int:
    """The longest episode the policy's run used: its config.yaml's ``env.max_steps``, else the env's own cap."""
    from imix_cli.core.registry import BUILTIN_ENVS, ENV_SPECS

    configured = _config_max_steps(run_dir)
    if configured is not None:
        return configured
    if env in BUILTIN_ENVS:
        return ENV_SPECS[env].max_steps
    import gymnasium as gym

    from imix_cli.running.files.policy_files import MAX_STEPS

    return gym.spec(env).max_episode_steps or MAX_STEPS


def _config_max_steps(run_dir) -> int | None:
    """``env.max_steps`` of ``<run_dir>/config.yaml`` if it is there, small and an integer; else None."""
    if run_dir is None:
        return None
    path = Path(run_dir) / "config.yaml"
    try:
        if not path.is_file():
            return None
        from imix_cli.running.files.safe_yaml import load_yaml_file

        value = (load_yaml_file(path) or {}).get("env", {}).get("max_steps")  # bounded: size, nesting, aliases, tags
    except Exception:  # an unreadable config.yaml: fall back to the env's own cap
        return None
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 1 else None


def config_env_kwargs(run_dir) -> dict:
    """``env.kwargs`` of ``<run_dir>/config.yaml`` (the env's constructor arguments the run was trained with), ``{}`` if
    none or unreadable: the policy is evaluated (and rendered) in the env it was trained in."""
    if run_dir is None:
        return {}
    path = Path(run_dir) / "config.yaml"
    try:
        if not path.is_file():
            return {}
        from imix_cli.running.files.safe_yaml import load_yaml_file

        value = (load_yaml_file(path) or {}).get("env", {}).get("kwargs")  # bounded: size, nesting, aliases, tags
    except Exception:  # an unreadable config.yaml: the seed checks refuse it elsewhere
        return {}
    return dict(value) if isinstance(value, dict) and all(isinstance(k, str) for k in value) else {}


def evaluator_for(header: dict, cache: dict | None = None, allowed_modules=(), run_dir=None, where: str = "policy file"):
    """The batched evaluator a policy was trained with (from its header, checked against the env)."""
    from imix_cli.core.evaluation import make_evaluator
    from imix_cli.running.files.policy_files import PolicyFileError

    if header.get("obs_normalizer") is not None:
        raise UsageError(
            f"policy of run {header.get('run')!r} seed {header.get('seed')} normalises observations; "
            "this imix eval cannot apply a normaliser yet", 1
        )  # fmt: skip
    env = policy_env(header, allowed_modules, where)
    cap = episode_cap(header, env, run_dir)
    if header["max_steps"] > cap:
        raise PolicyFileError(f"{where}: header field max_steps={header['max_steps']!r} is above the run's episode cap ({cap}); not evaluated")
    hidden = tuple(int(h) for h in header["hidden"])  # policy.hidden of the run
    env_kwargs = config_env_kwargs(run_dir)
    key = (env, header["max_steps"], hidden, header["output"], repr(sorted(env_kwargs.items())))
    cache = {} if cache is None else cache
    if key not in cache:
        from imix_cli.core.evaluation import missing_extra_message
        from imix_cli.messages import MissingExtraError

        missing = missing_extra_message(env)  # a MuJoCo run evaluated where mujoco is not installed: the one status of a missing extra
        if missing:
            raise MissingExtraError(f"{where}: {missing}")
        try:
            cache[key] = make_evaluator(env, header["max_steps"], hidden=hidden, output=header["output"], env_kwargs=env_kwargs)
        except ValueError as err:
            raise PolicyFileError(f"{where}: cannot evaluate on {env}: {str(err).splitlines()[0] if str(err) else type(err).__name__}") from None
    evaluator = cache[key]
    got = (int(evaluator.obs_dim), int(evaluator.out_dim), bool(evaluator.discrete))
    if got != (header["obs_dim"], header["out_dim"], header["discrete"]):
        raise PolicyFileError(
            f"{where}: header says obs_dim={header['obs_dim']}, out_dim={header['out_dim']}, discrete={header['discrete']}; "
            f"{env} has {got[0]}, {got[1]}, {got[2]}"
        )
    return evaluator


def evaluate_policy(policy, episodes: int, cache: dict | None = None, allowed_modules=(), run_dir=None, where: str = "policy file") -> dict:
    """Statistics of ``episodes`` fresh episodes of a :class:`~imix_cli.running.files.policy_files.PolicyFile`:
    ``mean``, ``std`` (ddof 1, NaN for one episode), ``min``, ``max`` of the returns, ``mean_steps``.

    Episodes run in batches (at most ~64 MB of parameter copies), so memory does not grow with
    ``episodes``; the batches draw the same episode seeds as one draw would
    (:func:`eval_episode_seeds`), and one batch (``episodes`` up to 10,000 for small policies)
    is exactly one call of the evaluator.
    """
    evaluator = evaluator_for(policy.header, cache, allowed_modules, run_dir, where)
    d = policy.params.size
    batch = int(max(1, min(_MAX_BATCH, _BATCH_BYTES // (8 * d))))
    rng = np.random.default_rng(np.random.SeedSequence(int(policy.header["seed"]), spawn_key=(EVAL_STREAM,)))
    n, mean, m2, low, high, steps = 0, 0.0, 0.0, math.inf, -math.inf, 0.0
    for start in range(0, episodes, batch):
        size = min(batch, episodes - start)
        seeds = rng.integers(0, np.iinfo(np.int64).max, size=size, dtype=np.int64)  # = eval_episode_seeds, batch by batch
        returns, lengths = evaluator.evaluate(np.repeat(policy.params[None, :], size, axis=0), seeds)
        returns = np.asarray(returns, dtype=np.float64)
        b_mean = float(np.mean(returns))
        b_m2 = float(np.sum((returns - b_mean) ** 2))
        delta, total = b_mean - mean, n + size  # Chan et al.'s pairwise update of mean and sum of squares
        mean, m2 = (b_mean, b_m2) if n == 0 else (mean + delta * size / total, m2 + b_m2 + delta * delta * n * size / total)
        n, low, high = total, min(low, float(np.min(returns))), max(high, float(np.max(returns)))
        steps += float(np.sum(lengths))
    std = math.sqrt(m2 / (n - 1)) if n > 1 else math.nan
    return {"mean": mean, "std": std, "min": low, "max": high, "mean_steps": steps / n}


def evaluate_run(run_dir: Path, which: str, episodes: int, cache: dict | None = None, allowed_modules=()):
    """Rows (dicts with :data:`EVAL_COLUMNS`) of every seed of one run folder, or [] without policy files."""
    from imix_cli.running.files.policy_files import PolicyFileError, read_policy

    rows = []
    policies = policy_files(run_dir, which)
    if policies:
        check_finished_seeds(run_dir, policies)
    for seed, path in policies.items():
        policy = read_policy(path)
        h = policy.header
        if h["seed"] != seed or h["which"] != which:
            raise PolicyFileError(f"{path}: header says seed {h['seed']}, which={h['which']!r}: not the file its name says")
        stats = evaluate_policy(policy, episodes, cache, allowed_modules, run_dir, str(path))
        rows.append(
            {
                "run": Path(run_dir).name, "seed": seed, "which": which, "episodes": episodes,
                "mean_return": stats["mean"], "std_return": stats["std"], "min_return": stats["min"], "max_return": stats["max"],
                "mean_steps": stats["mean_steps"], "train_generation": h.get("generation"),
                "train_return": h.get("train_return"), "config_hash": h.get("config_hash"),
            }
        )  # fmt: skip
    return rows


def check_finished_seeds(run_dir: Path, seeds) -> None:
    """CorruptResultError (one line naming the file) if the CSV of one of ``seeds`` contradicts the run's config.yaml
    (:func:`imix_cli.running.seed_checks.check_seed_csv`): its policies would be reported as the run's. A seed without a
    CSV (unfinished, its policy from a checkpoint) or a run without config.yaml is not checked."""
    from imix_cli.plotting.data import read_run_config
    from imix_cli.running.files.results import read_run_csv, seed_csv_path
    from imix_cli.running.seed_checks import check_seed_csv

    def warn(message: str) -> None:
        print(f"imix eval: warning: {message}", file=sys.stderr)

    config = read_run_config(Path(run_dir) / "config.yaml", warn, fallback="its seed CSVs are not checked against it")
    if not config:
        return
    for seed in seeds:
        path = seed_csv_path(run_dir, seed)
        if path.exists():
            check_seed_csv(read_run_csv(path), path, config)


def write_eval_csv(run_dir: Path, rows: list, root=None) -> Path:
    """Write ``<run_dir>/eval.csv`` through the one writer (:mod:`imix_cli.running.files.writing`: atomic, no link followed below
    ``root``, text cells neutralised), keeping the rows of the other ``which`` already there."""
    import pandas as pd

    from imix_cli.running.files.results import regular_file_size
    from imix_cli.running.files.writing import atomic_write_text, csv_text

    path = Path(run_dir) / "eval.csv"
    frame = pd.DataFrame(rows, columns=list(EVAL_COLUMNS))
    if path.exists() and not path.is_symlink():  # a link is not read (the writer refuses it below)
        try:
            if regular_file_size(path) > 64 << 20:  # an eval.csv is a few rows a seed; /dev/zero or a huge file is replaced, not read
                raise ValueError("not an eval.csv")
            old = pd.read_csv(path)
            old = old[old["which"] != rows[0]["which"]] if "which" in old.columns else old.iloc[0:0]
            frame = pd.concat([old.reindex(columns=list(EVAL_COLUMNS)), frame], ignore_index=True)
        except Exception:  # an unreadable old eval.csv is replaced, not merged
            pass
    frame = frame.sort_values(["which", "seed"], kind="stable")
    atomic_write_text(path, csv_text(frame, float_format="%.10g"), root=root)
    return path


def format_estimate(values, level: float = 0.95) -> str:
    """``mean ± half-width`` over seeds (Student t), or the bare value with one seed."""
    from imix_cli.core.stats import mean_ci

    mean, half, n = mean_ci(values, level)
    return f"{mean:.2f}" if n < 2 or not math.isfinite(half) else f"{mean:.2f} ± {half:.2f}"


def main(argv: list | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if help_requested(argv, HELP):
        return 0
    try:
        s = parse_key_values(argv, "eval", {**POLICY_KEYS, "episodes": 100}, convert={**POLICY_KEY_CHECKS, "episodes": at_least(1)})
        if s["episodes"] > MAX_EPISODES:
            raise UsageError(f"bad value for episodes: {s['episodes']} (at most {MAX_EPISODES:,} per seed: they run in batches, but more would take days)")
        folders = run_folders(s["results_dir"], s["experiment"], s["run"])
        from imix_cli.running.files.policy_files import PolicyFileError
        from imix_cli.running.files.results import CorruptResultError

        cache, results = {}, []
        for run_dir in folders:
            rows = evaluate_run(run_dir, s["which"], s["episodes"], cache, s["import"])
            if not rows:
                why = "unfinished, algo=ddpg, or run before policy files existed"
                print(f"imix eval: {run_dir.name}: no policy_<k>_{s['which']}.npz ({why}); skipped", file=sys.stderr)
                continue
            results.append((run_dir, rows))
    except UsageError as err:
        print(f"imix eval: {err}", file=sys.stderr)
        return err.status
    except (PolicyFileError, CorruptResultError) as err:
        print(f"imix eval: {err}", file=sys.stderr)
        return 1
    if not results:
        print(f"imix eval: no policy files to evaluate under {Path(s['results_dir']) / s['experiment']}", file=sys.stderr)
        return 1
    width = max(32, *(len(r[0].name) for r in results))
    print(f"{'run':<{width}} {'seeds':>5} {'return on fresh episodes (mean ± 95% CI over seeds)':>52}")
    for run_dir, rows in results:
        estimate = format_estimate([r["mean_return"] for r in rows])
        flag = "  (<5 seeds: CI unreliable)" if len(rows) < 5 else ""
        print(f"{run_dir.name:<{width}} {len(rows):>5} {estimate:>52}{flag}")
    print(f"({s['episodes']} episodes per seed, policy={s['which']}; per seed: <run>/eval.csv)")
    # The numbers are printed first: a read-only results folder (a colleague's) still gives them.
    for run_dir, rows in results:
        try:
            write_eval_csv(run_dir, rows, root=s["results_dir"])
        except OSError as err:
            where = err.filename or Path(run_dir) / "eval.csv"
            print(f"imix eval: cannot write {where} ({err.strerror or err}); the numbers above are not saved", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
