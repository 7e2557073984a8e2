"""Compiled importance mixing between diagonal Gaussians: the ``paper``, ``sun2009`` and ``exact`` rules.

Why compiled: OpenES, SNES and CEM mix every generation of every seed, and at the paper's
scale (d = 130, N = 50, K = 3) a mixing step in numpy is a few hundred small array calls:
``exact`` cost 12x drawing the generation plainly, and mixing was 63 % of a SNES + EIM run's
generation loop (cProfile, ``imix bench breakdown``). Here one call does a whole step with
scalar loops over the few thousand numbers involved.

What it computes: exactly what :func:`imix_cli.core.mixing.mix` computes on the same arguments --
same rules, same members, same order, **the same random numbers drawn in the same order from
the same** ``numpy.random.Generator`` (numba draws from a Generator passed to a compiled
function with NumPy's own algorithms and advances its state; ``standard_normal`` is NumPy's
ziggurat, ``permutation`` and ``integers`` NumPy's shuffles and bounded integers). The only
difference is summation order in the log-density ratios (sequential here, pairwise in numpy),
a few ulps, which can flip an acceptance only when a uniform lands within those ulps of its
threshold. ``tests/test_mixing.py`` checks member-for-member equality with the numpy path on
many random archives, and runs the chain (unbiasedness) tests on this path, which is the one
``mix`` takes for float64 diagonal Gaussians. The numpy path stays for every other
distribution, float32 samples, and archives of generations larger than ``popsize``.

The log-ratio log(p_new / p_old) is computed with the coefficients of
:class:`imix_cli.core.distributions.DiagonalLogRatio` (its docstring derives them): for a stored
row ``x``, ``c - 1/2 sum((q y + l) y)`` with ``y = x - m_old``; for a fresh draw
``x = m_new + s_new eps``, ``c' + 1/2 sum((q' eps + l') eps)``.

Compilation: ``@njit(cache=True)``, no ``fastmath`` (IEEE semantics); the cache is stamped with
every compiled source of the package (:mod:`imix_cli.core.numerics.numba_cache`). The compiled generation loop
plans its generations with :func:`mix_step`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from imix_cli.core.numerics import elementary as el
from imix_cli.core.numerics import linalg_kernels as lk

try:
    # The bounded integer draw of NumPy's Generator.shuffle (masked rejection on 32- or 64-bit
    # words). numba's own ``Generator.permutation`` uses it too, but through an N-d shuffle that
    # took ~5 s of a cold run's ~7 s compile of the ``exact`` entry point; :func:`_permutation` is
    # its 1-d loop. It is numba's internal API: should a numba release move it, the fallback
    # below is numba's permutation itself (the same draws, only slower to compile).
    from numba.np.random.random_methods import random_interval
except ImportError:  # pragma: no cover - exercised by tests/test_mixing.py with the import removed
    random_interval = None

__all__ = ["mix_diagonal", "mix_full_exact", "mix_step", "diagonal_log_norm", "fill_plain", "put_row"]

# As imix_cli.core.mixing: rule-2 draws per missing member before the rest is filled plainly.
_MAX_TRIALS_PER_MEMBER = 200
# As imix_cli.core.mixing._SCRATCH_ELEMENTS: Algorithm 2's block size is capped by it, and the block
# size decides how many fresh draws a step consumes, so it must be the same here.
_SCRATCH_ELEMENTS = 1 << 20


@njit(cache=True)
def _put(rows, i, row):
    """``rows[i] = row`` as a loop: numba's general slice assignment compiles for seconds."""
    for j in range(row.shape[0]):
        rows[i, j] = row[j]


if random_interval is not None:

    @njit(cache=True)
    def _permutation(rng, n):
        """``rng.permutation(n)``: the same array, the same draws (NumPy's Fisher-Yates, last index first)."""
        out = np.arange(n)
        bit_generator = rng.bit_generator
        for i in range(n - 1, 0, -1):
            j = np.intp(random_interval(bit_generator, i))
            if i != j:
                out[i], out[j] = out[j], out[i]
        return out

