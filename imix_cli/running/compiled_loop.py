"""The generation loop compiled: mixing, episodes and ES update of one seed, many generations per call.

Why. On the main job (SNES + EIM, CartPole) the Python loop -- :func:`imix_cli.running.lockstep.advance_lockstep`
-> :mod:`imix_cli.generation` -> mixing, evaluator, ES -- spends ~0.8 ms per seed-generation, while
the numbers themselves (a mixing step, two or three episodes, one update over 50 x 130 numbers) need
about a tenth of that: the rest is some sixty small numpy calls and Python dispatch per generation
(``imix bench breakdown``). Here one compiled call runs a chunk of generations of one seed: mix,
roll out the fresh members, rank, update, archive, and measure the distribution mean when due.

What it computes: *the Python path's numbers, bit for bit* -- the CSV rows, the checkpoints, the
policies. The same random numbers in the same order (numba draws from the seed's own numpy
Generators with NumPy's algorithms and advances them in place); the same kernels where the Python
path calls compiled ones (the mixing step of :mod:`imix_cli.mixing_kernels`, the episodes of
:mod:`imix_cli.envs.kernels`, the fixed-order sums of :mod:`imix_cli.linalg_kernels`); numpy's own
summation order where the Python path calls ``np.sum``/``np.mean`` (:func:`_numpy_sum`: numpy's
pairwise summation, blocks of 128 with eight accumulators); the same libm ``exp``/``log``/``pow``.
The Python path stays the reference: ``IMIX_COMPILED_LOOP=0`` takes it, and
``tests/test_compiled_loop.py`` runs both and compares CSVs, checkpoints and policy files.

Where it applies (:func:`applies`): OpenES and SNES (centred ranks, the estool weight decay), no
mixing or the ``paper``/``sun2009``/``exact`` rules with no re-evaluation options, no observation
normalisation, a built-in CartPole environment (CartPole, ContinuousCartPole, its Hard variant)
evaluated in the process. Anything else takes the Python path, unchanged. Acrobot is left out on
purpose: its reset computes the first observation with numpy's float32 ``cos``/``sin`` (SIMD code
of numpy's own), which a compiled loop cannot reproduce bit for bit.

When a chunk meets what the Python path treats specially -- a non-finite return, or an update that
leaves the distribution non-finite (divergence) -- the chunk is dropped (the random generators are
put back) and the seed continues on the Python path, which records it exactly as always.

Compilation: the entry point :func:`_run_chunk` is cached on disk like every imix kernel. numba
invalidates a cached function when *its own* file changes, not when a function it calls from another
file does; so the entry carries, in its closure (which numba hashes into the cache key), a digest of
the files it calls into: editing any of them recompiles it.
"""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path

import numpy as np
from numba import njit

from imix_cli import elementary as el
from imix_cli import linalg_kernels as lk
from imix_cli import mixing_kernels as mk
from imix_cli.algorithms.base import EstoolWeightDecay, centered_ranks, hash_multipliers
from imix_cli.algorithms.openes import OpenES
from imix_cli.algorithms.snes import SNES
from imix_cli.distributions import DiagonalGaussian
from imix_cli.envs import kernels as ek
from imix_cli.mixing import _COMPILED_MAX_ELEMENTS, Generation, variant_spec

__all__ = ["applies", "applies_to_run", "advance", "entry", "ENV_VARIABLE"]

#: ``IMIX_COMPILED_LOOP=0``: every run takes the Python path (the reference).
ENV_VARIABLE = "IMIX_COMPILED_LOOP"

_ALGOS = {OpenES: 0, SNES: 1}
_LOG_2PI = el.math_log(2.0 * math.pi)
_SEED_HIGH = np.iinfo(np.int64).max  # episode seeds: integers(0, int64 max), as lockstep draws them


def _dependency_digest() -> int:
    """A 63-bit digest of the sources this module's compiled entry calls into (module docstring)."""
    h = hashlib.sha256()
    for source in (__file__, mk.__file__, lk.__file__, ek.__file__, el.__file__):  # named by their modules: right wherever they live
        h.update(Path(source).read_bytes())
    return int.from_bytes(h.digest()[:8], "little") >> 1


