"""A generation compiled -- mix, roll out the fresh members, rank, update, archive, measure the mean -- many
generations of several seeds per call: the generation step of :mod:`imix_cli.core.mixing.generation`, in numba.

Why. On the main job (SNES + EIM, CartPole) the Python path -- :mod:`imix_cli.core.mixing.generation` -> mixing,
evaluator, ES -- spends ~0.8 ms per seed-generation, while the numbers themselves (a mixing step, two or three
episodes, one update over 50 x 130 numbers) need about a tenth of that: the rest is some sixty small numpy calls and
Python dispatch per generation (``imix bench breakdown``). The run's loop (:mod:`imix_cli.running.loop.compiled_loop`)
hands the seeds' arrays to :func:`entry_for`'s function and takes them back; this module holds the generation itself,
so that no module outside ``core/`` holds archive, fitness-assembly or mixing logic.

What it computes: *the Python path's numbers, bit for bit* -- the CSV rows, the checkpoints, the policies. The same
random numbers in the same order (numba draws from the seed's own numpy Generators with NumPy's algorithms and
advances them in place) and the same code: the ES's update is the ES's own compiled step
(:class:`imix_cli.core.algorithms.base.CompiledStep`, which its Python ``tell`` runs too) on a copy of its state
record, its utilities :meth:`~imix_cli.core.algorithms.base.EvolutionStrategy.compiled_utilities`, its mean weights
(what the archive keeps of each member's part in the move: the step's ``mean_weights``, e.g. CEM's elite weights, else
the utilities), the mixing step :func:`imix_cli.core.mixing.kernels.mix_step`, the episodes those of
:mod:`imix_cli.core.envs.kernels` (chosen by a number, :func:`env_code`: Acrobot's float32 reset -- its first
observation is numpy's float32 ``cos``/``sin`` -- runs inside :func:`imix_cli.core.envs.kernels.acrobot_seeded_episodes`,
which :class:`imix_cli.core.evaluation.AcrobotEvaluator` runs too); numpy's own summation order where the Python path
calls ``np.sum``/``np.mean`` (:func:`imix_cli.core.numerics.linalg_kernels.numpy_sum`). The archive is the Python
path's (:class:`imix_cli.core.mixing.generation.Archive`) as arrays of ``slots`` rows (:func:`pack_archive`,
:func:`unpack_archive`).

An ES whose members are mirrored pairs (ARS: :data:`imix_cli.core.mixing.mirrored.MIRRORED_PAIRS`) runs in the diagonal
chunk as its Python scheme has it: the N anchors are mixed (no minimal refresh) and archived, the mirrors 2m - anchor are
always fresh, and the ES's training fitness (return + its reward offset x length) is what is told and archived.

When a generation meets what the Python path treats specially -- a non-finite return, or an update that leaves the
distribution non-finite (divergence) -- the call returns early; its state is then unusable and the caller restores its
snapshot.

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
import types
from pathlib import Path

import numpy as np
from numba import njit
from numba.typed import List

from imix_cli.core.distributions import DiagonalGaussian, FullGaussian
from imix_cli.core.envs import kernels as ek
from imix_cli.core.mixing import Generation
from imix_cli.core.mixing import kernels as mk
from imix_cli.core.numerics import elementary as el
from imix_cli.core.numerics import linalg_kernels as lk

__all__ = ["SEEDS_PER_CALL", "entry", "entry_for", "env_code", "pack_archive", "pack_full_archive", "unpack_archive", "unpack_full_archive"]

# The ES's compiled update, utilities and mean weights, and for a full Gaussian its distribution and probes: each entry
# point gets its own in its globals (:func:`entry`).
_UPDATE = _UTILITIES = _MEAN_WEIGHTS = _DISTRIBUTION = _PROBES = None


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


#: The episode kernel a run's evaluator runs (:func:`env_code`), passed to the chunk as a number.
_CARTPOLE, _ACROBOT = 0, 1


@njit
def _episodes(env, params, seeds, sizes, continuous, sparse, max_steps, returns, steps, trace):
    """One episode per member by the evaluator's own kernel: ``env`` is :data:`_CARTPOLE` (``continuous``,
    ``sparse``: its variants) or :data:`_ACROBOT` (the float32 reset the evaluator computes, in the kernel)."""
    if env == _ACROBOT:
        ek.acrobot_seeded_episodes(params, seeds, sizes, max_steps, returns, steps, trace)
    else:
        ek.cartpole_episodes(params, seeds, sizes, continuous, sparse, max_steps, returns, steps, trace)


@njit
def _episodes_of(episodes, params, seeds, returns, steps, trace):
    """:func:`_episodes` with the chunk's ``episodes`` settings tuple."""
    env, sizes, continuous, sparse, max_steps = episodes
    _episodes(env, params, seeds, sizes, continuous, sparse, max_steps, returns, steps, trace)