else:

    @njit(cache=True)
    def _permutation(rng, n):
        """``rng.permutation(n)`` (numba's own: see the import of ``random_interval``)."""
        return rng.permutation(n)


@njit(cache=True)
def _row_coefficients(mean_new, std_new, log_norm_new, mean_old, std_old, log_norm_old):
    """(q, l, c) of log(p_new/p_old)(x) = c - 1/2 sum((q y + l) y), y = x - mean_old."""
    d = mean_new.shape[0]
    q = np.empty(d)
    lin = np.empty(d)
    dot = 0.0
    for j in range(d):
        w_new = (1.0 / std_new[j]) ** 2
        w_old = (1.0 / std_old[j]) ** 2
        delta = mean_new[j] - mean_old[j]
        q[j] = w_new - w_old
        lin[j] = -2.0 * delta * w_new
        dot += delta * delta * w_new
    return q, lin, log_norm_new - log_norm_old - 0.5 * dot


@njit(cache=True)
def _noise_coefficients(mean_new, std_new, log_norm_new, mean_old, std_old, log_norm_old):
    """(q', l', c') of log(p_new/p_old)(m_new + s_new eps) = c' + 1/2 sum((q' eps + l') eps)."""
    d = mean_new.shape[0]
    q = np.empty(d)
    lin = np.empty(d)
    dot = 0.0
    for j in range(d):
        inv_old = 1.0 / std_old[j]
        a = (mean_new[j] - mean_old[j]) * inv_old
        b = std_new[j] * inv_old
        q[j] = -(1.0 - b * b)
        lin[j] = 2.0 * a * b
        dot += a * a
    return q, lin, log_norm_new - log_norm_old + 0.5 * dot


@njit(cache=True)
def _place_rule2_draw(out, source, index, size, draw, region, pools, pool_len, xs):
    """Member ``size`` of a multi-generation step from a rule-2 draw: swapped for an unused old member of the newest
    older generation ``region`` whose region holds the draw (-1: none), else the draw itself (fresh)."""
    if region > 0 and pool_len[region] > 0:
        pool_len[region] -= 1
        row = pools[region, pool_len[region]]
        _put(out, size, xs[region, row])
        source[size] = region + 1
        index[size] = row
    else:
        _put(out, size, draw)
        source[size] = 0
        index[size] = -1


@njit(cache=True)
def _row_log_ratio(x, shift, q, lin, c):
    # Four running sums: one sum's chain of dependent additions (no fastmath, so no reordering by
    # the compiler) would bound this loop by the adder's latency; four keep the adders busy.
    d = x.shape[0]
    a0 = a1 = a2 = a3 = 0.0
    j = 0
    while j + 4 <= d:
        y0 = x[j] - shift[j]
        y1 = x[j + 1] - shift[j + 1]
        y2 = x[j + 2] - shift[j + 2]
        y3 = x[j + 3] - shift[j + 3]
        a0 += (q[j] * y0 + lin[j]) * y0
        a1 += (q[j + 1] * y1 + lin[j + 1]) * y1
        a2 += (q[j + 2] * y2 + lin[j + 2]) * y2
        a3 += (q[j + 3] * y3 + lin[j + 3]) * y3
        j += 4
    while j < d:
        y = x[j] - shift[j]
        a0 += (q[j] * y + lin[j]) * y
        j += 1
    return c - 0.5 * ((a0 + a1) + (a2 + a3))


@njit(cache=True)
def _logs(a):
    """log of each entry (:func:`imix_cli.core.numerics.elementary.log`: the same bits on every CPU; np.log calls the C library)."""
    out = np.empty_like(a)
    for i in range(a.shape[0]):
        out[i] = el.log(a[i])
    return out


@njit(cache=True)
def _draw(rng, mean, std, q, lin, c, out):
    """One draw from N(mean, std^2) into ``out`` (NumPy's standard_normal stream); its noise-form log-ratio."""
    acc = 0.0
    for j in range(mean.shape[0]):
        e = rng.standard_normal()
        acc += (q[j] * e + lin[j]) * e
        out[j] = e * std[j] + mean[j]
    return c + 0.5 * acc


