"""The generation loop compiled: mixing, episodes and ES update of one seed, many generations per call.

Why. On the main job (SNES + EIM, CartPole) the Python loop -- :func:`imix_cli.running.loop.lockstep.advance_lockstep`
-> :mod:`imix_cli.core.mixing.generation` -> mixing, evaluator, ES -- spends ~0.8 ms per seed-generation, while
the numbers themselves (a mixing step, two or three episodes, one update over 50 x 130 numbers) need
about a tenth of that: the rest is some sixty small numpy calls and Python dispatch per generation
(``imix bench breakdown``). Here one compiled call runs a chunk of generations of one seed: mix,
roll out the fresh members, rank, update, archive, and measure the distribution mean when due.

What it computes: *the Python path's numbers, bit for bit* -- the CSV rows, the checkpoints, the
policies. The same random numbers in the same order (numba draws from the seed's own numpy
Generators with NumPy's algorithms and advances them in place) and the same code: the ES's update
is the ES's own compiled step (:class:`imix_cli.core.algorithms.base.CompiledStep`, which its Python
``tell`` runs too), its utilities :meth:`~imix_cli.core.algorithms.base.EvolutionStrategy.compiled_utilities`,
its mean weights (what the archive keeps of each member's part in the move: the step's ``mean_weights``,
e.g. CEM's elite weights, else the utilities), the mixing step :func:`imix_cli.core.mixing.kernels.mix_step`, the episodes those of
:mod:`imix_cli.core.envs.kernels`; numpy's own summation order where the Python path calls
``np.sum``/``np.mean`` (:func:`imix_cli.core.numerics.linalg_kernels.numpy_sum`). This module holds only the loop:
the order of those calls, the archive, and the numbers of the CSV row.
The Python path stays the reference: ``IMIX_COMPILED_LOOP=0`` takes it, and
``tests/test_compiled_loop.py`` runs both and compares CSVs, checkpoints and policy files.

Where it applies (:func:`applies`): any ES with a compiled step over a float64 diagonal Gaussian
(OpenES, SNES and CEM) and compiled utilities (centred ranks, the estool weight decay), no
mixing or the ``paper``/``sun2009``/``exact`` rules with no re-evaluation options, no observation
normalisation, a built-in environment (CartPole, ContinuousCartPole, its Hard variant, Acrobot) evaluated
in the process. Of the paper's grid (OpenES, SNES, CEM, CMA-ES x CartPole, Acrobot x EIM or not), all
but CMA-ES (a full covariance: no compiled step). Anything else takes the Python path, unchanged. The loop calls the evaluator's own episode
kernel, chosen by a number (:func:`_env_code`): Acrobot's float32 reset -- its first observation is numpy's
float32 ``cos``/``sin`` -- runs inside it (:func:`imix_cli.core.envs.kernels.acrobot_seeded_episodes`, which
:class:`imix_cli.core.evaluation.AcrobotEvaluator` runs too).

When a chunk meets what the Python path treats specially -- a non-finite return, or an update that
leaves the distribution non-finite (divergence) -- the chunk is dropped (the random generators are
put back) and the seed continues on the Python path, which records it exactly as always.

Compilation: one entry point per (update, utilities, mean weights) triple, made from :func:`_make_chunk`'s
code with the three functions as its globals (numba resolves them when it compiles), cached on disk like every
imix kernel (stamped with every compiled source of the package: :mod:`imix_cli.core.numerics.numba_cache`). numba
keys a cached function by its closure's contents: the entry's closure holds a digest of the three
functions it runs, so each ES gets its own cached entry, and its own index file (the entry is named after the
digest: :func:`entry` says why).
"""

from __future__ import annotations

import hashlib
import inspect
import math
import os
import types
from pathlib import Path

import numpy as np
from numba import njit

from imix_cli.core import numerics as xp
from imix_cli.core.algorithms.base import EvolutionStrategy, copy_record, hash_multipliers
from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.envs import kernels as ek
from imix_cli.core.mixing import COMPILED_MAX_ELEMENTS, Generation, variant_spec
from imix_cli.core.mixing import kernels as mk
from imix_cli.core.numerics import linalg_kernels as lk
from imix_cli.running.loop.lockstep import generation_row