# ------------------------------------------------------------------------------ numerics
@njit
def _block_sum(a, lo, n):
    """numpy's pairwise_sum (numpy/_core/src/umath/loops_utils.h.src) of n <= 128 numbers: one loop
    below 8, else eight accumulators combined as a tree, then the remainder."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    last = n - n % 8
    while i < last:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit
def _half(n):
    half = n // 2
    return half - half % 8


@njit
def _pairwise(a, lo, n):
    """numpy's pairwise_sum of ``a[lo:lo + n]``: above 128 numbers, the sum of the two halves (the
    first rounded down to a multiple of 8), each summed the same way. Written with an explicit
    stack: numba's on-disk cache does not reload self-recursive functions safely."""
    if n <= 128:
        return _block_sum(a, lo, n)
    los = np.empty(64, dtype=np.int64)
    ns = np.empty(64, dtype=np.int64)
    right = np.zeros(64, dtype=np.bool_)  # the pending node's left half is summed; its right is running
    left = np.empty(64)
    los[0], ns[0], right[0], top = lo, n, False, 1
    while True:
        i = top - 1
        if ns[i] > 128:  # descend into the left half
            los[top], ns[top], right[top] = los[i], _half(ns[i]), False
            top += 1
            continue
        v = _block_sum(a, los[i], ns[i])
        top -= 1
        while True:  # hand v up: a left half starts its sibling, a right half completes its parent
            if top == 0:
                return v
            p = top - 1
            if not right[p]:
                left[p], right[p] = v, True
                half = _half(ns[p])
                los[top], ns[top], right[top] = los[p] + half, ns[p] - half, False
                top += 1
                break
            v = left[p] + v
            top -= 1


@njit
def _numpy_sum(a):
    """``np.sum(a)`` of a contiguous (n,) float64 array, the same bits (numpy's pairwise summation)."""
    return _pairwise(a, 0, a.shape[0])


@njit
def _log_norm(std):
    """``DiagonalGaussian._log_norm``: -d/2 log(2 pi) - np.sum(lk.log(std))."""
    d = std.shape[0]
    logs = np.empty(d)
    for j in range(d):
        logs[j] = el.log(std[j])
    return -0.5 * d * _LOG_2PI - _numpy_sum(logs)


@njit
def _keys(x, mult, salt_term):
    """:func:`imix_cli.algorithms.base.member_keys` (wrapping uint64 arithmetic)."""
    n, d = x.shape
    bits = x.view(np.uint64)
    out = np.empty(n, dtype=np.uint64)
    for i in range(n):
        h = np.uint64(0)
        for j in range(d):
            h += bits[i, j] * mult[j]
        h += salt_term
        h ^= h >> np.uint64(30)
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(27)
        h *= np.uint64(0x94D049BB133111EB)
        h ^= h >> np.uint64(31)
        out[i] = h
    return out


@njit
def _utilities(x, fitness, mult, salt_term, weight_decay):
    """:meth:`EvolutionStrategy.utilities` with centred ranks (ties ordered by key) and the estool
    weight decay: ranks / (n - 1) - 0.5 - w * mean(x_i^2). ``fitness`` is finite here."""
    n, d = x.shape
    keys = _keys(x, mult, salt_term)
    # np.lexsort((keys, fitness)): ascending fitness, ties by ascending key, stable (insertion sort)
    order = np.arange(n)
    for i in range(1, n):
        k = order[i]
        j = i - 1
        while j >= 0 and (fitness[order[j]] > fitness[k] or (fitness[order[j]] == fitness[k] and keys[order[j]] > keys[k])):
            order[j + 1] = order[j]
            j -= 1
        order[j + 1] = k
    u = np.empty(n)
    sq = np.empty(d)
    for r in range(n):
        u[order[r]] = float(r) / (n - 1) - 0.5
    for i in range(n):
        for j in range(d):
            sq[j] = x[i, j] * x[i, j]
        u[i] = u[i] - weight_decay * (_numpy_sum(sq) / d)
    return u