@njit(cache=True)
def _fill_plain(rng, mean, std, out, size, popsize):
    """``new_dist.sample(popsize - size)`` into the missing rows (the documented fallback)."""
    for i in range(size, popsize):
        for j in range(mean.shape[0]):
            out[i, j] = rng.standard_normal() * std[j] + mean[j]


@njit(cache=True)
def _refresh(rng, mean, std, out, source, index, popsize, min_fresh):
    """:func:`imix_cli.core.mixing._refresh`: ``min_fresh`` slots drawn at random, the member in each replaced by
    a fresh draw (the same draws, in the same order)."""
    if min_fresh <= 0:
        return
    slots = _permutation(rng, popsize)
    for s in range(min(min_fresh, popsize)):
        i = slots[s]
        for j in range(mean.shape[0]):
            out[i, j] = rng.standard_normal() * std[j] + mean[j]
        source[i] = 0
        index[i] = -1


@njit(cache=True)
def _sun2009(rng, new, archive, popsize, log_keep, alpha, out, source, index):
    """mixing._sun2009 (archive entry 0 only); returns (size, trials)."""
    mean, std, log_norm = new
    means, stds, log_norms, xs, _, counts = archive
    q, lin, c = _row_coefficients(mean, std, log_norm, means[0], stds[0], log_norms[0])
    nq, nl, nc = _noise_coefficients(mean, std, log_norm, means[0], stds[0], log_norms[0])
    n_old = counts[0]
    log_u = _logs(rng.random(n_old))
    size = 0
    for i in range(n_old):
        if log_u[i] < log_keep + _row_log_ratio(xs[0, i], means[0], q, lin, c):
            _put(out, size, xs[0, i])
            source[size] = 1
            index[size] = i
            size += 1
    max_trials = _MAX_TRIALS_PER_MEMBER * max(popsize - size, 1)
    trials = 0
    while size < popsize and trials < max_trials:
        n = popsize - size
        cand = np.empty((n, mean.shape[0]))
        ratio = np.empty(n)
        for i in range(n):
            ratio[i] = _draw(rng, mean, std, nq, nl, nc, cand[i])
        u = rng.random(n)
        for i in range(n):
            if size < popsize and u[i] < max(alpha, -el.expm1(-max(ratio[i], 0.0))):
                _put(out, size, cand[i])
                size += 1
        trials += n
    return size, n_old