__all__ = ["applies", "applies_to_run", "advance", "entry", "entry_for", "ENV_VARIABLE"]

#: ``IMIX_COMPILED_LOOP=0``: every run takes the Python path (the reference).
ENV_VARIABLE = "IMIX_COMPILED_LOOP"

_SEED_HIGH = np.iinfo(np.int64).max  # episode seeds: integers(0, int64 max), as lockstep draws them
# The ES's compiled update, utilities and mean weights: each entry point gets its own in its globals (:func:`entry`).
_UPDATE = _UTILITIES = _MEAN_WEIGHTS = None


def _functions_digest(*functions) -> int:
    """A 63-bit digest of ``functions`` (their names and their files' contents): the entry's closure holds it
    (module docstring). imix's own sources are in every imix kernel's cache stamp already
    (:mod:`imix_cli.core.numerics.numba_cache`); the files here cover an ES defined outside the package."""
    h = hashlib.sha256()
    for f in functions:
        py_func = getattr(f, "py_func", f)
        h.update(f"{py_func.__module__}.{py_func.__qualname__}".encode())
        h.update(Path(inspect.getfile(py_func)).read_bytes())
    return int.from_bytes(h.digest()[:8], "little") >> 1


@njit
def utilities_are_mean_weights(utilities, constants):
    """The mean weights of an ES whose compiled step gives none (:class:`~imix_cli.core.algorithms.base.CompiledStep`):
    its utilities, as :meth:`~imix_cli.core.algorithms.base.EvolutionStrategy._mean_weights` has them."""
    return utilities


@njit
def _draw_seeds(rng, n):
    """``rng.integers(0, int64 max, size=n)`` as uint64 (the episode kernels' seed type)."""
    return rng.integers(0, 9223372036854775807, size=n).astype(np.uint64)


#: The episode kernel a run's evaluator runs (:func:`_env_code`), passed to the chunk as a number.
_CARTPOLE, _ACROBOT = 0, 1


@njit
def _episodes(env, params, seeds, sizes, continuous, sparse, max_steps, returns, steps, trace):
    """One episode per member by the evaluator's own kernel: ``env`` is :data:`_CARTPOLE` (``continuous``,
    ``sparse``: its variants) or :data:`_ACROBOT` (the float32 reset the evaluator computes, in the kernel)."""
    if env == _ACROBOT:
        ek.acrobot_seeded_episodes(params, seeds, sizes, max_steps, returns, steps, trace)
    else:
        ek.cartpole_episodes(params, seeds, sizes, continuous, sparse, max_steps, returns, steps, trace)


