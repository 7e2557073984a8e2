"""The generation loop compiled: seeds' generations in chunks, each one call of the compiled generation
(:mod:`imix_cli.core.mixing.compiled_generation`) for up to ``SEEDS_PER_CALL`` seeds at the same generation (their fresh
members' episodes run together), whose arrays this module packs from the seeds' states and unpacks back, appending
the CSV rows.

The Python path (:func:`imix_cli.running.loop.lockstep.advance_lockstep`) stays the reference: ``IMIX_COMPILED_LOOP=0``
takes it, and ``tests/test_compiled_loop.py`` runs both and compares CSVs, checkpoints and policy files: the same numbers,
bit for bit.

Where it applies (:func:`applies`): any ES with a compiled step (:class:`~imix_cli.core.algorithms.base.CompiledStep`)
and compiled utilities (centred ranks with the estool weight decay, or ARS's raw fitness) -- over a float64 diagonal
Gaussian (OpenES, SNES, CEM, and ARS, whose mirrored pairs' anchors are mixed), with no mixing or the
``paper``/``sun2009``/``exact`` rules, or over a full Gaussian (CMA-ES, its own chunk), with no mixing or ``exact``
-- no re-evaluation options, no observation normalisation, the ES's points the policy's parameters (``policy.bias``),
a built-in environment (CartPole, ContinuousCartPole, its Hard variant, Acrobot) evaluated in the process: the whole
paper grid (OpenES, SNES, CEM, CMA-ES x CartPole, Acrobot x EIM or not). Anything else (a generation scheme of
its own, a weighted variant) takes the Python path, unchanged.

When a chunk meets what the Python path treats specially -- a non-finite return, or an update that
leaves the distribution non-finite (divergence) -- the chunk is dropped (the random generators are
put back, the ES keeps its own state record: the chunk moved a copy) and the seed continues on the Python path,
which records it exactly as always.
"""

from __future__ import annotations

import functools
import os

import numpy as np

from imix_cli.core import numerics as xp
from imix_cli.core.algorithms.base import EvolutionStrategy, copy_record, hash_multipliers
from imix_cli.core.distributions import DiagonalGaussian, FullGaussian
from imix_cli.core.mixing import COMPILED_MAX_ELEMENTS, variant_spec
from imix_cli.core.mixing.compiled_generation import (
    SEEDS_PER_CALL,
    entry_for,
    env_code,
    pack_archive,
    pack_full_archive,
    unpack_archive,
    unpack_full_archive,
)
from imix_cli.core.mixing.generation import INDEPENDENT, scheme_of
from imix_cli.core.mixing.mirrored import MirroredPairs
from imix_cli.running.loop.lockstep import scored_row

__all__ = ["applies", "applies_to_run", "advance", "advance_seeds", "ENV_VARIABLE"]

#: ``IMIX_COMPILED_LOOP=0``: every run takes the Python path (the reference).
ENV_VARIABLE = "IMIX_COMPILED_LOOP"


def enabled() -> bool:
    """Whether runs may take the compiled loop (``IMIX_COMPILED_LOOP`` unset or not ``0``)."""
    return os.environ.get(ENV_VARIABLE, "1").strip() != "0"


#: The number of the ``"exact"`` rule's compiled step (:data:`imix_cli.core.mixing.kernels.KERNELS`): between full
#: Gaussians the only one.
EXACT_KERNEL = 3


def _kernel(variant: str | None) -> int | None:
    """The number of mixing ``variant``'s compiled step (:func:`imix_cli.core.mixing.kernels.mix_step`): 0 without
    mixing, the variant's ``kernel`` (:class:`imix_cli.core.mixing.Variant`), None if it has none (the loop cannot take it)."""
    if variant is None:
        return 0
    return variant_spec(variant).kernel or None