@njit(cache=True)
def _paper(rng, new, archive, popsize, out, source, index):
    """mixing._alternate_rules on archive entry 0 + Algorithm 2's overfull drop; returns (size, steps)."""
    mean, std, log_norm = new
    means, stds, log_norms, xs, _, counts = archive
    d = mean.shape[0]
    q, lin, c = _row_coefficients(mean, std, log_norm, means[0], stds[0], log_norms[0])
    nq, nl, nc = _noise_coefficients(mean, std, log_norm, means[0], stds[0], log_norms[0])
    n_old = counts[0]
    order = _permutation(rng, n_old)
    log_u1 = _logs(rng.random(n_old))
    u2 = rng.random(n_old)
    missing = popsize
    max_block = max(1, min(n_old, missing, _SCRATCH_ELEMENTS // max(d, 1)))
    cand = np.empty((max_block, d))
    accept_old = np.zeros(max_block, np.bool_)
    accept_new = np.zeros(max_block, np.bool_)
    size = 0
    step = 0
    while step < n_old and missing > 0:
        stop = min(n_old, step + min(missing, max_block))
        block = stop - step
        for b in range(block):  # rule 1 on the block's old rows
            row = order[step + b]
            accept_old[b] = log_u1[step + b] < _row_log_ratio(xs[0, row], means[0], q, lin, c)
        for b in range(block):  # the block's fresh draws, all drawn (as numpy draws the block at once)
            r = _draw(rng, mean, std, nq, nl, nc, cand[b])
            accept_new[b] = u2[step + b] < -el.expm1(-max(r, 0.0))
        filled = 0
        taken = block
        for b in range(block):  # the step at which the generation fills
            filled += np.int64(accept_old[b]) + np.int64(accept_new[b])
            if filled >= missing:
                taken = b + 1
                break
        for b in range(taken):  # as Builder.add: the block's old members first, then its fresh ones
            if accept_old[b]:
                row = order[step + b]
                _put(out, size, xs[0, row])
                source[size] = 1
                index[size] = row
                size += 1
        for b in range(taken):
            if accept_new[b]:
                _put(out, size, cand[b])
                source[size] = 0
                index[size] = -1
                size += 1
        step += taken
        missing = popsize - size
    if size > popsize:  # both rules accepted on the last step: drop one member at random
        victim = rng.integers(0, size)
        for i in range(victim, size - 1):
            _put(out, i, out[i + 1])
            source[i] = source[i + 1]
            index[i] = index[i + 1]
        size -= 1
    return size, step


@njit(cache=True)
def _exact(rng, new, archive, popsize, out, source, index):
    """mixing._multi_generation; returns (size, rule-2 draws)."""
    mean, std, log_norm = new
    means, stds, log_norms, xs, heights, counts = archive
    n_entries, d = means.shape
    q, lin, c = _row_coefficients(mean, std, log_norm, means[0], stds[0], log_norms[0])
    size = 0
    for i in range(counts[0]):  # the previous generation: every member below the new graph is kept
        if heights[0, i] < _row_log_ratio(xs[0, i], means[0], q, lin, c):
            _put(out, size, xs[0, i])
            source[size] = 1
            index[size] = i
            size += 1
    if size == popsize:
        return size, 0

    # Older generations' substitutes: rows under no newer archived graph and under the new one.
    pools = np.empty((n_entries, xs.shape[1]), np.int64)
    pool_len = np.zeros(n_entries, np.int64)
    new_q = np.empty((n_entries, d))
    new_l = np.empty((n_entries, d))
    new_c = np.empty(n_entries)
    for k in range(1, n_entries):
        qk, lk, new_c[k] = _row_coefficients(mean, std, log_norm, means[k], stds[k], log_norms[k])
        _put(new_q, k, qk)
        _put(new_l, k, lk)
        open_rows = np.ones(counts[k], np.bool_)
        for j in range(k):
            qj, lj, cj = _row_coefficients(means[j], stds[j], log_norms[j], means[k], stds[k], log_norms[k])
            for i in range(counts[k]):
                if open_rows[i] and not (heights[k, i] >= _row_log_ratio(xs[k, i], means[k], qj, lj, cj)):
                    open_rows[i] = False
        below = np.empty(counts[k], np.int64)
        n_below = 0
        for i in range(counts[k]):
            if open_rows[i] and heights[k, i] < _row_log_ratio(xs[k, i], means[k], new_q[k], new_l[k], new_c[k]):
                below[n_below] = i
                n_below += 1
        order = _permutation(rng, n_below)
        for m in range(n_below):
            pools[k, m] = below[order[m]]
        pool_len[k] = n_below

    nq, nl, nc = _noise_coefficients(mean, std, log_norm, means[0], stds[0], log_norms[0])
    max_draws = _MAX_TRIALS_PER_MEMBER * (popsize - size)
    draws = 0
    while size < popsize and draws < max_draws:
        n = popsize - size
        cand = np.empty((n, d))
        ratio = np.empty(n)
        for i in range(n):
            ratio[i] = _draw(rng, mean, std, nq, nl, nc, cand[i])
        log_u = _logs(rng.random(n))
        draws += n
        for i in range(n):
            if not (log_u[i] >= -ratio[i]) or size >= popsize:  # rule 2: above the previous graph
                continue
            region = -1  # the newest older generation whose region holds the draw
            for k in range(1, n_entries):
                if log_u[i] < -_row_log_ratio(cand[i], means[k], new_q[k], new_l[k], new_c[k]):
                    region = k
                    break
            _place_rule2_draw(out, source, index, size, cand[i], region, pools, pool_len, xs)
            size += 1
    return size, draws


@njit(cache=True)
def _output(popsize, d):
    # one spare row: Algorithm 2's last step may accept two
    return np.empty((popsize + 1, d)), np.zeros(popsize + 1, np.int64), np.full(popsize + 1, -1, np.int64)


# One compiled entry point per rule, so that a run compiles (once, on first use) only its own rule. Each takes
# ``new`` = (mean, std, log_norm) of the new distribution and ``archive`` = (means, stds, log_norms, xs, heights,
# counts) of the archived generations it may reuse, newest first (tuples: numba types each field).
@njit(cache=True)
def _mix_paper(rng, new, archive, popsize, log_keep, alpha, min_fresh):
    mean, std = new[0], new[1]
    out, source, index = _output(popsize, mean.shape[0])
    size, trials = _paper(rng, new, archive, popsize, out, source, index)
    _fill_plain(rng, mean, std, out, size, popsize)
    _refresh(rng, mean, std, out, source, index, popsize, min_fresh)
    return out[:popsize], source[:popsize].copy(), index[:popsize].copy(), trials


@njit(cache=True)
def _mix_sun2009(rng, new, archive, popsize, log_keep, alpha, min_fresh):
    mean, std = new[0], new[1]
    out, source, index = _output(popsize, mean.shape[0])
    size, trials = _sun2009(rng, new, archive, popsize, log_keep, alpha, out, source, index)
    _fill_plain(rng, mean, std, out, size, popsize)
    _refresh(rng, mean, std, out, source, index, popsize, min_fresh)
    return out[:popsize], source[:popsize].copy(), index[:popsize].copy(), trials


@njit(cache=True)
def _mix_exact(rng, new, archive, popsize, log_keep, alpha, min_fresh):
    mean, std = new[0], new[1]
    out, source, index = _output(popsize, mean.shape[0])
    size, trials = _exact(rng, new, archive, popsize, out, source, index)
    _fill_plain(rng, mean, std, out, size, popsize)
    _refresh(rng, mean, std, out, source, index, popsize, min_fresh)
    return out[:popsize], source[:popsize].copy(), index[:popsize].copy(), trials


@njit(cache=True)
def _full_draws(rng, low, mean, n):
    """``FullGaussian.sample(n, rng)``: NumPy's standard_normal stream row by row, each row mean + L eps (L eps by
    :func:`imix_cli.core.numerics.linalg_kernels.lower_times_rows`'s kernel, k ascending)."""
    d = mean.shape[0]
    eps = np.empty((n, d))
    for r in range(n):
        for j in range(d):
            eps[r, j] = rng.standard_normal()
    out = lk._lower_times_rows(low, eps)
    for r in range(n):
        for i in range(d):
            out[r, i] = mean[i] + out[r, i]
    return out


@njit(cache=True)
def _exact_full(rng, lows, means, log_norms, xs, heights, table, known, counts, popsize, min_fresh):
    """The ``"exact"`` step between FullGaussians: :func:`imix_cli.core.mixing._multi_generation`, then the plain
    fill and :func:`imix_cli.core.mixing._refresh`, with the same numbers bit for bit (the same draws in the same
    order, and the log-densities of :func:`imix_cli.core.numerics.linalg_kernels.gaussian_log_probs`, which
    :meth:`FullGaussian.log_prob` computes too). ``lows``/``means``/``log_norms``: index 0 the new distribution, k
    archive entry k - 1; ``table[k, j, i]``: log p_j at ``xs[k, i]`` for j <= k + 1, given by the caller (who keeps
    them between generations) where ``known[k]``, else computed here. Returns ``(samples, source, index, rule-2 draws)``."""
    n_entries, rows, d = xs.shape
    for k in range(n_entries):
        if not known[k]:  # the distributions read below only: the new one and those of entries 0 .. k
            table[k, : k + 2] = lk.gaussian_log_probs_kernel(lows[: k + 2], means[: k + 2], log_norms[: k + 2], xs[k])
    out = np.empty((popsize, d))
    source = np.zeros(popsize, np.int64)
    index = np.full(popsize, -1, np.int64)
    size = 0
    for i in range(counts[0]):  # the previous generation: every member below the new graph is kept
        if heights[0, i] < table[0, 0, i] - table[0, 1, i]:
            _put(out, size, xs[0, i])
            source[size] = 1
            index[size] = i
            size += 1
    draws = 0
    if size < popsize:
        # Older generations' substitutes: rows under no newer archived graph and under the new one.
        pools = np.empty((n_entries, rows), np.int64)
        pool_len = np.zeros(n_entries, np.int64)
        for k in range(1, n_entries):
            below = np.empty(counts[k], np.int64)
            n_below = 0
            for i in range(counts[k]):
                open_row = True
                for j in range(k):
                    if not (heights[k, i] >= table[k, j + 1, i] - table[k, k + 1, i]):
                        open_row = False
                        break
                if open_row and heights[k, i] < table[k, 0, i] - table[k, k + 1, i]:
                    below[n_below] = i
                    n_below += 1
            order = _permutation(rng, n_below)
            for m in range(n_below):
                pools[k, m] = below[order[m]]
            pool_len[k] = n_below
        max_draws = _MAX_TRIALS_PER_MEMBER * (popsize - size)
        while size < popsize and draws < max_draws:
            n = popsize - size
            cand = _full_draws(rng, lows[0], means[0], n)
            lp = lk.gaussian_log_probs_kernel(lows, means, log_norms, cand)
            log_u = _logs(rng.random(n))
            draws += n
            for i in range(n):
                if not (log_u[i] >= -(lp[0, i] - lp[1, i])) or size >= popsize:  # rule 2: above the previous graph
                    continue
                region = -1  # the newest older generation whose region holds the draw
                for k in range(1, n_entries):
                    if log_u[i] < -(lp[0, i] - lp[k + 1, i]):
                        region = k
                        break
                _place_rule2_draw(out, source, index, size, cand[i], region, pools, pool_len, xs)
                size += 1
    if size < popsize:  # the documented fallback: plain draws
        plain = _full_draws(rng, lows[0], means[0], popsize - size)
        for m in range(popsize - size):
            _put(out, size + m, plain[m])
    if min_fresh > 0:  # the minimal refresh: slots drawn at random, each member replaced by a fresh draw
        slots = _permutation(rng, popsize)[:min_fresh]
        fresh = _full_draws(rng, lows[0], means[0], slots.shape[0])
        for m in range(slots.shape[0]):
            _put(out, slots[m], fresh[m])
            source[slots[m]] = 0
            index[slots[m]] = -1
    return out, source, index, draws


def mix_full_exact(new_dist, dists, samples, heights, table, popsize: int, rng: np.random.Generator, min_fresh: int = 0):
    """One ``"exact"`` mixing step between float64 FullGaussians (:func:`_exact_full`), as :func:`imix_cli.core.mixing.mix`
    gives it: ``dists``/``samples``/``heights`` the archive entries used (newest first, n_k <= popsize rows each),
    ``table`` their log-densities (:func:`_exact_full`), or None: computed in the compiled step, cheaper at small d than
    keeping them. Returns ``(samples, source, index, trials)``."""
    rows = max(x.shape[0] for x in samples)
    every = (new_dist, *dists)
    known = np.ones(len(samples), np.bool_) if table is not None else np.zeros(len(samples), np.bool_)  # np.full's, faster
    if table is None:
        table = np.empty((len(samples), len(every), rows))
    return _exact_full(
        rng, np.array([g.chol for g in every]), np.array([g.mean for g in every]), np.array([g.log_norm for g in every]),
        _stacked(samples, rows), _stacked(heights, rows), table, known, np.array([x.shape[0] for x in samples], dtype=np.int64), popsize, int(min_fresh),
    )  # fmt: skip


#: Each compiled step by its number, which its :class:`imix_cli.core.mixing.Variant` carries (``kernel``); the
#: compiled generation loop (:mod:`imix_cli.running.loop.compiled_loop`) branches on the same numbers.
KERNELS = {1: _mix_paper, 2: _mix_sun2009, 3: _mix_exact}


#: For other compiled code (the compiled generation loop): the kernels themselves.
put_row = _put
fill_plain = _fill_plain
full_draws, exact_full = _full_draws, _exact_full


@njit(cache=True)
def diagonal_log_norm(std):
    """:attr:`imix_cli.core.distributions.DiagonalGaussian.log_norm` of standard deviations ``std`` compiled:
    -d/2 log(2 pi) - np.sum(log std), numpy's summation order (:func:`imix_cli.core.numerics.linalg_kernels.numpy_sum`)."""
    d = std.shape[0]
    logs = np.empty(d)
    for j in range(d):
        logs[j] = el.log(std[j])
    return -0.5 * d * el.LOG_2PI - lk.numpy_sum(logs)


@njit(cache=True)
def mix_step(kernel, rng, new, archive, heights_drawn, used, rule):
    """One generation of ``popsize`` members of N(mean, std^2) for compiled code, as :func:`imix_cli.core.mixing.mix`
    gives it: plain draws when ``kernel`` is 0 (no mixing) or ``used`` (the archived generations it may
    reuse, newest first, the first ``used`` rows of ``archive`` = (means, stds, log_norms, xs, heights)) is 0,
    else the variant's step (:data:`KERNELS`). ``new`` = (mean, std, log_norm); ``rule`` = (popsize, log_keep,
    alpha, min_fresh). ``"exact"`` (kernel 3) draws each generation's log-heights once, the first
    time it is mixed from (``heights_drawn``), as :func:`imix_cli.core.mixing._heights` does.
    Returns ``(samples, source, index, trials)``."""
    mean, std = new[0], new[1]
    means, stds, log_norms, xs, heights = archive
    popsize, log_keep, alpha, min_fresh = rule
    d = mean.shape[0]
    if kernel == 0 or used == 0:
        x = np.empty((popsize, d))
        _fill_plain(rng, mean, std, x, 0, popsize)
        return x, np.zeros(popsize, dtype=np.int64), np.full(popsize, -1, dtype=np.int64), 0
    if kernel == 3:
        for k in range(used):
            if not heights_drawn[k]:
                for i in range(popsize):
                    r = rng.random()
                    heights[k, i] = el.log(r) if r > 0.0 else -np.inf
                heights_drawn[k] = True
    used_archive = (means[:used], stds[:used], log_norms[:used], xs[:used], heights[:used], np.full(used, popsize, dtype=np.int64))
    if kernel == 1:
        return _mix_paper(rng, new, used_archive, popsize, log_keep, alpha, min_fresh)
    if kernel == 2:
        return _mix_sun2009(rng, new, used_archive, popsize, log_keep, alpha, min_fresh)
    return _mix_exact(rng, new, used_archive, popsize, log_keep, alpha, min_fresh)


def _stacked(arrays, rows: int) -> np.ndarray:
    """The arrays (each ``rows`` long or shorter) as one array; shorter ones padded with zeros, never read."""
    if all(a.shape[0] == rows for a in arrays):
        return np.array(arrays)  # np.stack's result, in fewer Python steps
    out = np.zeros((len(arrays), rows, *arrays[0].shape[1:]))
    for k, a in enumerate(arrays):
        out[k, : a.shape[0]] = a
    return out


def mix_diagonal(new_dist, dists, samples, heights, popsize: int, rng: np.random.Generator, kernel: int, alpha: float, min_fresh: int = 0):
    """One mixing step, as :func:`imix_cli.core.mixing.mix` with float64 DiagonalGaussians; ``kernel``: the
    variant's step (:data:`KERNELS`, the variant's ``kernel``).

    ``dists``/``samples``/``heights``: the archive entries used (newest first), their (n_k, d)
    samples with n_k <= popsize, and (``"exact"`` only) their log-heights. Returns
    ``(samples, source, index, trials)``.
    """
    rows = max(x.shape[0] for x in samples)
    xs = _stacked(samples, rows)
    h = _stacked(heights, rows) if heights is not None else np.zeros((len(samples), rows))
    counts = np.array([x.shape[0] for x in samples], dtype=np.int64)
    means = np.stack([dist.mean for dist in dists])
    stds = np.stack([dist.std for dist in dists])
    log_norms = np.array([dist.log_norm for dist in dists])
    log_keep = el.math_log1p(-alpha)  # -inf for alpha = 1
    new = (new_dist.mean, new_dist.std, float(new_dist.log_norm))
    return KERNELS[kernel](rng, new, (means, stds, log_norms, xs, h, counts), popsize, log_keep, float(alpha), int(min_fresh))