def _make_chunk(digest: int):
    def _run_chunk(generations, rule, es, archive, rngs, episodes, measure, seed, out):
        """Run ``generations`` generations of one seed (module docstring); ``_UPDATE``, ``_UTILITIES`` and
        ``_MEAN_WEIGHTS`` are the ES's compiled step, utilities and mean weights (:func:`entry`). The arguments are tuples (numba types each
        field), built by :func:`advance`, which names every field:

        - ``rule``: the mixing rule and the ES's utilities' settings;
        - ``es``: the ES's generation count, a copy of its state record (``state.mean``, ``state.std``: the diagonal
          Gaussian searched) and its step's constants (:class:`~imix_cli.core.algorithms.base.CompiledStep`);
        - ``archive``: the archived generations, newest first, as arrays of ``slots`` rows;
        - ``rngs``: the seed's generators (members, episodes, the mean's episodes);
        - ``episodes``: the episode kernel (:func:`_env_code`) and its settings; ``measure``: when and how the mean is evaluated;
        - ``seed``: the best member so far and the last utilities; ``out``: the rows' numbers, one row per generation.

        Every state array is updated in place; returns the number of generations done -- fewer when a generation
        met what only the Python path handles (its state is then unusable: the caller restores a snapshot)."""
        if digest == 0:  # never: the digest is in the closure so that numba keys the cache on it
            return -1
        kernel, depth, alpha, log_keep, min_fresh, weight_decay, mult = rule
        es_generation, state, constants = es
        a_n, a_x, a_mean, a_std, a_lognorm, a_h, a_hset, a_ret, a_age, a_src, a_idx, a_mw, a_trials = archive
        sample_rng, episode_rng, mean_rng = rngs
        env, sizes, continuous, sparse, max_steps = episodes
        eval_every, eval_episodes, generation0 = measure
        best, best_return, last_u = seed
        out_fitness, out_reused, out_evaluated, out_steps, out_sigma_mean, out_theta = out
        popsize, d = a_x.shape[1], a_x.shape[2]
        trace = np.empty((0, 0, 0))
        mu, std = state.mean, state.std
        for g in range(generations):
            # ---- plan: mix (or draw) the generation from the distribution N(mu, std^2)
            log_norm = mk.diagonal_log_norm(std)
            x, source, index, trials = mk.mix_step(
                kernel, sample_rng, (mu, std, log_norm), (a_mean, a_std, a_lognorm, a_x, a_h), a_hset, min(a_n[0], depth),
                (popsize, log_keep, alpha, min_fresh),
            )  # fmt: skip
            age = np.zeros(popsize, dtype=np.int64)
            fitness = np.empty(popsize)
            n_eval = 0
            for i in range(popsize):
                s = source[i]
                if s == 0:
                    n_eval += 1
                else:
                    age[i] = a_age[s - 1, index[i]] + 1
                    fitness[i] = a_ret[s - 1, index[i]]
            # ---- evaluate the fresh members, in population order
            params = np.empty((n_eval, d))
            rows = np.empty(n_eval, dtype=np.int64)
            e = 0
            for i in range(popsize):
                if source[i] == 0:
                    mk.put_row(params, e, x[i])
                    rows[e] = i
                    e += 1
            seeds = _draw_seeds(episode_rng, n_eval)
            returns = np.empty(n_eval)
            steps = np.empty(n_eval, dtype=np.int64)
            if n_eval:
                _episodes(env, params, seeds, sizes, continuous, sparse, max_steps, returns, steps, trace)
            total_steps = 0
            for e in range(n_eval):
                fitness[rows[e]] = returns[e]
                total_steps += steps[e]
            for i in range(popsize):
                if not math.isfinite(fitness[i]):
                    return g
            # ---- tell: the ES's own utilities and update
            u = _UTILITIES(x, fitness, es_generation[0], weight_decay, mult)
            out_sigma_mean[g] = lk.numpy_sum(std) / d
            mu_drawn, std_drawn = mu.copy(), std.copy()  # the distribution the generation was drawn from
            _UPDATE(x, u, state, constants)
            mw = _MEAN_WEIGHTS(u, constants)  # after the update, as tell takes them (constants are never written)
            for j in range(d):  # a distribution no longer finite: the Python path records the divergence
                if not (math.isfinite(mu[j]) and math.isfinite(std[j]) and std[j] > 0.0):
                    return g
            es_generation[0] += 1
            last_u[:] = mw
            # ---- archive (newest first, at most depth generations)
            if depth > 0:
                top = min(a_n[0], depth - 1)
                for k in range(top, 0, -1):
                    a_x[k] = a_x[k - 1]
                    a_mean[k] = a_mean[k - 1]
                    a_std[k] = a_std[k - 1]
                    a_lognorm[k] = a_lognorm[k - 1]
                    a_h[k] = a_h[k - 1]
                    a_hset[k] = a_hset[k - 1]
                    a_ret[k] = a_ret[k - 1]
                    a_age[k] = a_age[k - 1]
                    a_src[k] = a_src[k - 1]
                    a_idx[k] = a_idx[k - 1]
                    a_mw[k] = a_mw[k - 1]
                    a_trials[k] = a_trials[k - 1]
                a_x[0] = x
                a_mean[0] = mu_drawn
                a_std[0] = std_drawn
                a_lognorm[0] = log_norm
                a_hset[0] = False
                a_ret[0] = fitness
                a_age[0] = age
                a_src[0] = source
                a_idx[0] = index
                a_mw[0] = mw
                a_trials[0] = trials
                a_n[0] = min(a_n[0] + 1, depth)
            # ---- the row's numbers
            reused = 0
            from_previous = 0
            for i in range(popsize):
                if source[i] > 0:
                    reused += 1
                    if source[i] == 1:
                        from_previous += 1
            out_fitness[g] = fitness
            out_reused[g, 0] = reused
            out_reused[g, 1] = from_previous
            out_reused[g, 2] = reused - from_previous
            out_evaluated[g] = n_eval
            out_steps[g] = total_steps
            b = 0
            for i in range(1, popsize):
                if fitness[i] > fitness[b]:
                    b = i
            if fitness[b] > best_return[0]:
                best_return[0] = fitness[b]
                best[:] = x[b]
            # ---- the distribution mean on fresh episodes, when due
            out_theta[g] = np.nan
            done = generation0 + g + 1
            if eval_every > 0 and done % eval_every == 0:
                mseeds = _draw_seeds(mean_rng, eval_episodes)
                mparams = np.empty((eval_episodes, d))
                for r in range(eval_episodes):
                    mk.put_row(mparams, r, mu)
                mreturns = np.empty(eval_episodes)
                msteps = np.empty(eval_episodes, dtype=np.int64)
                _episodes(env, mparams, mseeds, sizes, continuous, sparse, max_steps, mreturns, msteps, trace)
                out_theta[g] = lk.numpy_sum(mreturns) / eval_episodes
        return generations

    return _run_chunk