@njit(inline="always")
def _seed_list(batch, generators, n):
    """The first ``n`` seeds of ``batch`` as a typed List of ``(es, archive, rngs, measure, seed, out)``, each seed's
    generators ``generators[s]`` put in: indexing the tuples with a variable compiles a switch over their entries at
    every use, once here. Inlined into the chunk (numba's ``inline="always"``, at the IR level): compiled as a function
    of its own it got a CPython wrapper too -- code that unboxes ``batch`` from Python objects, never called, and the
    slowest part of the entry's compile (:data:`SEEDS_PER_CALL`).

    Why the generators come apart from the rest: numba types a call's arguments before every call. An argument made
    of tuples, records and arrays only is typed in C from its fingerprint (microseconds); one holding a numpy
    ``Generator`` anywhere is typed field by field in Python -- the main job's 16 seeds' tuples took 9 ms a call, 40
    calls a worker (~0.35 s of its 3 s); apart, the two arguments take 0.5 ms (``/tmp`` script, numba 0.68)."""
    seed_tuples = List()
    for s in range(n):
        es, archive, measure, seed, out = batch[s]
        seed_tuples.append((es, archive, generators[s], measure, seed, out))
    return seed_tuples


@njit
def _call_arrays(n, popsize, d, rows, eval_episodes):
    """A call's work arrays: the seeds' generations ``(samples, sources, indices, ages, fitness, trials)``, ``rows``
    episodes' ``(params, member, episode seed, return, steps)`` and the mean measurements' (:func:`_measure_means`)."""
    generation = (np.empty((n, popsize, d)), np.empty((n, popsize), dtype=np.int64), np.empty((n, popsize), dtype=np.int64),
                  np.empty((n, popsize), dtype=np.int64), np.empty((n, popsize)), np.empty(n, dtype=np.int64))  # fmt: skip
    episode_rows = (np.empty((rows, d)), np.empty(rows, dtype=np.int64), np.empty(rows, dtype=np.uint64), np.empty(rows), np.empty(rows, dtype=np.int64))
    scratch = (np.empty((n * eval_episodes, d)), np.empty(n * eval_episodes, dtype=np.uint64), np.empty(n * eval_episodes),
               np.empty(n * eval_episodes, dtype=np.int64), np.empty((0, 0, 0)))  # fmt: skip
    return generation, episode_rows, scratch


@njit
def _place_members(x, source, index, stored, params, rows, e, ages, fitness):
    """One seed's generation: its fresh members into the episodes' rows from ``e``, in population order, and its reused
    ones' ages and stored returns (``stored`` = the archive's ages and returns); returns the next free row."""
    a_age, a_ret = stored
    for i in range(x.shape[0]):
        ages[i] = 0
        if source[i] == 0:
            mk.put_row(params, e, x[i])
            rows[e] = i
            e += 1
        else:
            ages[i] = a_age[source[i] - 1, index[i]] + 1
            fitness[i] = a_ret[source[i] - 1, index[i]]
    return e


@njit
def _take_returns(fitnesses, rows, returns, steps, offset, fresh_from, members_end):
    """Each seed's fresh members' training fitness (rows ``fresh_from[s]:members_end[s]``) into its fitness: every row's
    return + ``offset`` x its length (the ES's :meth:`~imix_cli.core.algorithms.base.EvolutionStrategy.training_fitness`,
    probes' rows too); False if a member's fitness is not finite (the Python path records it)."""
    n, popsize = fitnesses.shape
    if offset != 0.0:
        for e in range(fresh_from[n]):
            returns[e] = returns[e] + offset * steps[e]
    for s in range(n):
        for e in range(fresh_from[s], members_end[s]):
            fitnesses[s, rows[e]] = returns[e]
        for i in range(popsize):
            if not math.isfinite(fitnesses[s, i]):
                return False
    return True


@njit
def _mirrored_pairs(anchors, source, index, mean):
    """The members ``[anchors; 2 mean - anchors]`` of an ES of mirrored pairs (:mod:`imix_cli.core.mixing.mirrored`), with
    their sources and indices: a mirror is always fresh."""
    rows, d = anchors.shape
    x = np.empty((2 * rows, d))
    members_source = np.zeros(2 * rows, dtype=np.int64)
    members_index = np.full(2 * rows, -1, dtype=np.int64)
    for i in range(rows):
        members_source[i] = source[i]
        members_index[i] = index[i]
        for j in range(d):
            x[i, j] = anchors[i, j]
            x[rows + i, j] = 2.0 * mean[j] - anchors[i, j]
    return x, members_source, members_index