@njit
def _adam(m, v, t, lr, beta1, beta2, grad):
    """:meth:`imix_cli.algorithms.base.Adam.step` in place of its moments; returns the increment."""
    t[0] += 1
    d = grad.shape[0]
    step_size = lr * math.sqrt(1.0 - el.pow(beta2, float(t[0]))) / (1.0 - el.pow(beta1, float(t[0])))
    out = np.empty(d)
    for j in range(d):
        m[j] = beta1 * m[j] + (1.0 - beta1) * grad[j]
        v[j] = beta2 * v[j] + (1.0 - beta2) * grad[j] * grad[j]
        out[j] = step_size * m[j] / (math.sqrt(v[j]) + 1e-8)
    return out


@njit
def _tell(algo, x, u, mu, log_sigma, std, sigma0, opt_m, opt_v, opt_t, lrs, beta1, beta2):
    """OpenES's or SNES's ``_update`` (their docstrings): mu, log_sigma and std in place.
    Returns False when the new distribution is not finite (the Python path's divergence)."""
    n, d = x.shape
    eps = np.empty((n, d))
    for i in range(n):
        for j in range(d):
            eps[i, j] = (x[i, j] - mu[j]) / std[j]
    grad = lk._vec_mat(u, eps)
    if algo == 0:  # OpenES: g = sum u eps / (n sigma); std stays sigma
        scale = n * sigma0
        for j in range(d):
            grad[j] = grad[j] / scale
        step = _adam(opt_m[0], opt_v[0], opt_t[0:1], lrs[0], beta1, beta2, grad)
        for j in range(d):
            mu[j] = mu[j] + step[j]
    else:  # SNES: natural gradients on mu and log sigma
        for j in range(d):
            grad[j] = std[j] * grad[j]
        sq = np.empty((n, d))
        for i in range(n):
            for j in range(d):
                sq[i, j] = eps[i, j] * eps[i, j] - 1.0
        grad_ls = lk._vec_mat(u, sq)
        for j in range(d):
            grad_ls[j] = grad_ls[j] / 2.0
        step = _adam(opt_m[0], opt_v[0], opt_t[0:1], lrs[0], beta1, beta2, grad)
        step_ls = _adam(opt_m[1], opt_v[1], opt_t[1:2], lrs[1], beta1, beta2, grad_ls)
        for j in range(d):
            mu[j] = mu[j] + step[j]
            log_sigma[j] = log_sigma[j] + step_ls[j]
            std[j] = el.exp(log_sigma[j])
    for j in range(d):
        if not (math.isfinite(mu[j]) and math.isfinite(std[j]) and std[j] > 0.0):
            return False
    return True


@njit
def _draw_seeds(rng, n):
    """``rng.integers(0, int64 max, size=n)`` as uint64 (the episode kernels' seed type)."""
    return rng.integers(0, 9223372036854775807, size=n).astype(np.uint64)


