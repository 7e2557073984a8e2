"""Resuming a seed: its checkpoint read back, and checked against the run it is to continue.

A checkpoint (:mod:`imix_cli.running.files.checkpoints`: the file, its format, where it lives, and writing it)
holds a seed's whole state (:class:`imix_cli.running.loop.lockstep.SeedState`: ES, archive, RNG states, rows so
far). One that is damaged, of another seed or config, not a checkpoint at all, or holding a value the
run could not have produced is refused with one warning line naming the file and why, and its seed
restarts from scratch.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from imix_cli.core.distributions import AffinePushforward
from imix_cli.core.evaluation.policies import NormalizerChange
from imix_cli.core.mixing import variant_spec
from imix_cli.core.mixing.generation import scheme_of
from imix_cli.messages import warn as _warn
from imix_cli.running.files.checkpoints import DEFAULT_MAX_BYTES, CheckpointError, checkpoint_path, load_or_warn
from imix_cli.running.files.results import COLUMNS


def load_checkpoint(run_dir: Path, seed: int, identity: dict, fresh, warn=None, spec=None, max_steps: int | None = None, policy_dim: int | None = None):
    """The saved state of ``seed`` (built on ``fresh``, a new state of the same run and seed), or None.

    None if there is no checkpoint, or -- after one warning line naming the file and why --
    if it is damaged, of another seed or config, not a checkpoint (a pickle, say), or (given the run's
    ``spec`` and episode cap ``max_steps``) larger than the run's config allows or holding a value
    the run could not have produced (:func:`validate_seed_state`). The seed then restarts from
    scratch: that costs recomputation, and gives the same CSV as an uninterrupted run.
    ``policy_dim``: the policy's parameter count, where it differs from the ES's (``policy.bias=false``).
    """
    say = warn or _warn
    path = checkpoint_path(run_dir, seed)
    max_bytes = DEFAULT_MAX_BYTES if spec is None else checkpoint_byte_limit(spec, _dim_of(fresh))
    st = load_or_warn(path, fresh, identity=identity, seed=seed, warn=warn, max_bytes=max_bytes)
    if st is not None and (st.seed != seed or st.generation != len(st.rows)):
        say(f"{path}: checkpoint ignored: inconsistent state; seed {seed} restarts from scratch")
        return None
    if st is not None and spec is not None:
        try:
            validate_seed_state(st, spec, _dim_of(fresh), max_steps, policy_dim)
        except CheckpointError as err:
            say(f"{path}: checkpoint ignored: {err}; seed {seed} restarts from scratch")
            return None
    return st


def _dim_of(state) -> int:
    return int(np.asarray(state.es.distribution.mean).size)


def _archive_depth(spec) -> int:
    """The generations a seed of ``spec`` archives: its variant's look-back rule (:meth:`imix_cli.core.mixing.Variant.depth`)."""
    return 0 if spec.variant is None else variant_spec(spec.variant).depth(spec.eim_generations)


def checkpoint_byte_limit(spec, dim: int) -> int:
    """The most bytes a checkpoint of run ``spec`` (``dim`` parameters) can need, with a margin of 2.

    The archive (popsize x d samples and a few per-member arrays per archived generation, and each
    generation's distribution: d x d for CMA-ES), the ES's state (d x d matrices for CMA-ES), the
    best member, and the JSON header (one row per generation, under 2 kB each). A file declaring
    more is refused before anything is inflated.
    """
    full = spec.algo == "cmaes"
    dist = 8 * (dim * dim + dim) if full else 16 * dim
    per_generation = 8 * spec.popsize * (dim + 4) + dist
    es = 8 * (6 * dim * dim + 16 * dim) if full else 8 * 8 * dim
    header = 2048 * (max(spec.generations, 1) + 64)
    return 2 * ((_archive_depth(spec) + 1) * per_generation + es + 8 * dim + header) + (1 << 20)


def _fail(message: str):
    raise CheckpointError(message)