@njit
def _archive_generation(common, depth, x, fitness, ages, source, index, mean_weights, trials):
    """The archive's fields every chunk shares, ``common`` = (count, samples, log-heights, drawn?, returns, ages,
    sources, indices, mean weights, trials): entries one older (at most ``depth``), the generation told newest. The
    distributions' fields are the chunk's own, shifted before."""
    a_n, a_x, a_h, a_hset, a_ret, a_age, a_src, a_idx, a_mw, a_trials = common
    for k in range(min(a_n[0], depth - 1), 0, -1):
        a_x[k] = a_x[k - 1]
        a_h[k] = a_h[k - 1]
        a_hset[k] = a_hset[k - 1]
        a_ret[k] = a_ret[k - 1]
        a_age[k] = a_age[k - 1]
        a_src[k] = a_src[k - 1]
        a_idx[k] = a_idx[k - 1]
        a_mw[k] = a_mw[k - 1]
        a_trials[k] = a_trials[k - 1]
    a_x[0] = x
    a_hset[0] = False
    a_ret[0] = fitness
    a_age[0] = ages
    a_src[0] = source
    a_idx[0] = index
    a_mw[0] = mean_weights
    a_trials[0] = trials
    a_n[0] = min(a_n[0] + 1, depth)


@njit
def _record(g, x, source, fitness, steps, seed, out):
    """Generation ``g``'s row numbers into ``out`` (every return, reuse counts, the episodes run: ``steps`` their
    lengths) and the best member so far into ``seed`` (the first best kept)."""
    best, best_return, last_u = seed
    out_fitness, out_reused, out_evaluated, out_steps, out_sigma_mean, out_theta = out
    popsize = x.shape[0]
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
    out_evaluated[g] = steps.shape[0]
    total_steps = 0
    for e in range(steps.shape[0]):
        total_steps += steps[e]
    out_steps[g] = total_steps
    b = 0
    for i in range(1, popsize):
        if fitness[i] > fitness[b]:
            b = i
    if fitness[b] > best_return[0]:
        best_return[0] = fitness[b]
        best[:] = x[b]
    out_theta[g] = np.nan


@njit
def _measure_means(g, seed_tuples, means, episodes, scratch):
    """The distribution means ``means[s]`` on fresh episodes, for every seed due at generation ``g`` (every
    ``eval_every``), all in one call of the episode kernel; each seed's episode seeds from its own generator."""
    mparams, mseeds, mreturns, msteps, trace = scratch
    eval_every, eval_episodes = seed_tuples[0][3][0], seed_tuples[0][3][1]
    if eval_every <= 0:
        return
    due = 0
    for s in range(len(seed_tuples)):
        measure, rngs = seed_tuples[s][3], seed_tuples[s][2]
        if (measure[2] + g + 1) % eval_every == 0:
            mseeds[due * eval_episodes : (due + 1) * eval_episodes] = _draw_seeds(rngs[2], eval_episodes)
            for r in range(eval_episodes):
                mk.put_row(mparams, due * eval_episodes + r, means[s])
            due += 1
    if due:
        m = due * eval_episodes
        _episodes_of(episodes, mparams[:m], mseeds[:m], mreturns[:m], msteps[:m], trace)
        due = 0
        for s in range(len(seed_tuples)):
            measure, out = seed_tuples[s][3], seed_tuples[s][5]
            if (measure[2] + g + 1) % eval_every == 0:
                out[5][g] = lk.numpy_sum(mreturns[due * eval_episodes : (due + 1) * eval_episodes]) / eval_episodes
                due += 1


#: Most seeds one call runs (:func:`_make_chunk`): the call takes them as a tuple of this length, padded, so that numba
#: compiles one entry point whatever the number of seeds. Why 8 and not more: the entry's CPython wrapper unboxes every
#: padded seed's tuple (~40 arrays and records each), and its compile grows faster than the seeds -- the wrapper alone
#: took 5, 11 and 35 s for 4, 8 and 16 seeds; the SNES entry's whole compile took 125 s at 16 (``_seed_list`` a function
#: of its own, with a wrapper of its own) against 37 s at 8 (numba 0.68, ``/tmp`` scripts on the 2-core VM). 8 seeds' fresh members (two or three each on
#: the main job) still fill the episode kernel's lanes (:data:`imix_cli.core.envs.kernels.LANES`); a worker's 13 seeds
#: take two calls.
SEEDS_PER_CALL = 8