# ------------------------------------------------------------------------------ the Python side
_ENTRIES: dict = {}


def entry(update, utilities, mean_weights=None):
    """The compiled entry point running ES update ``update`` with utilities ``utilities`` and mean weights ``mean_weights``
    (None: :func:`utilities_are_mean_weights`), built on first use: its cache key needs the dependency digest (module docstring)."""
    mean_weights = mean_weights or utilities_are_mean_weights
    key = (update, utilities, mean_weights)
    if key not in _ENTRIES:
        digest = _functions_digest(update, utilities, mean_weights)
        inner = _make_chunk(digest)
        own = {"_UPDATE": update, "_UTILITIES": utilities, "_MEAN_WEIGHTS": mean_weights}
        chunk = types.FunctionType(inner.__code__, {**globals(), **own}, inner.__name__, None, inner.__closure__)
        # Named after the digest: each entry gets an index file of its own in numba's cache. An index holds the types of
        # its entries' arguments, the ES's state record among them, and numba imports their classes when it reads the
        # index: a shared index would make every run import the record class of any ES ever run (one defined in a
        # script or a test cannot be imported by another process).
        chunk.__qualname__ = f"_run_chunk_{digest:016x}"
        chunk.__module__, chunk.__doc__ = inner.__module__, inner.__doc__
        _ENTRIES[key] = njit(cache=True)(chunk)
    return _ENTRIES[key]


def entry_for(es):
    """The compiled entry point that runs ``es`` (one with a compiled step and compiled utilities)."""
    step = es.compiled_step()
    return entry(step.update, es.compiled_utilities(), step.mean_weights)


def enabled() -> bool:
    """Whether runs may take the compiled loop (``IMIX_COMPILED_LOOP`` unset or not ``0``)."""
    return os.environ.get(ENV_VARIABLE, "1").strip() != "0"


def _kernel(variant: str | None) -> int | None:
    """The number of mixing ``variant``'s compiled step (:func:`imix_cli.core.mixing.kernels.mix_step`): 0 without
    mixing, the variant's ``kernel`` (:class:`imix_cli.core.mixing.Variant`), None if it has none (the loop cannot take it)."""
    if variant is None:
        return 0
    return variant_spec(variant).kernel or None


