"""Policy files: a trained policy as data (``.npz`` arrays + a JSON header), never a pickle.

Why: a run's result is the policy it learned, not only its learning curves. ``imix eval`` and
``imix render`` (and any outside tool) read these files back without running imix's code
paths that trained them: the header says how to rebuild the network and on which env it acts.

Each ES seed ``k`` of a run writes, beside ``seed_<k>.csv`` (see :func:`write_seed_policies`):

* ``policy_<k>_mean.npz``: the final search-distribution mean θ (the policy one deploys);
* ``policy_<k>_best.npz``: the best-ever evaluated member and its (training) return.

File layout (``np.load(path, allow_pickle=False)`` reads it)::

    params   float64 (d,)   the flat MLP parameter vector (layout: imix_cli.core.evaluation.policies)
    header   str scalar     JSON, the fields of HEADER_FIELDS below

A file is written atomically (temporary file + rename, :func:`imix_cli.running.files.writing.atomic_write_bytes`),
so a reader never sees half a policy.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imix_cli.running.files.results import regular_file_size
from imix_cli.running.files.writing import atomic_write_bytes

FORMAT = "imix-policy/1"
WHICH = ("mean", "best")

#: The JSON header's fields (all present; null where not applicable).
HEADER_FIELDS = (
    "format",  # FORMAT: bumped on an incompatible change
    "env_name",  # config name (cartpole, acrobot, ...) or the gymnasium id of a generic env
    "env_id",  # gymnasium id the env reproduces (CartPole-v0, imix/ContinuousCartPole-v0, ...)
    "max_steps",  # episode cap used in training (null: the env's own time limit)
    "obs_dim",  # policy inputs
    "out_dim",  # policy outputs (discrete: number of actions; continuous: action dimensions)
    "hidden",  # hidden layer sizes, tanh units
    "discrete",  # true: action = action_start + argmax(outputs); false: see output
    "output",  # continuous actions: "tanh" (tanh of the outputs mapped onto the bounds) or "clip" (clipped to them)
    "action_start",  # first discrete action (gymnasium Discrete.start), 0 otherwise
    "action_low",  # continuous: per-dimension lower bounds (null: [-1, 1]); discrete: null
    "action_high",  # continuous: per-dimension upper bounds; discrete: null
    "obs_normalizer",  # null, or {"mean": [...], "var": [...], ...}: observations are normalised first
    "imix_version",
    "algo",
    "mixing",
    "run",  # run folder name
    "config_hash",  # sha256 (16 hex) of the result-determining config (config.yaml minus seeds/workers/...)
    "seed",
    "which",  # "mean" (final distribution mean) or "best" (best-ever member)
    "generation",  # generations completed when written
    "train_return",  # "best": the member's training return; "mean": null (θ itself is never evaluated in training)
)

#: Fields a file may lack because it was written before they existed, and what such a file meant.
HEADER_DEFAULTS = {"output": "tanh"}


class PolicyFileError(ValueError):
    """A policy file is missing, unreadable or not an imix policy; one-line message naming it."""


@dataclass
class PolicyFile:
    params: np.ndarray  # (d,) float64
    header: dict

    def batch_policy(self, n: int = 1):
        """A :class:`imix_cli.core.evaluation.policies.BatchPolicy` of ``n`` copies of this policy (actions before
        ``action_start`` is added)."""
        from imix_cli.core.evaluation.policies import BatchPolicy

        h = self.header
        return BatchPolicy(
            np.repeat(self.params[None, :], n, axis=0), h["obs_dim"], h["out_dim"], discrete=h["discrete"],
            hidden=h["hidden"], low=h["action_low"], high=h["action_high"], output=h["output"],
        )  # fmt: skip


def policy_path(run_dir, seed: int, which: str) -> Path:
    return Path(run_dir) / f"policy_{seed}_{which}.npz"


def config_hash(identity: dict) -> str:
    """sha256 (first 16 hex digits) of a config's result-determining keys, JSON with sorted keys."""
    text = json.dumps(identity, sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def architecture_of(evaluator) -> dict:
    """The header's network and action fields, from an :class:`imix_cli.core.evaluation.BatchEvaluator`."""
    low = getattr(evaluator, "_low", None)
    high = getattr(evaluator, "_high", None)
    return {
        "obs_dim": int(evaluator.obs_dim),
        "out_dim": int(evaluator.out_dim),
        "hidden": [int(h) for h in evaluator.hidden],
        "discrete": bool(evaluator.discrete),
        "output": str(getattr(evaluator, "output", "tanh")),
        "action_start": int(getattr(evaluator, "_start", 0) or 0),
        "action_low": None if low is None else [float(v) for v in low],
        "action_high": None if high is None else [float(v) for v in high],
    }


def write_policy(path, params, header: dict) -> None:
    """Write ``params`` and ``header`` (every field of :data:`HEADER_FIELDS`) atomically to ``path``."""
    missing = [k for k in HEADER_FIELDS if k not in header]
    if missing:
        raise ValueError(f"policy header lacks {missing}")
    params = np.asarray(params, dtype=np.float64).reshape(-1)
    text = json.dumps({k: header[k] for k in HEADER_FIELDS}, allow_nan=True)
    buffer = io.BytesIO()
    np.savez(buffer, params=params, header=np.array(text))
    atomic_write_bytes(path, buffer.getvalue())


#: Bounds of a policy file: its JSON header, and its network (parameters, layers, widths). They are
#: far above any policy imix trains (a MuJoCo 64x64 policy has ~6k parameters) and keep what a
#: forged file can make ``eval`` allocate to ~128 MB.
MAX_HEADER_CHARS = 1_000_000
MAX_PARAMS = 1 << 24
MAX_LAYERS = 16
MAX_WIDTH = 1 << 16
#: The longest episode a policy header may ask for; the run's config.yaml or the env's cap
#: bounds it further in ``imix eval`` (:mod:`imix_cli.commands.eval_command`).
MAX_STEPS = 10_000_000


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def validate_header(header, where: str = "policy file") -> dict:
    """``header`` if every field has the type and range :data:`HEADER_FIELDS` describes; PolicyFileError naming the field otherwise.

    Why: the header drives what ``eval`` and ``render`` build (network shapes, action bounds,
    episode length); a field of the wrong type or range must be one line, not a traceback or a
    score of something else.
    """

    def bad(field, why):
        return PolicyFileError(f"{where}: header field {field}={header.get(field)!r} {why}")

    if not isinstance(header, dict) or header.get("format") != FORMAT:
        found = header.get("format") if isinstance(header, dict) else None
        raise PolicyFileError(f"{where}: not an {FORMAT} file (format={found!r})")
    from imix_cli.core.evaluation.policies import OUTPUTS

    header = {**header, **{k: v for k, v in HEADER_DEFAULTS.items() if k not in header}}
    missing = [k for k in HEADER_FIELDS if k not in header]
    if missing:
        raise PolicyFileError(f"{where}: header lacks {missing}")
    for field in ("env_name", "env_id"):
        if not isinstance(header[field], str) or not header[field] or len(header[field]) > 200:
            raise bad(field, "is not an env name")
    for field, low, high in (("obs_dim", 1, MAX_WIDTH), ("out_dim", 1, MAX_WIDTH), ("max_steps", 1, MAX_STEPS), ("seed", 0, 2**63 - 1)):
        if not _is_int(header[field]) or not low <= header[field] <= high:
            raise bad(field, f"is not an integer in [{low}, {high}]")
    hidden = header["hidden"]
    if not isinstance(hidden, list) or len(hidden) > MAX_LAYERS or not all(_is_int(h) and 1 <= h <= MAX_WIDTH for h in hidden):
        raise bad("hidden", f"is not a list of at most {MAX_LAYERS} layer sizes in [1, {MAX_WIDTH}]")
    if not isinstance(header["discrete"], bool):
        raise bad("discrete", "is not true or false")
    if header["output"] not in OUTPUTS:
        raise bad("output", f"is not one of {list(OUTPUTS)}")
    if not _is_int(header["action_start"]) or abs(header["action_start"]) > 2**31:
        raise bad("action_start", "is not an integer")
    if header["discrete"]:
        if header["out_dim"] < 1 or header["action_low"] is not None or header["action_high"] is not None:
            raise bad("action_low", "must be null for discrete actions")
    else:
        for field in ("action_low", "action_high"):
            value = header[field]
            finite = isinstance(value, list) and all(_is_number(v) and math.isfinite(v) for v in value)
            if value is not None and (not finite or len(value) != header["out_dim"]):
                raise bad(field, f"is not null or {header['out_dim']} finite numbers")
        if (header["action_low"] is None) != (header["action_high"] is None) or (
            header["action_low"] is not None and not all(lo < hi for lo, hi in zip(header["action_low"], header["action_high"], strict=True))
        ):
            raise bad("action_high", "must be above action_low, both given or both null")
    if header["which"] not in WHICH:
        raise bad("which", f"is not one of {list(WHICH)}")
    if not _is_int(header["generation"]) or header["generation"] < 0:
        raise bad("generation", "is not an integer >= 0")
    train_return = header["train_return"]
    if train_return is not None and (not _is_number(train_return) or not math.isfinite(train_return) or abs(train_return) > 1e12):
        raise bad("train_return", "is not null or a finite return")
    for field in ("imix_version", "algo", "mixing", "run", "config_hash"):
        if header[field] is not None and not isinstance(header[field], str):
            raise bad(field, "is not a string")
    if num_params_of(header) > MAX_PARAMS:
        raise PolicyFileError(f"{where}: the header's network has {num_params_of(header):,} parameters, more than {MAX_PARAMS:,}")
    return header


def num_params_of(header: dict) -> int:
    from imix_cli.core.evaluation.policies import num_params

    return num_params(header["obs_dim"], header["out_dim"], header["hidden"])


def read_policy(path) -> PolicyFile:
    """Read a policy file; raises :class:`PolicyFileError` (one line naming the file) if it is not a valid one.

    Memory is bounded whatever the file holds (:func:`imix_cli.running.files.safe_npz.read_npz`): the header is read
    first (at most :data:`MAX_HEADER_CHARS`), then the parameters only if their declared shape is the
    one the header's network needs. The header's fields are checked (:func:`validate_header`) and the
    parameters must be finite: a NaN or infinite weight is refused, not scored.
    """
    from imix_cli.running.files.safe_npz import NpzLimitError, read_npz

    path = Path(path)
    header_bytes = 4 * MAX_HEADER_CHARS + 1024  # a '<U' scalar: 4 bytes a character
    try:
        regular_file_size(path)
        header_array = read_npz(path, header_bytes + 8 * MAX_PARAMS + 1024, _policy_member_check(path), names=("params", "header"), only="header")
        header = validate_header(json.loads(str(header_array["header"][()])), str(path))
        expected = num_params_of(header)

        def params_shape(name, shape, dtype):
            if name == "params" and (shape != (expected,) or dtype != np.float64):
                raise PolicyFileError(f"{path}: params are {dtype} {shape}, the header's network needs float64 ({expected},)")

        params = read_npz(path, header_bytes + 8 * expected + 1024, params_shape, names=("params", "header"), only="params")["params"]
    except FileNotFoundError:
        raise PolicyFileError(f"{path}: no such policy file") from None
    except IsADirectoryError:
        raise PolicyFileError(f"{path}: is a folder, not a policy file") from None
    except OSError as err:
        raise PolicyFileError(f"{path}: {err.strerror or err}") from None
    except PolicyFileError:
        raise
    except NpzLimitError as err:
        raise PolicyFileError(f"{path}: not a readable imix policy file ({err})") from None
    except Exception as err:  # zip, JSON or pickle-refused errors: all mean "not a policy file"
        raise PolicyFileError(f"{path}: not a readable imix policy file ({type(err).__name__})") from None
    if not np.all(np.isfinite(params)):
        raise PolicyFileError(f"{path}: {int(np.count_nonzero(~np.isfinite(params)))} of its {params.size} weights are NaN or infinite; not evaluated")
    return PolicyFile(np.asarray(params, dtype=np.float64), header)


def _policy_member_check(path):
    def check(name, shape, dtype):
        if name == "header" and (dtype.kind != "U" or shape != () or dtype.itemsize > 4 * MAX_HEADER_CHARS):
            raise PolicyFileError(f"{path}: header is not a JSON string of at most {MAX_HEADER_CHARS:,} characters")
        if name == "params" and (len(shape) != 1 or dtype != np.float64 or shape[0] > MAX_PARAMS):
            raise PolicyFileError(f"{path}: params are {dtype} {shape}, not at most {MAX_PARAMS:,} float64 numbers")

    return check


def write_seed_policies(spec, seed: int, evaluator, mean, best, best_return: float, generation: int) -> list[Path]:
    """Write ``policy_<seed>_mean.npz`` and ``policy_<seed>_best.npz`` of a finished ES seed.

    ``spec`` is the run's :class:`imix_cli.running.config.run_spec.RunSpec`; ``mean`` the final distribution mean,
    ``best``/``best_return`` the best-ever member and its return (``best`` None: not written).
    """
    from imix_cli import __version__

    common = {
        "format": FORMAT,
        "env_name": spec.env_name,
        "env_id": spec.env_id,
        "max_steps": spec.env_max_steps if spec.env_max_steps is not None else int(evaluator.max_steps),
        **architecture_of(evaluator),
        "obs_normalizer": None,
        "imix_version": __version__,
        "algo": spec.algo,
        "mixing": spec.mixing,
        "run": spec.run_name,
        "config_hash": config_hash(spec.identity()),
        "seed": int(seed),
        "generation": int(generation),
    }
    paths = [policy_path(spec.run_dir, seed, "mean")]
    write_policy(paths[0], mean, {**common, "which": "mean", "train_return": None})
    if best is not None:
        paths.append(policy_path(spec.run_dir, seed, "best"))
        write_policy(paths[1], best, {**common, "which": "best", "train_return": float(best_return)})
    return paths