def _make_chunk(digest: int):
    def _run_chunk(generations, rule, episodes, batch, generators, n):
        """Run ``generations`` generations of the first ``n`` seeds of ``batch`` (module docstring); ``_UPDATE``,
        ``_UTILITIES`` and ``_MEAN_WEIGHTS`` are the ES's compiled step, utilities and mean weights (:func:`entry`).
        The arguments are tuples (numba types each field), built by :func:`imix_cli.running.loop.compiled_loop.advance_seeds`,
        which names every field:

        - ``rule``: the mixing rule, the ES's utilities' settings, its training reward's offset
          (:attr:`~imix_cli.core.algorithms.base.EvolutionStrategy.reward_offset`), whether its members are mirrored
          pairs (ARS: the anchors are mixed and archived, :mod:`imix_cli.core.mixing.mirrored`) and the most probes a
          generation has (the full chunk's);
        - ``episodes``: the episode kernel (:func:`_env_code`) and its settings;
        - ``batch``: :data:`SEEDS_PER_CALL` seeds' tuples (the last ones repeat the first, unused), each
          ``(es, archive, measure, seed, out)``: the ES's generation count, a copy of its state record
          (``state.mean``, ``state.std``: the diagonal Gaussian searched) and its step's constants
          (:class:`~imix_cli.core.algorithms.base.CompiledStep`); the archived generations, newest first, as arrays of
          ``slots`` rows; when and how the mean is evaluated; the best member so far and the last utilities; the rows'
          numbers, one row per generation;
        - ``generators``: the seeds' generators, as many and in the same order: (members, episodes, the mean's
          episodes) -- an argument of their own (:func:`_seed_list`).

        Each generation plans every seed (mixing), runs the fresh members of all of them in one call of the episode
        kernel -- one seed's two or three fresh members left that kernel's lanes idle (``LANES_FROM``), the seeds' together
        fill them -- then tells each seed. A member's episode, and every draw of a seed's generators, are those of the
        seed run alone: the same numbers, in any batch.

        Every state array is updated in place; returns the number of generations done -- fewer when a generation of
        any seed met what only the Python path handles (the states are then unusable: the caller restores snapshots)."""
        if digest == 0:  # never: the digest is in the closure so that numba keys the cache on it
            return -1
        kernel, depth, alpha, log_keep, min_fresh, weight_decay, mult, offset, mirrored, max_probes = rule
        seed_tuples = _seed_list(batch, generators, n)
        a_x0 = seed_tuples[0][1][1]
        kept, d = a_x0.shape[1], a_x0.shape[2]  # the rows a generation archives: its members, or its pairs' anchors
        popsize = 2 * kept if mirrored else kept
        generation, episode_rows, scratch = _call_arrays(n, popsize, d, n * popsize, seed_tuples[0][3][1])
        xs, sources, indices, ages, fitnesses, trials_of = generation
        params, rows, seeds, returns, steps = episode_rows
        trace = scratch[4]
        log_norms = np.empty(n)
        fresh_from = np.empty(n + 1, dtype=np.int64)  # seed s's fresh members are rows fresh_from[s]:fresh_from[s + 1]
        means = np.empty((n, d))
        for g in range(generations):
            # ---- plan: mix (or draw) each seed's generation from its distribution N(mu, std^2) -- or its pairs' anchors,
            # then mirror them (mirrors are always fresh)
            fresh_from[0] = 0
            for s in range(n):
                es, archive, rngs, measure, seed, out = seed_tuples[s]
                state = es[1]
                a_n, a_x, a_mean, a_std, a_lognorm, a_h, a_hset, a_ret, a_age, a_src, a_idx, a_mw, a_trials = archive
                log_norms[s] = mk.diagonal_log_norm(state.std)
                x, source, index, trials_of[s] = mk.mix_step(
                    kernel, rngs[0], (state.mean, state.std, log_norms[s]), (a_mean, a_std, a_lognorm, a_x, a_h), a_hset,
                    min(a_n[0], depth), (kept, log_keep, alpha, min_fresh),
                )  # fmt: skip
                if mirrored:
                    x, source, index = _mirrored_pairs(x, source, index, state.mean)
                xs[s] = x
                sources[s] = source
                indices[s] = index
                e = _place_members(x, source, index, (a_age, a_ret), params, rows, fresh_from[s], ages[s], fitnesses[s])
                seeds[fresh_from[s] : e] = _draw_seeds(rngs[1], e - fresh_from[s])
                fresh_from[s + 1] = e
            # ---- evaluate the fresh members of every seed, in one call
            total = fresh_from[n]
            if total:
                _episodes_of(episodes, params[:total], seeds[:total], returns[:total], steps[:total], trace)
            if not _take_returns(fitnesses, rows, returns, steps, offset, fresh_from, fresh_from[1:]):
                return g
            # ---- tell each seed: the ES's own utilities and update; archive (a mirrored ES: the anchors); the row's numbers
            for s in range(n):
                es, archive, rngs, measure, seed, out = seed_tuples[s]
                es_generation, state, constants = es
                a_n, a_x, a_mean, a_std, a_lognorm, a_h, a_hset, a_ret, a_age, a_src, a_idx, a_mw, a_trials = archive
                last_u = seed[2]
                mu, std = state.mean, state.std
                x, source, fitness = xs[s], sources[s], fitnesses[s]
                u = _UTILITIES(x, fitness, es_generation[0], weight_decay, mult)
                out[4][g] = lk.numpy_sum(std) / d
                mu_drawn, std_drawn = mu.copy(), std.copy()  # the distribution the generation was drawn from
                _UPDATE(x, u, state, constants)
                mw = _MEAN_WEIGHTS(u, constants)  # after the update, as tell takes them (constants are never written)
                for j in range(d):  # a distribution no longer finite: the Python path records the divergence
                    if not (math.isfinite(mu[j]) and math.isfinite(std[j]) and std[j] > 0.0):
                        return g
                es_generation[0] += 1
                last_u[:] = mw
                if depth > 0:  # archive (newest first, at most depth generations): the distributions, then the rest
                    for k in range(min(a_n[0], depth - 1), 0, -1):
                        a_mean[k] = a_mean[k - 1]
                        a_std[k] = a_std[k - 1]
                        a_lognorm[k] = a_lognorm[k - 1]
                    a_mean[0] = mu_drawn
                    a_std[0] = std_drawn
                    a_lognorm[0] = log_norms[s]
                    common = (a_n, a_x, a_h, a_hset, a_ret, a_age, a_src, a_idx, a_mw, a_trials)
                    _archive_generation(common, depth, x[:kept], fitness[:kept], ages[s][:kept], source[:kept], indices[s][:kept], mw[:kept], trials_of[s])
                _record(g, x, source, fitness, steps[fresh_from[s] : fresh_from[s + 1]], seed, out)
                means[s] = mu
            # ---- the distribution means on fresh episodes, when due: every due seed's in one call
            _measure_means(g, seed_tuples, means, episodes, scratch)
        return generations

    return _run_chunk


