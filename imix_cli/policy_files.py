"""Policy files: a trained policy as data (``.npz`` arrays + a JSON header), never a pickle.

Why: a run's result is the policy it learned, not only its learning curves. ``imix eval`` and
``imix render`` (and any outside tool) read these files back without running imix's code
paths that trained them: the header says how to rebuild the network and on which env it acts.

Each ES seed ``k`` of a run writes, beside ``seed_<k>.csv`` (see :func:`write_seed_policies`):

* ``policy_<k>_mean.npz``: the final search-distribution mean θ (the policy one deploys);
* ``policy_<k>_best.npz``: the best-ever evaluated member and its (training) return.

File layout (``np.load(path, allow_pickle=False)`` reads it)::

    params   float64 (d,)   the flat MLP parameter vector (layout: imix_cli.policies)
    header   str scalar     JSON, the fields of HEADER_FIELDS below

A file is written atomically (temporary file + rename, :func:`imix_cli.results.atomic_write_bytes`),
so a reader never sees half a policy.
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imix_cli.results import atomic_write_bytes

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
    "discrete",  # true: action = action_start + argmax(outputs); false: tanh(outputs) mapped onto the bounds
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


class PolicyFileError(ValueError):
    """A policy file is missing, unreadable or not an imix policy; one-line message naming it."""


@dataclass
class PolicyFile:
    params: np.ndarray  # (d,) float64
    header: dict

    def batch_policy(self, n: int = 1):
        """A :class:`imix_cli.policies.BatchPolicy` of ``n`` copies of this policy (actions before
        ``action_start`` is added)."""
        from imix_cli.policies import BatchPolicy

        h = self.header
        return BatchPolicy(
            np.repeat(self.params[None, :], n, axis=0), h["obs_dim"], h["out_dim"], discrete=h["discrete"],
            hidden=h["hidden"], low=h["action_low"], high=h["action_high"],
        )  # fmt: skip


def policy_path(run_dir, seed: int, which: str) -> Path:
    return Path(run_dir) / f"policy_{seed}_{which}.npz"


def config_hash(identity: dict) -> str:
    """sha256 (first 16 hex digits) of a config's result-determining keys, JSON with sorted keys."""
    text = json.dumps(identity, sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def architecture_of(evaluator) -> dict:
    """The header's network and action fields, from an :class:`imix_cli.evaluation.BatchEvaluator`."""
    low = getattr(evaluator, "_low", None)
    high = getattr(evaluator, "_high", None)
    return {
        "obs_dim": int(evaluator.obs_dim),
        "out_dim": int(evaluator.out_dim),
        "hidden": [int(h) for h in evaluator.hidden],
        "discrete": bool(evaluator.discrete),
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


def read_policy(path) -> PolicyFile:
    """Read a policy file; raises :class:`PolicyFileError` naming the file if it is not a valid one."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            params = np.asarray(data["params"], dtype=np.float64)
            header = json.loads(str(data["header"][()]))
    except FileNotFoundError:
        raise PolicyFileError(f"{path}: no such policy file") from None
    except Exception as err:  # zip, key, JSON or pickle-refused errors: all mean "not a policy file"
        raise PolicyFileError(f"{path}: not a readable imix policy file ({type(err).__name__})") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise PolicyFileError(f"{path}: not an {FORMAT} file (format={header.get('format') if isinstance(header, dict) else None!r})")
    from imix_cli.policies import num_params

    expected = num_params(header["obs_dim"], header["out_dim"], header["hidden"])
    if params.ndim != 1 or params.size != expected:
        raise PolicyFileError(f"{path}: params have shape {params.shape}, the header's network needs ({expected},)")
    return PolicyFile(params, header)


def write_seed_policies(spec, seed: int, evaluator, mean, best, best_return: float, generation: int) -> list[Path]:
    """Write ``policy_<seed>_mean.npz`` and ``policy_<seed>_best.npz`` of a finished ES seed.

    ``spec`` is the run's :class:`imix_cli.run_spec.RunSpec`; ``mean`` the final distribution mean,
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