def _env_code(evaluator) -> int | None:
    """The episode kernel of ``evaluator`` (:func:`_episodes`): a built-in env's evaluator run in this process only
    (a pool's or Ray's evaluator is another class: its episodes run elsewhere); None, the loop cannot run it."""
    from imix_cli.core.evaluation import AcrobotEvaluator, CartPoleEvaluator, ContinuousCartPoleEvaluator

    return {CartPoleEvaluator: _CARTPOLE, ContinuousCartPoleEvaluator: _CARTPOLE, AcrobotEvaluator: _ACROBOT}.get(type(evaluator))


def applies_to_run(settings, evaluator, es=None) -> bool:
    """Whether the seeds of a run (its :class:`imix_cli.running.loop.lockstep.LoopSettings`) evaluated by ``evaluator``
    can take the compiled loop (module docstring); ``es``: one of its ES, if made (else judged by ``settings.algo``)."""
    if not enabled() or _env_code(evaluator) is None:
        return False
    if es is None:
        from imix_cli.core.algorithms import make_es

        es = make_es(settings.algo, settings.dim, **settings.es_options)
    step = es.compiled_step()
    if step is None or es.compiled_utilities() is None:
        return False
    if step.mean_weights is None and type(es)._mean_weights is not EvolutionStrategy._mean_weights:
        return False  # mean weights of its own in Python only: the loop would archive the utilities instead
    mixing = settings.mixing
    if _kernel(mixing.variant) is None or mixing.reeval_age is not None or mixing.reeval_prob > 0.0 or mixing.reeval_count > 0:
        return False
    # policy.bias=false: the ES's points are not the evaluator's parameter vectors (lockstep.policy_params)
    return settings.obs_norm_warmup is None and settings.policy_bias


def applies(settings, evaluator, st) -> bool:
    """Whether seed ``st`` of a run can take the compiled loop now (module docstring)."""
    es = getattr(st.es, "es", st.es)
    if not applies_to_run(settings, evaluator, es) or st.obs_norm is not None or getattr(st.es, "diverged", None) is not None:
        return False
    depth = settings.mixing.depth
    if type(es.distribution) is not DiagonalGaussian or es.distribution.dtype != np.float64:
        return False
    if es.popsize < 2 or es.popsize * es.dim * max(depth, 1) > COMPILED_MAX_ELEMENTS:
        return False
    archive = st.archive
    if len(archive.generations) > depth or np.any(archive.pairs != 0.0):
        return False
    for g in archive.generations:
        if type(g.dist) is not DiagonalGaussian or g.samples.shape != (es.popsize, es.dim) or g.samples.dtype != np.float64 or g.mean_weights is None:
            return False
    return True