def _make_full_chunk(digest: int):
    def _run_full_chunk(generations, rule, episodes, batch, generators, n):
        """:func:`_make_chunk`'s chunk for an ES searching a full Gaussian (CMA-ES: its compiled step's ``full``,
        :class:`~imix_cli.core.algorithms.base.CompiledStep`): ``_DISTRIBUTION`` gives the Gaussian of its state,
        ``_PROBES`` the points it asks to have evaluated besides its members (TPA's), ``_UPDATE`` moves the state. The
        mixing step is ``"exact"``'s between FullGaussians (:func:`imix_cli.core.mixing.kernels.mix_full_exact`'s
        kernel), as :func:`imix_cli.core.mixing.mix` takes it. ``rule`` ends with the most probes a generation has.
        Each seed's ``archive`` (:func:`pack_full_archive`) keeps in slot 0 of its distribution arrays the current
        distribution, in slot k + 1 archive entry k's, and the archived log-densities between generations (``table``):
        only the new distribution's are computed each generation, as the Python path's cache does."""
        if digest == 0:  # never: the digest is in the closure so that numba keys the cache on it
            return -1
        kernel, depth, alpha, log_keep, min_fresh, weight_decay, mult, offset, mirrored, max_probes = rule
        seed_tuples = _seed_list(batch, generators, n)
        a_x0 = seed_tuples[0][1][1]
        popsize, d = a_x0.shape[1], a_x0.shape[2]
        generation, episode_rows, scratch = _call_arrays(n, popsize, d, n * (popsize + max_probes), seed_tuples[0][3][1])
        xs, sources, indices, ages, fitnesses, trials_of = generation
        params, rows, seeds, returns, steps = episode_rows
        trace = scratch[4]
        probe_points = np.empty((n, max(max_probes, 1), d))
        # seed s's episodes are rows fresh_from[s]:fresh_from[s + 1]: its fresh members, then from probe_from[s] its probes
        fresh_from = np.empty(n + 1, dtype=np.int64)
        probe_from = np.empty(n, dtype=np.int64)
        means = np.empty((n, d))
        counts = np.full(max(depth, 1), popsize, dtype=np.int64)
        known = np.ones(max(depth, 1), dtype=np.bool_)
        mean_weights = np.empty(popsize)
        for s in range(n):  # each seed's distribution, in slot 0
            state, archive = seed_tuples[s][0][1], seed_tuples[s][1]
            mean, cov, low, log_norm, ok = _DISTRIBUTION(state)
            if not ok:
                return 0
            archive[2][0] = low
            archive[3][0] = mean
            archive[4][0] = cov
            archive[5][0] = log_norm
        for g in range(generations):
            # ---- plan: mix (or draw) each seed's generation, then its probes
            fresh_from[0] = 0
            for s in range(n):
                es, archive, rngs, measure, seed, out = seed_tuples[s]
                a_n, a_x, a_low, a_mean, a_cov, a_lognorm, a_h, a_hset, a_table, a_known, a_ret, a_age, a_src, a_idx, a_mw, a_trials = archive
                rng = rngs[0]
                used = min(a_n[0], depth)
                if kernel == 0 or used == 0:
                    x = mk.full_draws(rng, a_low[0], a_mean[0], popsize)
                    source = np.zeros(popsize, dtype=np.int64)
                    index = np.full(popsize, -1, dtype=np.int64)
                    trials_of[s] = 0
                else:
                    for k in range(used):  # each generation's log-heights, drawn the first time it is mixed from
                        if not a_hset[k]:
                            for i in range(popsize):
                                r = rng.random()
                                a_h[k, i] = el.log(r) if r > 0.0 else -np.inf
                            a_hset[k] = True
                    for k in range(used):  # entry k's rows under the archived distributions: once, then kept
                        if not a_known[k]:
                            a_table[k, 1 : k + 2] = lk.gaussian_log_probs_kernel(a_low[1 : k + 2], a_mean[1 : k + 2], a_lognorm[1 : k + 2], a_x[k])
                            a_known[k] = True
                    for k in range(used):  # the archived rows under the new distribution: every generation
                        a_table[k, :1] = lk.gaussian_log_probs_kernel(a_low[:1], a_mean[:1], a_lognorm[:1], a_x[k])
                    x, source, index, trials_of[s] = mk.exact_full(
                        rng, a_low[: used + 1], a_mean[: used + 1], a_lognorm[: used + 1], a_x[:used], a_h[:used], a_table[:used],
                        known[:used], counts[:used], popsize, min_fresh,
                    )  # fmt: skip
                xs[s] = x
                sources[s] = source
                indices[s] = index
                e = _place_members(x, source, index, (a_age, a_ret), params, rows, fresh_from[s], ages[s], fitnesses[s])
                probe_from[s] = e
                for p in range(_PROBES(rng, es[1], es[2], probe_points[s])):  # never mixed, never archived: not members
                    mk.put_row(params, e, probe_points[s, p])
                    e += 1
                seeds[fresh_from[s] : e] = _draw_seeds(rngs[1], e - fresh_from[s])
                fresh_from[s + 1] = e
            # ---- evaluate the fresh members and probes of every seed, in one call
            total = fresh_from[n]
            if total:
                _episodes_of(episodes, params[:total], seeds[:total], returns[:total], steps[:total], trace)
            if not _take_returns(fitnesses, rows, returns, steps, offset, fresh_from, probe_from):
                return g
            # ---- tell each seed: the ES's own utilities and update; archive; the row's numbers
            for s in range(n):
                es, archive, rngs, measure, seed, out = seed_tuples[s]
                es_generation, state, constants = es
                a_n, a_x, a_low, a_mean, a_cov, a_lognorm, a_h, a_hset, a_table, a_known, a_ret, a_age, a_src, a_idx, a_mw, a_trials = archive
                x, source, fitness = xs[s], sources[s], fitnesses[s]
                u = _UTILITIES(x, fitness, es_generation[0], weight_decay, mult)
                std = np.empty(d)
                for j in range(d):
                    std[j] = math.sqrt(a_cov[0, j, j])
                out[4][g] = lk.numpy_sum(std) / d
                if not _UPDATE(x, u, fitness, returns[probe_from[s] : fresh_from[s + 1]], state, constants, mean_weights):
                    return g  # the Python path records the divergence
                mean, cov, low, log_norm, ok = _DISTRIBUTION(state)
                if not ok:
                    return g
                for j in range(d):  # a distribution no longer finite: the Python path records the divergence
                    if not (math.isfinite(mean[j]) and math.isfinite(cov[j, j])):
                        return g
                es_generation[0] += 1
                seed[2][:] = mean_weights
                if depth > 0:  # archive (newest first, at most depth generations): the distributions, then the rest
                    for k in range(min(a_n[0], depth - 1), 0, -1):  # slot k + 1 holds entry k's distribution
                        a_low[k + 1] = a_low[k]
                        a_mean[k + 1] = a_mean[k]
                        a_cov[k + 1] = a_cov[k]
                        a_lognorm[k + 1] = a_lognorm[k]
                        # entry k - 1's log-densities under the distribution it was mixed for (slot 0, now entry 0's:
                        # the one this generation was drawn from) and under the archived ones: the same distributions
                        a_table[k, 1 : k + 2] = a_table[k - 1, : k + 1]
                        a_known[k] = a_known[k - 1]
                    a_low[1] = a_low[0]
                    a_mean[1] = a_mean[0]
                    a_cov[1] = a_cov[0]
                    a_lognorm[1] = a_lognorm[0]
                    a_known[0] = False
                    common = (a_n, a_x, a_h, a_hset, a_ret, a_age, a_src, a_idx, a_mw, a_trials)
                    _archive_generation(common, depth, x, fitness, ages[s], source, indices[s], mean_weights, trials_of[s])
                a_low[0] = low
                a_mean[0] = mean
                a_cov[0] = cov
                a_lognorm[0] = log_norm
                _record(g, x, source, fitness, steps[fresh_from[s] : fresh_from[s + 1]], seed, out)
                means[s] = mean
            # ---- the distribution means on fresh episodes, when due: every due seed's in one call
            _measure_means(g, seed_tuples, means, episodes, scratch)
        return generations

    return _run_full_chunk