def applies_to_run(settings, evaluator, es=None) -> bool:
    """Whether the seeds of a run (its :class:`imix_cli.running.loop.lockstep.LoopSettings`) evaluated by ``evaluator``
    can take the compiled loop (module docstring); ``es``: one of its ES, if made (else judged by ``settings.algo``)."""
    if not enabled() or env_code(evaluator) is None:
        return False
    if es is None:
        from imix_cli.core.algorithms import make_es

        es = make_es(settings.algo, settings.dim, **settings.es_options)
    step = es.compiled_step()
    if step is None or es.compiled_utilities() is None:
        return False
    scheme = scheme_of(es, settings.mixing)
    if scheme is not INDEPENDENT and not (isinstance(scheme, MirroredPairs) and step.full is None):
        return False  # a scheme of its own (a weighted variant's, a user's): the Python path's alone
    if step.full is None and step.mean_weights is None and type(es)._mean_weights is not EvolutionStrategy._mean_weights:
        return False  # mean weights of its own in Python only: the loop would archive the utilities instead
    mixing = settings.mixing
    if _kernel(mixing.variant) is None or mixing.reeval_age is not None or mixing.reeval_prob > 0.0 or mixing.reeval_count > 0:
        return False
    if step.full is not None and _kernel(mixing.variant) not in (0, EXACT_KERNEL):
        return False  # between full Gaussians the compiled mixing step is "exact"'s alone
    # policy.bias=false: the ES's points are not the evaluator's parameter vectors (lockstep.policy_params)
    return settings.obs_norm_warmup is None and settings.policy_bias


def applies(settings, evaluator, st) -> bool:
    """Whether seed ``st`` of a run can take the compiled loop now (module docstring)."""
    es = getattr(st.es, "es", st.es)
    if not applies_to_run(settings, evaluator, es) or st.obs_norm is not None or getattr(st.es, "diverged", None) is not None:
        return False
    depth = settings.mixing.depth
    kind = FullGaussian if es.compiled_step().full is not None else DiagonalGaussian
    if type(es.distribution) is not kind or es.distribution.dtype != np.float64:
        return False
    if es.popsize < 2 or es.popsize * es.dim * max(depth, 1) > COMPILED_MAX_ELEMENTS:
        return False
    if kind is FullGaussian and es.dim * es.dim * (depth + 1) > COMPILED_MAX_ELEMENTS:
        return False
    archive, mirrored = st.archive, _mirrored(es)
    if len(archive.generations) > depth or np.any(archive.pairs != 0.0):
        return False
    rows = scheme_of(es).archived_rows(es)
    for g in archive.generations:
        if type(g.dist) is not kind or g.samples.shape != (rows, es.dim) or g.samples.dtype != np.float64 or (g.mean_weights is None) != mirrored:
            return False
    return True


def _mirrored(es) -> bool:
    """Whether ``es``'s members are mirrored pairs, whose anchors alone are mixed and archived (ARS)."""
    return isinstance(scheme_of(es), MirroredPairs)


def advance(st, settings, evaluator, generations: int) -> bool:
    """:func:`advance_seeds` of seed ``st`` alone."""
    return advance_seeds([st], settings, evaluator, generations)