def advance(st, settings, evaluator, generations: int) -> bool:
    """Run ``generations`` generations of seed ``st`` (a :class:`imix_cli.running.loop.lockstep.SeedState` for which
    :func:`applies`) in one compiled call, appending their rows as the Python path does. Returns
    False, having changed nothing, when a generation needs the Python path (module docstring)."""
    mixing = settings.mixing
    es = getattr(st.es, "es", st.es)
    step = es.compiled_step()
    d, popsize, depth = es.dim, es.popsize, mixing.depth
    slots = max(depth, 1)
    archive = st.archive
    n_arch = len(archive.generations)

    a_x = np.zeros((slots, popsize, d))
    a_mean, a_std = np.zeros((slots, d)), np.ones((slots, d))
    a_lognorm = np.zeros(slots)
    a_h, a_hset = np.zeros((slots, popsize)), np.zeros(slots, dtype=np.bool_)
    a_ret, a_mw = np.zeros((slots, popsize)), np.zeros((slots, popsize))
    a_age, a_src, a_idx = (np.zeros((slots, popsize), dtype=np.int64) for _ in range(3))
    a_trials = np.zeros(slots, dtype=np.int64)
    for k, g in enumerate(archive.generations):
        a_x[k], a_mean[k], a_std[k], a_lognorm[k] = g.samples, g.dist.mean, g.dist.std, g.dist.log_norm
        if g.log_u is not None:
            a_h[k], a_hset[k] = g.log_u, True
        a_ret[k], a_mw[k], a_age[k], a_src[k], a_idx[k], a_trials[k] = archive.returns[k], g.mean_weights, archive.ages[k], g.source, g.index, g.trials

    es_generation = np.array([es.generation], dtype=np.int64)
    best = np.zeros(d) if st.best_params is None else np.array(st.best_params, dtype=np.float64)
    best_return = np.array([st.best_return], dtype=np.float64)
    last_u = np.zeros(popsize)
    a_n = np.array([n_arch], dtype=np.int64)

    out_fitness = np.empty((generations, popsize))  # every member's return, stored or new
    out_reused = np.empty((generations, 3), dtype=np.int64)
    out_evaluated = np.empty(generations, dtype=np.int64)
    out_steps = np.empty(generations, dtype=np.int64)
    out_sigma_mean = np.empty(generations)
    out_theta = np.empty(generations)

    rngs = (st.sample_rng, st.episode_rng, st.mean_eval_rng)
    snapshot = [r.bit_generator.state for r in rngs]
    with np.errstate(divide="ignore"):
        log_keep = xp.log1p(-mixing.alpha)
    rule = (_kernel(mixing.variant), depth, float(mixing.alpha), log_keep, int(mixing.min_fresh), float(es.weight_decay), hash_multipliers(d))
    archive_arrays = (a_n, a_x, a_mean, a_std, a_lognorm, a_h, a_hset, a_ret, a_age, a_src, a_idx, a_mw, a_trials)
    episodes = (_env_code(evaluator), evaluator.layer_sizes(), type(evaluator).__name__ == "ContinuousCartPoleEvaluator",
                bool(getattr(evaluator, "hard", False)), int(evaluator.max_steps))  # fmt: skip
    measure = (int(settings.eval_mean_every), int(settings.eval_mean_episodes), int(st.generation))
    out = (out_fitness, out_reused, out_evaluated, out_steps, out_sigma_mean, out_theta)
    state = copy_record(es.state)  # the chunk moves this copy; the ES takes it only if the chunk ran to its end
    done = entry_for(es)(
        generations, rule, (es_generation, state, step.constants), archive_arrays,
        (st.sample_rng, st.episode_rng, st.mean_eval_rng), episodes, measure, (best, best_return, last_u), out,
    )  # fmt: skip
    if done < generations:  # put the generators back: the Python path takes this chunk
        for r, rng_state in zip(rngs, snapshot):
            r.bit_generator.state = rng_state
        return False

    # ---- write the state back into the ES, the archive and the seed
    es.set_state(state)
    es.generation = int(es_generation[0])
    es.mean_weights = last_u
    if depth:
        archive.generations = [
            Generation(a_x[k].copy(), a_src[k].copy(), a_idx[k].copy(), DiagonalGaussian(a_mean[k], a_std[k]), int(a_trials[k]),
                       a_h[k].copy() if a_hset[k] else None, a_mw[k].copy())
            for k in range(int(a_n[0]))
        ]  # fmt: skip
        archive.returns = [a_ret[k].copy() for k in range(int(a_n[0]))]
        archive.ages = [a_age[k].copy() for k in range(int(a_n[0]))]
    if best_return[0] > st.best_return:
        st.best_params, st.best_return = best, float(best_return[0])
    every, episodes = settings.eval_mean_every, int(settings.eval_mean_episodes)
    numbers = (out_reused, out_evaluated, out_steps, out_sigma_mean, out_theta)
    for fitness, (counts, n, steps, sigma_mean, theta) in zip(out_fitness, zip(*(a.tolist() for a in numbers))):
        st.evaluations += n
        st.env_steps += steps
        if every and (st.generation + 1) % every == 0:
            st.mean_policy_episodes += episodes
        row = generation_row(settings, st, fitness, (*counts, 0), sigma_mean)
        row["mean_policy_score"], row["mean_policy_episodes"] = theta, st.mean_policy_episodes  # as measure_distribution_means
        st.rows.append(row)
    return True