def _make_entry(digest: int):
    @njit(cache=True)
    def _run_chunk(
        generations, algo, variant, depth, alpha, log_keep, min_fresh, weight_decay, mult, es_generation,
        mu, log_sigma, std, sigma0, opt_m, opt_v, opt_t, lrs, beta1, beta2,
        a_n, a_x, a_mean, a_std, a_lognorm, a_h, a_hset, a_ret, a_age, a_src, a_idx, a_mw, a_trials,
        sample_rng, episode_rng, mean_rng, sizes, continuous, sparse, max_steps, eval_every, eval_episodes, generation0,
        best, best_return, last_u,
        out_scores, out_reused, out_evaluated, out_steps, out_sigma_mean, out_theta,
    ):  # fmt: skip
        """Run ``generations`` generations of one seed (module docstring). Every state array is
        updated in place; returns the number of generations done -- fewer when a generation met what
        only the Python path handles (its state is then unusable: the caller restores a snapshot)."""
        if digest == 0:  # never: the digest is in the closure so that numba keys the cache on it
            return -1
        popsize, d = a_x.shape[1], a_x.shape[2]
        trace = np.empty((0, 0, 0))
        golden = np.uint64(0x9E3779B97F4A7C15)
        for g in range(generations):
            # ---- plan: mix (or draw) the generation from the distribution N(mu, std^2)
            log_norm = _log_norm(std)
            k_used = min(a_n[0], depth)
            if variant == 0 or k_used == 0:
                x = np.empty((popsize, d))
                mk._fill_plain(sample_rng, mu, std, x, 0, popsize)
                source = np.zeros(popsize, dtype=np.int64)
                index = np.full(popsize, -1, dtype=np.int64)
                trials = 0
            else:
                if variant == 3:  # each generation's heights are drawn once, when it is first mixed from
                    for k in range(k_used):
                        if not a_hset[k]:
                            for i in range(popsize):
                                r = sample_rng.random()
                                a_h[k, i] = el.log(r) if r > 0.0 else -math.inf
                            a_hset[k] = True
                counts = np.full(k_used, popsize, dtype=np.int64)
                if variant == 1:
                    x, source, index, trials = mk._mix_paper(
                        sample_rng, mu, std, log_norm, a_mean[:k_used], a_std[:k_used], a_lognorm[:k_used],
                        a_x[:k_used], a_h[:k_used], counts, popsize, log_keep, alpha, min_fresh,
                    )  # fmt: skip
                elif variant == 2:
                    x, source, index, trials = mk._mix_sun2009(
                        sample_rng, mu, std, log_norm, a_mean[:k_used], a_std[:k_used], a_lognorm[:k_used],
                        a_x[:k_used], a_h[:k_used], counts, popsize, log_keep, alpha, min_fresh,
                    )  # fmt: skip
                else:
                    x, source, index, trials = mk._mix_exact(
                        sample_rng, mu, std, log_norm, a_mean[:k_used], a_std[:k_used], a_lognorm[:k_used],
                        a_x[:k_used], a_h[:k_used], counts, popsize, log_keep, alpha, min_fresh,
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
                    mk._put(params, e, x[i])
                    rows[e] = i
                    e += 1
            seeds = _draw_seeds(episode_rng, n_eval)
            returns = np.empty(n_eval)
            steps = np.empty(n_eval, dtype=np.int64)
            if n_eval:
                ek.cartpole_episodes(params, seeds, sizes, continuous, sparse, max_steps, returns, steps, trace)
            total_steps = 0
            for e in range(n_eval):
                fitness[rows[e]] = returns[e]
                total_steps += steps[e]
            for i in range(popsize):
                if not math.isfinite(fitness[i]):
                    return g
            # ---- tell
            salt_term = np.uint64(es_generation[0] + 1) * golden
            u = _utilities(x, fitness, mult, salt_term, weight_decay)
            out_sigma_mean[g] = _numpy_sum(std) / d
            mu_drawn, std_drawn = mu.copy(), std.copy()  # the distribution the generation was drawn from
            if not _tell(algo, x, u, mu, log_sigma, std, sigma0, opt_m, opt_v, opt_t, lrs, beta1, beta2):
                return g
            es_generation[0] += 1
            last_u[:] = u
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
                a_mw[0] = u
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
            out_scores[g, 0] = _numpy_sum(fitness) / popsize  # np.mean (every return is finite here)
            out_scores[g, 1] = fitness[0]
            for i in range(1, popsize):
                out_scores[g, 1] = max(out_scores[g, 1], fitness[i])
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
                    mk._put(mparams, r, mu)
                mreturns = np.empty(eval_episodes)
                msteps = np.empty(eval_episodes, dtype=np.int64)
                ek.cartpole_episodes(mparams, mseeds, sizes, continuous, sparse, max_steps, mreturns, msteps, trace)
                out_theta[g] = _numpy_sum(mreturns) / eval_episodes
        return generations

    return _run_chunk


# ------------------------------------------------------------------------------ the Python side
_ENTRY = []


def entry():
    """The compiled entry point (built on first use: its cache key needs the dependency digest)."""
    if not _ENTRY:
        _ENTRY.append(_make_entry(_dependency_digest()))
    return _ENTRY[0]


def enabled() -> bool:
    """Whether runs may take the compiled loop (``IMIX_COMPILED_LOOP`` unset or not ``0``)."""
    return os.environ.get(ENV_VARIABLE, "1").strip() != "0"


def _kernel(variant: str | None) -> int | None:
    """The loop's number for mixing ``variant``: 0 without mixing, the variant's compiled step
    (:class:`imix_cli.mixing.Variant`'s ``kernel``), None if it has none (the loop cannot take it)."""
    if variant is None:
        return 0
    return variant_spec(variant).kernel or None


def applies_to_run(settings, evaluator) -> bool:
    """Whether the seeds of a run (its :class:`imix_cli.running.lockstep.LoopSettings`) evaluated by ``evaluator``
    can take the compiled loop (module docstring)."""
    from imix_cli.evaluation import CartPoleEvaluator, ContinuousCartPoleEvaluator

    if not enabled() or type(evaluator) not in (CartPoleEvaluator, ContinuousCartPoleEvaluator) or settings.algo not in ("openes", "snes"):
        return False
    mixing = settings.mixing
    if _kernel(mixing.variant) is None or mixing.reeval_age is not None or mixing.reeval_prob > 0.0 or mixing.reeval_count > 0:
        return False
    # policy.bias=false: the ES's points are not the evaluator's parameter vectors (lockstep.policy_params)
    return settings.obs_norm_warmup is None and settings.policy_bias and settings.es_options["weight_decay_form"] == "estool"


def applies(settings, evaluator, st) -> bool:
    """Whether seed ``st`` of a run can take the compiled loop now (module docstring)."""
    if not applies_to_run(settings, evaluator) or st.obs_norm is not None or getattr(st.es, "diverged", None) is not None:
        return False
    depth = settings.mixing.depth
    es = getattr(st.es, "es", st.es)
    if type(es) not in _ALGOS or type(es.distribution) is not DiagonalGaussian or es.distribution.dtype != np.float64:
        return False
    params = es.params
    if params.weight_decay_form != "estool" or params.fitness_shaping != "centered_ranks" or es._shaping is not centered_ranks:
        return False
    if type(es._weight_decay) is not EstoolWeightDecay or es.popsize < 2 or es.popsize * es.dim * max(depth, 1) > _COMPILED_MAX_ELEMENTS:
        return False
    optimizers = [es.optimizer] if type(es) is OpenES else [es.mu_optimizer, es.sigma_optimizer]
    if any(o.epsilon != 1e-8 or o.beta1 != params.beta1 or o.beta2 != params.beta2 for o in optimizers):
        return False
    archive = st.archive
    if len(archive.generations) > depth or np.any(archive.pairs != 0.0):
        return False
    for g in archive.generations:
        if type(g.dist) is not DiagonalGaussian or g.samples.shape != (es.popsize, es.dim) or g.samples.dtype != np.float64 or g.mean_weights is None:
            return False
    return True


def advance(st, settings, evaluator, generations: int) -> bool:
    """Run ``generations`` generations of seed ``st`` (a :class:`imix_cli.running.lockstep.SeedState` for which
    :func:`applies`) in one compiled call, appending their rows as the Python path does. Returns
    False, having changed nothing, when a generation needs the Python path (module docstring)."""
    mixing = settings.mixing
    es = getattr(st.es, "es", st.es)
    snes = type(es) is SNES
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
        a_x[k], a_mean[k], a_std[k], a_lognorm[k] = g.samples, g.dist.mean, g.dist.std, g.dist._log_norm
        if g.log_u is not None:
            a_h[k], a_hset[k] = g.log_u, True
        a_ret[k], a_mw[k], a_age[k], a_src[k], a_idx[k], a_trials[k] = archive.returns[k], g.mean_weights, archive.ages[k], g.source, g.index, g.trials

    mu = es._mu.copy()
    std = es.distribution.std.copy()
    optimizers = [es.mu_optimizer, es.sigma_optimizer] if snes else [es.optimizer, es.optimizer]
    log_sigma = es._log_sigma.copy() if snes else np.zeros(d)
    opt_m = np.stack([o.m for o in optimizers])
    opt_v = np.stack([o.v for o in optimizers])
    opt_t = np.array([o.t for o in optimizers], dtype=np.int64)
    lrs = np.array([optimizers[0].lr, optimizers[1].lr])
    es_generation = np.array([es.generation], dtype=np.int64)
    best = np.zeros(d) if st.best_params is None else np.array(st.best_params, dtype=np.float64)
    best_return = np.array([st.best_return], dtype=np.float64)
    last_u = np.zeros(popsize)
    a_n = np.array([n_arch], dtype=np.int64)

    out_scores = np.empty((generations, 2))  # mean and best return of the generation
    out_reused = np.empty((generations, 3), dtype=np.int64)
    out_evaluated = np.empty(generations, dtype=np.int64)
    out_steps = np.empty(generations, dtype=np.int64)
    out_sigma_mean = np.empty(generations)
    out_theta = np.empty(generations)

    rngs = (st.sample_rng, st.episode_rng, st.mean_eval_rng)
    snapshot = [r.bit_generator.state for r in rngs]
    with np.errstate(divide="ignore"):
        log_keep = el.math_log1p(-mixing.alpha)
    done = entry()(
        generations, _ALGOS[type(es)], _kernel(mixing.variant), depth, float(mixing.alpha), log_keep, int(mixing.min_fresh),
        float(es.weight_decay), hash_multipliers(d), es_generation,
        mu, log_sigma, std, float(es.sigma), opt_m, opt_v, opt_t, lrs, float(es.params.beta1), float(es.params.beta2),
        a_n, a_x, a_mean, a_std, a_lognorm, a_h, a_hset, a_ret, a_age, a_src, a_idx, a_mw, a_trials,
        st.sample_rng, st.episode_rng, st.mean_eval_rng, evaluator._sizes(), type(evaluator).__name__ != "CartPoleEvaluator",
        bool(getattr(evaluator, "hard", False)), int(evaluator.max_steps), int(settings.eval_mean_every), int(settings.eval_mean_episodes),
        st.generation, best, best_return, last_u,
        out_scores, out_reused, out_evaluated, out_steps, out_sigma_mean, out_theta,
    )  # fmt: skip
    if done < generations:  # put the generators back: the Python path takes this chunk
        for r, state in zip(rngs, snapshot):
            r.bit_generator.state = state
        return False

    # ---- write the state back into the ES, the archive and the seed
    es._mu = mu
    for o, m, v, t in list(zip(optimizers, opt_m, opt_v, opt_t))[: 2 if snes else 1]:
        o.m, o.v, o.t = m.copy(), v.copy(), int(t)
    if snes:
        es._log_sigma = log_sigma
        es._dist = DiagonalGaussian(mu, std)
    else:
        es._dist = DiagonalGaussian(mu, es.sigma)
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
    numbers = (out_scores, out_reused, out_evaluated, out_steps, out_sigma_mean, out_theta)
    for scores, counts, n, steps, sigma_mean, theta in zip(*(a.tolist() for a in numbers)):
        st.evaluations += n
        st.env_steps += steps
        if every and (st.generation + 1) % every == 0:
            st.mean_policy_episodes += episodes
        # lockstep.generation_row's row, key for key, from the numbers the kernel computed as it does
        st.rows.append({
            "algo": settings.algo, "env": settings.env, "mixing": settings.mixing_name, "seed": st.seed, "generation": st.generation,
            "evaluations": st.evaluations, "env_steps": st.env_steps, "mean_score": scores[0], "best_score": scores[1],
            "reused": counts[0], "reused_im": counts[1], "reused_eim": counts[2], "reevaluated": 0,
            "popsize": settings.popsize, "sigma_mean": sigma_mean, "nonfinite": 0, "wall_time": 0.0,
            "mean_policy_score": theta, "mean_policy_episodes": st.mean_policy_episodes,
        })  # fmt: skip
    return True