def advance_seeds(states: list, settings, evaluator, generations: int) -> bool:
    """Run ``generations`` generations of seeds ``states`` (:class:`imix_cli.running.loop.lockstep.SeedState` records of
    one run, for each of which :func:`applies`, at most :data:`~imix_cli.core.mixing.compiled_generation.SEEDS_PER_CALL`)
    in one compiled call, appending their rows as the Python path does. Returns False, having changed nothing, when a
    generation of any of them needs the Python path (module docstring)."""
    mixing = settings.mixing
    es0 = getattr(states[0].es, "es", states[0].es)
    step = es0.compiled_step()
    d, popsize, depth = es0.dim, es0.popsize, mixing.depth
    slots, mirrored, full = max(depth, 1), _mirrored(es0), step.full is not None
    with np.errstate(divide="ignore"):
        log_keep = xp.log1p(-mixing.alpha)
    min_fresh = 0 if mirrored else int(mixing.min_fresh)  # every mirror is fresh: no pair generation is reused whole
    rule = (_kernel(mixing.variant), depth, float(mixing.alpha), log_keep, min_fresh, float(es0.weight_decay), hash_multipliers(d),
            float(es0.reward_offset), mirrored, int(step.full[2]) if full else 0)  # fmt: skip
    pack, unpack = (pack_full_archive, unpack_full_archive) if full else (pack_archive, functools.partial(unpack_archive, mean_weights=not mirrored))
    rows = scheme_of(es0).archived_rows(es0)
    episodes = (env_code(evaluator), evaluator.layer_sizes(), type(evaluator).__name__ == "ContinuousCartPoleEvaluator",
                bool(getattr(evaluator, "hard", False)), int(evaluator.max_steps))  # fmt: skip
    batch, generators, snapshots, chunks = [], [], [], []
    for st in states:
        es = getattr(st.es, "es", st.es)
        archive_arrays = pack(st.archive, slots, rows, d)
        es_generation = np.array([es.generation], dtype=np.int64)
        best = np.zeros(d) if st.best_params is None else np.array(st.best_params, dtype=np.float64)
        best_return = np.array([st.best_return], dtype=np.float64)
        last_u = np.zeros(popsize)
        out = (np.empty((generations, popsize)),  # every member's return, stored or new
               np.empty((generations, 3), dtype=np.int64), np.empty(generations, dtype=np.int64),
               np.empty(generations, dtype=np.int64), np.empty(generations), np.empty(generations))  # fmt: skip
        rngs = (st.sample_rng, st.episode_rng, st.mean_eval_rng)
        snapshots.append([r.bit_generator.state for r in rngs])
        state = copy_record(es.state)  # the chunk moves this copy; the ES takes it only if the chunk ran to its end
        measure = (int(settings.eval_mean_every), int(settings.eval_mean_episodes), int(st.generation))
        batch.append(((es_generation, state, es.compiled_step().constants), archive_arrays, measure, (best, best_return, last_u), out))
        generators.append(rngs)
        chunks.append((es, (archive_arrays, unpack), es_generation, state, best, best_return, None if mirrored else last_u, out))
    padding = SEEDS_PER_CALL - len(batch)  # one entry point whatever the number of seeds
    padded, padded_generators = tuple(batch + [batch[0]] * padding), tuple(generators + [generators[0]] * padding)
    done = entry_for(es0, step)(generations, rule, episodes, padded, padded_generators, len(batch))
    if done < generations:  # put the generators back: the Python path takes this chunk
        for st, snapshot in zip(states, snapshots):
            for r, rng_state in zip((st.sample_rng, st.episode_rng, st.mean_eval_rng), snapshot):
                r.bit_generator.state = rng_state
        return False
    for st, chunk in zip(states, chunks):
        _take_back(st, settings, depth, *chunk)
    return True


def _take_back(st, settings, depth, es, archive, es_generation, state, best, best_return, last_u, out) -> None:
    """Write a finished chunk's state back into seed ``st``'s ES, archive (``(arrays, unpack)``) and seed, and append its rows."""
    out_fitness, out_reused, out_evaluated, out_steps, out_sigma_mean, out_theta = out
    es.set_state(state)
    es.generation = int(es_generation[0])
    if last_u is not None:  # (a mirrored ES's tell keeps no mean weights)
        es.mean_weights = last_u
    if depth:
        archive_arrays, unpack = archive
        unpack(st.archive, archive_arrays)
    if best_return[0] > st.best_return:
        st.best_params, st.best_return = best, float(best_return[0])
    every, episodes = settings.eval_mean_every, int(settings.eval_mean_episodes)
    # Every return of a chunk is finite (else the chunk is handed back): generation_row's mean and best of each row,
    # numpy's mean (pairwise sum, then / popsize) and max of each row of the chunk at once -- the same numbers.
    numbers = (out_fitness.mean(axis=1), out_fitness.max(axis=1), out_reused, out_evaluated, out_steps, out_sigma_mean, out_theta)
    for mean_score, best_score, counts, n, steps, sigma_mean, theta in zip(*(a.tolist() for a in numbers)):
        st.evaluations += n
        st.env_steps += steps
        if every and (st.generation + 1) % every == 0:
            st.mean_policy_episodes += episodes
        row = scored_row(settings, st, (mean_score, best_score), (*counts, 0), sigma_mean)
        row["mean_policy_score"], row["mean_policy_episodes"] = theta, st.mean_policy_episodes  # as measure_distribution_means
        st.rows.append(row)