# ------------------------------------------------------------------------------ the entry points, and the archive as arrays
_ENTRIES: dict = {}


def entry(update, utilities, mean_weights=None, full=None):
    """The compiled entry point running ES update ``update`` with utilities ``utilities`` and mean weights ``mean_weights``
    (None: :func:`utilities_are_mean_weights`) -- or, ``full`` = (distribution, probes, most probes) given, the chunk of a
    full Gaussian (:func:`_make_full_chunk`) -- built on first use: its cache key needs the dependency digest (module docstring)."""
    mean_weights = mean_weights or utilities_are_mean_weights
    key = (update, utilities, mean_weights, None if full is None else full[:2])
    if key not in _ENTRIES:
        digest = _functions_digest(update, utilities, mean_weights, *(() if full is None else full[:2]))
        inner = (_make_chunk if full is None else _make_full_chunk)(digest)
        own = {"_UPDATE": update, "_UTILITIES": utilities, "_MEAN_WEIGHTS": mean_weights}
        if full is not None:
            own.update(_DISTRIBUTION=full[0], _PROBES=full[1])
        chunk = types.FunctionType(inner.__code__, {**globals(), **own}, inner.__name__, None, inner.__closure__)
        # Named after the digest: each entry gets an index file of its own in numba's cache. An index holds the types of
        # its entries' arguments, the ES's state record among them, and numba imports their classes when it reads the
        # index: a shared index would make every run import the record class of any ES ever run (one defined in a
        # script or a test cannot be imported by another process).
        chunk.__qualname__ = f"{inner.__name__}_{digest:016x}"
        chunk.__module__, chunk.__doc__ = inner.__module__, inner.__doc__
        _ENTRIES[key] = njit(cache=True)(chunk)
    return _ENTRIES[key]