def _int(value, low=0, high=None) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= low and (high is None or value <= high)


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def return_bounds(spec, max_steps: int | None, training: bool = True) -> tuple[float, float]:
    """The returns run ``spec`` can produce: a built-in's ``max_steps`` x its step rewards (``training``:
    plus ARS's ``algo.alive_bonus_offset`` per step, which the members' returns include and the
    distribution mean's measurements do not); else unbounded. The bounds a seed CSV's scores are checked against too
    (:func:`imix_cli.core.registry.env_return_bounds`, :func:`imix_cli.running.seed_checks.check_seed_scores`)."""
    from imix_cli.core.registry import env_return_bounds

    offset = float(spec.algo_options.get("alive_bonus_offset", 0.0)) if training else 0.0
    return env_return_bounds(spec.env_name, max_steps or spec.env_max_steps, offset)


def validate_seed_state(st, spec, dim: int, max_steps: int | None = None, policy_dim: int | None = None) -> None:
    """CheckpointError (a few words) unless every field of seed state ``st`` is one run ``spec`` can produce.

    Why: a checksum only proves that the file is what some writer wrote, and anyone can recompute
    it; a checkpoint from elsewhere is data to check like any input. Every value that goes on into
    the CSV, the policy files or the search is checked against the run's config: the rows (one per
    generation, the run's algo/env/mixing/seed/popsize, integer counters in range, episodes and
    steps that add up, finite scores within the env's returns), the counters of the state, the
    best member (the policy's ``policy_dim`` finite numbers, default d; its return the best of the
    rows), the ES (finite, d parameters, its generation count) and the archive (at most the run's
    depth, (popsize, d) finite samples, sources and indices in range).
    """
    bounds = {training: return_bounds(spec, max_steps, training) for training in (True, False)}
    cap = max_steps or spec.env_max_steps

    def score_ok(value, training: bool = True) -> bool:  # training: a member's return; else the distribution mean's
        low, high = bounds[training]
        return _number(value) and (math.isnan(value) or low - 1e-9 <= value <= high + 1e-9)

    rows, popsize = st.rows, spec.popsize
    probes = st.es.probe_count  # episodes besides the members (CMA-ES's TPA points)
    if not isinstance(rows, list) or len(rows) > max(spec.generations, 1) * 4:
        _fail(f"{len(rows) if isinstance(rows, list) else 'no'} rows for a run of {spec.generations} generations")
    required = set(COLUMNS) - {"diverged"}
    evaluations = env_steps = mean_episodes = 0
    best_seen = -math.inf
    for i, row in enumerate(rows):
        if not isinstance(row, dict) or not required <= set(row) <= set(COLUMNS):
            _fail(f"row {i}: not a row of the CSV's columns")
        if (row["algo"], row["env"], row["mixing"]) != (spec.algo, spec.env_name, spec.mixing) or row["seed"] != st.seed or row["generation"] != i:
            _fail(f"row {i}: algo/env/mixing/seed/generation are not this run's")
        counters = ("evaluations", "env_steps", "reused", "reused_im", "reused_eim", "reevaluated", "popsize", "nonfinite", "mean_policy_episodes")
        bad = next((c for c in counters if not _int(row[c])), None)
        if bad or row.get("diverged", 0) not in (0, 1) or row["popsize"] != popsize:
            _fail(f"row {i}: {bad or 'popsize'}={row[bad or 'popsize']!r} is not a count of this run")
        fresh = popsize - row["reused"] + row["reevaluated"]
        if i > 0 and row["evaluations"] - evaluations == fresh + probes:  # the ES's probe points, once the mean has moved
            fresh += probes
        if not (row["reused"] == row["reused_im"] + row["reused_eim"] <= popsize and row["reevaluated"] <= row["reused"] and row["nonfinite"] <= popsize):
            _fail(f"row {i}: reused/reevaluated/nonfinite counts out of range")
        if row["evaluations"] - evaluations != fresh:
            _fail(f"row {i}: evaluations {row['evaluations']} after {evaluations} with {fresh} fresh episodes")
        steps = row["env_steps"] - env_steps
        if steps < fresh or (cap is not None and steps > fresh * cap):
            _fail(f"row {i}: {steps} env steps for {fresh} episodes")
        if row["mean_policy_episodes"] < mean_episodes:
            _fail(f"row {i}: mean_policy_episodes decreases")
        evaluations, env_steps, mean_episodes = row["evaluations"], row["env_steps"], row["mean_policy_episodes"]
        for column in ("mean_score", "best_score", "mean_policy_score"):
            if not score_ok(row[column], training=column != "mean_policy_score") or (
                column != "mean_policy_score" and math.isnan(row[column]) and row["nonfinite"] < popsize
            ):
                _fail(f"row {i}: {column}={row[column]!r} is not a return of {spec.env_name}")
        if row["mean_score"] > row["best_score"] + 1e-9 * max(1.0, abs(row["best_score"])):
            _fail(f"row {i}: mean_score above best_score")
        if not (_number(row["sigma_mean"]) and math.isfinite(row["sigma_mean"]) and row["sigma_mean"] >= 0):
            _fail(f"row {i}: sigma_mean={row['sigma_mean']!r}")
        if not (_number(row["wall_time"]) and math.isfinite(row["wall_time"]) and row["wall_time"] >= 0):
            _fail(f"row {i}: wall_time={row['wall_time']!r}")
        if not math.isnan(row["best_score"]):
            best_seen = max(best_seen, row["best_score"])
    counters = (st.evaluations, st.env_steps, st.mean_policy_episodes)
    if not all(_int(c) for c in counters) or counters != (evaluations, env_steps, mean_episodes):
        _fail("its counters do not match its rows")
    if not (_number(st.elapsed) and math.isfinite(st.elapsed) and st.elapsed >= 0):
        _fail(f"elapsed={st.elapsed!r}")
    # the best-ever member: d finite numbers, its return the best of the rows
    if st.best_params is None:
        if st.best_return != -math.inf or best_seen != -math.inf:
            _fail("best member missing")
    else:
        params, size = st.best_params, dim if policy_dim is None else policy_dim  # the best member as a policy (lockstep.policy_params)
        if not isinstance(params, np.ndarray) or params.dtype != np.float64 or params.shape != (size,) or not np.all(np.isfinite(params)):
            _fail(f"best_params is not {size} finite float64 numbers")
        if not (_number(st.best_return) and math.isfinite(st.best_return) and st.best_return == best_seen):
            _fail(f"best_return={st.best_return!r} is not the best score of its rows ({best_seen})")
    _validate_es(st, spec, dim)
    _validate_archive(st, spec, dim, score_ok)
    if (st.obs_norm is None) == bool(spec.obs_norm):
        _fail("observation normaliser does not match policy.obs_norm")
    if st.obs_norm is not None and st.obs_norm.var_floor != spec.obs_var_floor:
        _fail(f"observation normaliser's variance floor {st.obs_norm.var_floor!r} is not policy.obs_var_floor={spec.obs_var_floor!r}")
    if st.obs_norm is not None and st.obs_norm.freeze != spec.obs_norm_freeze:
        _fail(f"observation normaliser's freeze={st.obs_norm.freeze!r} is not policy.obs_norm_freeze={spec.obs_norm_freeze!r}")