def entry_for(es, step=None):
    """The compiled entry point that runs ``es`` (one with a compiled step and compiled utilities); ``step``: its
    :meth:`~imix_cli.core.algorithms.base.EvolutionStrategy.compiled_step`, if the caller has it already."""
    step = step or es.compiled_step()
    return entry(step.update, es.compiled_utilities(), step.mean_weights, step.full)


def env_code(evaluator) -> int | None:
    """The episode kernel of ``evaluator`` (:func:`_episodes`): a built-in env's evaluator run in this process only
    (a pool's or Ray's evaluator is another class: its episodes run elsewhere); None, the loop cannot run it."""
    from imix_cli.core.evaluation import AcrobotEvaluator, CartPoleEvaluator, ContinuousCartPoleEvaluator

    return {CartPoleEvaluator: _CARTPOLE, ContinuousCartPoleEvaluator: _CARTPOLE, AcrobotEvaluator: _ACROBOT}.get(type(evaluator))


def pack_archive(archive, slots: int, popsize: int, d: int) -> tuple:
    """``archive`` (an :class:`~imix_cli.core.mixing.generation.Archive` of diagonal Gaussians, newest first) as the
    chunk's arrays of ``slots`` rows: ``(n, samples, means, stds, log_norms, log_u, log_u_set, returns, ages, sources,
    indices, mean_weights, trials)``; rows past its generations are placeholders the chunk never reads."""
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
        a_ret[k], a_age[k], a_src[k], a_idx[k], a_trials[k] = archive.returns[k], archive.ages[k], g.source, g.index, g.trials
        if g.mean_weights is not None:  # (a mirrored ES's anchors have none)
            a_mw[k] = g.mean_weights
    a_n = np.array([len(archive.generations)], dtype=np.int64)
    return (a_n, a_x, a_mean, a_std, a_lognorm, a_h, a_hset, a_ret, a_age, a_src, a_idx, a_mw, a_trials)


def unpack_archive(archive, arrays: tuple, mean_weights: bool = True) -> None:
    """Put :func:`pack_archive`'s arrays, as a chunk left them, back into ``archive``; ``mean_weights`` False: the
    generations keep none (a mirrored ES's anchors, as the Python path archives them)."""
    a_n, a_x, a_mean, a_std, a_lognorm, a_h, a_hset, a_ret, a_age, a_src, a_idx, a_mw, a_trials = arrays
    n = int(a_n[0])
    archive.generations = [
        Generation(a_x[k].copy(), a_src[k].copy(), a_idx[k].copy(), DiagonalGaussian(a_mean[k], a_std[k]), int(a_trials[k]),
                   a_h[k].copy() if a_hset[k] else None, a_mw[k].copy() if mean_weights else None)
        for k in range(n)
    ]  # fmt: skip
    archive.returns = [a_ret[k].copy() for k in range(n)]
    archive.ages = [a_age[k].copy() for k in range(n)]


def pack_full_archive(archive, slots: int, popsize: int, d: int) -> tuple:
    """``archive`` (an :class:`~imix_cli.core.mixing.generation.Archive` of FullGaussians, newest first) as
    :func:`_make_full_chunk`'s arrays: ``(n, samples, lows, means, covs, log_norms, log_u, log_u_set, table, table_known,
    returns, ages, sources, indices, mean_weights, trials)``, the distributions' arrays with one slot more than the
    others (slot 0: the current distribution, set by the chunk; slot k + 1: entry k's), ``table`` the archived
    log-densities the chunk keeps (computed in it: none known here)."""
    a_x = np.zeros((slots, popsize, d))
    a_low, a_cov = np.zeros((slots + 1, d, d)), np.zeros((slots + 1, d, d))
    a_mean, a_lognorm = np.zeros((slots + 1, d)), np.zeros(slots + 1)
    a_h, a_hset = np.zeros((slots, popsize)), np.zeros(slots, dtype=np.bool_)
    a_table, a_known = np.zeros((slots, slots + 1, popsize)), np.zeros(slots, dtype=np.bool_)
    a_ret, a_mw = np.zeros((slots, popsize)), np.zeros((slots, popsize))
    a_age, a_src, a_idx = (np.zeros((slots, popsize), dtype=np.int64) for _ in range(3))
    a_trials = np.zeros(slots, dtype=np.int64)
    for k, g in enumerate(archive.generations):
        a_x[k], a_low[k + 1], a_mean[k + 1], a_cov[k + 1], a_lognorm[k + 1] = g.samples, g.dist.chol, g.dist.mean, g.dist.cov, g.dist.log_norm
        if g.log_u is not None:
            a_h[k], a_hset[k] = g.log_u, True
        a_ret[k], a_mw[k], a_age[k], a_src[k], a_idx[k], a_trials[k] = archive.returns[k], g.mean_weights, archive.ages[k], g.source, g.index, g.trials
    a_n = np.array([len(archive.generations)], dtype=np.int64)
    return (a_n, a_x, a_low, a_mean, a_cov, a_lognorm, a_h, a_hset, a_table, a_known, a_ret, a_age, a_src, a_idx, a_mw, a_trials)


def unpack_full_archive(archive, arrays: tuple) -> None:
    """Put :func:`pack_full_archive`'s arrays, as a chunk left them, back into ``archive``: each distribution the
    FullGaussian the Python path holds (its factor and log-normaliser as computed, its covariance kept)."""
    a_n, a_x, a_low, a_mean, a_cov, a_lognorm, a_h, a_hset, a_table, a_known, a_ret, a_age, a_src, a_idx, a_mw, a_trials = arrays
    n = int(a_n[0])
    generations = []
    for k in range(n):
        dist = FullGaussian.from_cholesky(a_mean[k + 1].copy(), a_low[k + 1].copy(), checked=False, log_norm=float(a_lognorm[k + 1]))
        dist._cov = a_cov[k + 1].copy()
        generations.append(Generation(a_x[k].copy(), a_src[k].copy(), a_idx[k].copy(), dist, int(a_trials[k]),
                                      a_h[k].copy() if a_hset[k] else None, a_mw[k].copy()))  # fmt: skip
    archive.generations = generations
    archive.returns = [a_ret[k].copy() for k in range(n)]
    archive.ages = [a_age[k].copy() for k in range(n)]