def _validate_es(st, spec, dim: int) -> None:
    from imix_cli.core.divergence import nonfinite_parameters

    es = st.es
    if _dim_of(st) != dim:
        _fail(f"the search distribution has {_dim_of(st)} parameters, the policy {dim}")
    reason = nonfinite_parameters(es)
    if reason or es.diverged is not None:
        _fail(f"the ES's state is not finite ({reason or es.diverged})")
    state = es.state_dict()
    if not _int(state.get("generation")) or state["generation"] != st.generation:
        _fail(f"the ES counts {state.get('generation')!r} generations, its rows {st.generation}")
    for name, value in state.items():
        if isinstance(value, np.ndarray) and value.dtype.kind not in "biuf":
            _fail(f"ES state {name}: dtype {value.dtype}")
        if isinstance(value, np.ndarray) and value.dtype.kind in "iu" and value.size and value.min() < 0:
            _fail(f"ES state {name}: a negative count")
        if isinstance(value, int) and not isinstance(value, bool) and value < 0:
            _fail(f"ES state {name}={value}")


def _validate_archive(st, spec, dim: int, score_ok) -> None:
    # the rows of each archived generation, by the ES's generation scheme (ARS: the N anchors of its pairs only)
    archive, popsize, depth = st.archive, scheme_of(st.es).archived_rows(st.es), _archive_depth(spec)
    gens, returns, ages = archive.generations, archive.returns, archive.ages
    if not (isinstance(gens, list) and isinstance(returns, list) and isinstance(ages, list)):
        _fail("archive is not three lists")
    if not len(gens) == len(returns) == len(ages) <= min(depth, st.generation):
        _fail(f"archive of {len(gens)}/{len(returns)}/{len(ages)} generations, the run keeps {depth}")
    weighted = spec.variant is not None and variant_spec(spec.variant).weights
    for k, (g, ret, age) in enumerate(zip(gens, returns, ages, strict=True)):
        # eim_variant=weighted archives each generation's fresh members only: 2 to popsize rows
        rows = g.samples.shape[0] if weighted and getattr(g.samples, "ndim", 0) == 2 and 2 <= g.samples.shape[0] <= popsize else popsize
        for name, value, shape, kind in (
            ("samples", g.samples, (rows, dim), "f"), ("source", g.source, (rows,), "i"), ("index", g.index, (rows,), "i"),
            ("returns", ret, (rows,), "f"), ("ages", age, (rows,), "i"),
        ):  # fmt: skip
            if not isinstance(value, np.ndarray) or value.shape != shape or value.dtype.kind != kind:
                _fail(f"archive generation {k}: {name} is not {shape} of kind {kind}")
        if not np.all(np.isfinite(g.samples)):
            _fail(f"archive generation {k}: non-finite samples")
        if g.source.min() < 0 or g.source.max() > depth or g.index.min() < -1 or g.index.max() >= popsize or np.any((g.source == 0) != (g.index == -1)):
            _fail(f"archive generation {k}: sources or indices out of range")
        if age.min() < 0 or age.max() > st.generation:
            _fail(f"archive generation {k}: ages out of range")
        finite = ret[np.isfinite(ret)]
        if finite.size and not (score_ok(float(finite.min())) and score_ok(float(finite.max()))):
            _fail(f"archive generation {k}: returns outside {spec.env_name}'s")
        base = g.dist
        if type(g.dist) is AffinePushforward:  # policy.obs_norm_freeze=false: re-expressed under newer statistics
            if not (spec.obs_norm and not spec.obs_norm_freeze) or type(g.dist.transform) is not NormalizerChange or g.dist.transform.dim != dim:
                _fail(f"archive generation {k}: a re-expressed distribution where the run re-expresses none")
            base = g.dist.base
        mean = np.asarray(getattr(g.dist, "mean", None))
        if mean.shape != (dim,) or not np.all(np.isfinite(mean)) or type(base) is not type(st.es.distribution):
            _fail(f"archive generation {k}: its distribution is not one of {dim} finite parameters")
        log_u = getattr(g, "log_u", None)
        if log_u is not None and (not isinstance(log_u, np.ndarray) or log_u.shape != (rows,) or np.any(log_u > 0)):
            _fail(f"archive generation {k}: log_u out of range")
        weights = getattr(g, "mean_weights", None)
        if weights is not None and (not isinstance(weights, np.ndarray) or weights.shape != (rows,) or not np.all(np.isfinite(weights))):
            _fail(f"archive generation {k}: mean_weights are not {rows} finite numbers")
    pairs = getattr(archive, "pairs", None)
    if not isinstance(pairs, np.ndarray) or pairs.shape != (5,) or not np.all(np.isfinite(pairs)) or pairs[0] < 0 or pairs[3] < 0:
        _fail("archive pairs are not 5 finite sums (count and sum of squares >= 0)")


def can_checkpoint(es) -> bool:
    """Whether ``es`` has a state dict; if not, say once that its seeds will not be checkpointed."""
    try:
        es.state_dict()
    except NotImplementedError:
        _warn(f"algo={es.name} cannot be checkpointed yet: a killed run restarts its unfinished seeds")
        return False
    return True
