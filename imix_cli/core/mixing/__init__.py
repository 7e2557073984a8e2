"""Importance mixing: build a new ES generation that reuses already-evaluated samples.

Why: an ES that moves its search distribution a little draws a generation much like the last one, whose returns
are known. :func:`mix` keeps the earlier members the new distribution would have drawn anyway and draws fresh only
the rest, so that the generation is still distributed as the new distribution while most of it costs no episode.

How, in brief: rule 1 keeps an old member with probability min(1, p_new/p_old), rule 2 keeps a fresh draw with
probability max(0, 1 - p_old/p_new); each variant (:data:`VARIANT_SPECS`) is one way of applying them to the
archive; ``min_fresh`` slots, chosen at random, are then drawn fresh, so that a distribution that stops moving
cannot repeat its generation. All in log space, from log-ratios.

The argument, one section per question, is docs/research/mixing.md ("How importance mixing builds a generation"):
"Why it works" (the two rules), "Variants" (``paper``, ``sun2009``, ``exact``, ``conditional``, ``eim_paper``),
"Multi-generation mixing" (why Algorithm 3 drifts and what ``exact`` does instead), "Reuse inside the loop" (why
``conditional``), "A minimal refresh" (``min_fresh``) and "In log space". The defaults of every setting:
:data:`MIXING_DEFAULTS`.

Archive entries are ``(dist, samples)`` pairs or :class:`Generation` objects returned by an earlier ``mix``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from imix_cli.core import numerics as xp
from imix_cli.core.distributions import AffinePushforward, DiagonalGaussian, DiagonalLogRatio, FullGaussian, FullGaussianStack

__all__ = [
    "DiagonalGaussian", "FullGaussian", "Generation", "MIXING_DEFAULTS", "MixingDefaults", "Variant", "VARIANT_SPECS", "VARIANTS",
    "config_variants", "mix", "variant_spec",
]  # fmt: skip

# Sun et al.'s rule-2 loop accepts a fresh draw with probability ~(1 - lambda); when the two
# distributions nearly coincide that can take very many draws. After this many candidate
# draws per missing member, the rest is filled with plain draws (documented bias, never hit
# in practice: it needs lambda > 1 - 1/200).
_SUN2009_MAX_TRIALS_PER_MEMBER = 200
# At large d, rule-2 candidates are drawn in blocks of at most this many numbers (one row at d = 10^6).
_SCRATCH_ELEMENTS = 1 << 20
# Up to this many numbers in an old generation (rows x d), rule 1 is decided for all its rows at once.
_UPFRONT_ELEMENTS = 1 << 16
# Up to this many archived numbers, float64 diagonal steps are compiled (mixing.kernels; it copies
# the archive into one array, 8 MB at most); above, numpy's vectorised step costs little more.
COMPILED_MAX_ELEMENTS = 1 << 20


@dataclass
class Generation:
    """A new generation built by :func:`mix`.

    Attributes
    ----------
    samples : (popsize, d) array
        The members.
    source : (popsize,) int array
        0 for a fresh member (must be evaluated), k >= 1 for a member reused from ``archive[k-1]``.
    index : (popsize,) int array
        Row of that archive entry's samples, -1 for fresh members.
    dist :
        The distribution the generation is distributed as (the ``new_dist`` given to ``mix``).
    trials : int
        Number of rule-1/rule-2 steps taken (old samples tried).
    log_u : (popsize,) float array or None
        Each member's *height* under the graph of ``dist``, as log(y / p_dist(x)), a number in
        (-inf, 0] (``"exact"`` only; see "Multi-generation mixing"). None until the generation
        is first mixed from; drawn then and kept, because the older-generation steps of later
        mixes must see the heights that decided which members went on.
    mean_weights : (popsize,) float array or None
        The weight of each member in the move of the mean the ES made from this generation
        (:attr:`EvolutionStrategy.mean_weights <imix_cli.core.algorithms.base.EvolutionStrategy.mean_weights>`),
        set once the generation is told (:func:`imix_cli.core.mixing.generation.finish_generation`); what
        ``"conditional"`` conditions on. None: the members are independent of the path.
    """

    samples: np.ndarray
    source: np.ndarray
    index: np.ndarray
    dist: object
    trials: int = 0
    log_u: np.ndarray | None = None
    mean_weights: np.ndarray | None = None

    @property
    def fresh(self) -> np.ndarray:
        """Boolean mask of members that must be evaluated."""
        return self.source == 0

    @property
    def reused(self) -> int:
        return int(np.count_nonzero(self.source > 0))

    @property
    def reused_from_previous(self) -> int:
        """Members reused from the previous generation (the paper's "from IM")."""
        return int(np.count_nonzero(self.source == 1))

    @property
    def reused_from_older(self) -> int:
        """Members reused from generations before the previous one (the paper's "from EIM")."""
        return int(np.count_nonzero(self.source > 1))

    def __iter__(self):  # a Generation is an archive entry: (dist, samples)
        return iter((self.dist, self.samples))


def _unpack_entry(entry):
    if type(entry) is Generation:  # its fields (unpacking it goes through __iter__)
        return entry.dist, np.asarray(entry.samples)
    dist, samples = entry
    return dist, np.asarray(samples)


def _row_keys(samples: np.ndarray) -> np.ndarray:
    """One hashable key per row: the bytes of its first few coordinates (a continuous random
    sample is identified by them; equality is then confirmed on the whole row)."""
    head = np.ascontiguousarray(samples[:, :8])
    return head.view(np.dtype((np.void, head.dtype.itemsize * head.shape[1]))).ravel()


#: From this dimension on, the compiled ``"exact"`` step between FullGaussians is given the archived log-densities kept
#: between steps (:func:`_cached_log_probs`); below, it computes them itself: at d = 10 the (K + 1) K N triangular
#: solves cost less than looking the kept ones up in Python (pycma's adapter, issue 45).
_KEEP_LOG_PROBS_FROM_DIM = 32
#: Arrays whose log-densities one distribution keeps (:func:`_cached_log_probs`): the archived generations.
_LOG_PROB_CACHE = 8


def _cached_log_probs(dist, arrays) -> list:
    """``[dist.log_prob(x) for x in arrays]`` (a FullGaussian), each kept on ``dist`` for the next call with the same
    array; those not kept yet are computed in one call, their rows stacked.

    Why: with full covariances (pycma, imix's CMA-ES) a log-density is a triangular solve per row, and a step of
    ``"exact"`` mixing asks for the same archived rows under the same archived distributions again and again
    (every pair of archived generations, every generation): at d = 10 that was most of the mixing time. What is
    new in a step -- the archived rows under the new distribution -- is one call, not one per generation.
    Rows are independent in :meth:`FullGaussian.log_prob`, so ``log_prob(x)[rows]`` is ``log_prob(x[rows])`` bit
    for bit, whatever rows are stacked with it. The array itself is kept beside its values, so an id is never
    mistaken for another array's.
    """
    cache = dist.__dict__.setdefault("_log_prob_cache", {})
    out, missing = [], []
    for x in arrays:
        hit = cache.pop(id(x), None)
        if hit is not None and hit[0] is x:
            cache[id(x)] = hit  # least recently used last: the archived arrays, asked for every generation, stay
            out.append(hit[1])
        else:
            out.append(None)
            missing.append(len(out) - 1)
    if missing:
        stacked = arrays[missing[0]] if len(missing) == 1 else np.concatenate([arrays[i] for i in missing])
        values = dist.log_prob(stacked)
        start = 0
        for i in missing:
            x = arrays[i]
            out[i] = values[start : start + x.shape[0]]
            start += x.shape[0]
            if len(cache) >= _LOG_PROB_CACHE:
                del cache[next(iter(cache))]
            cache[id(x)] = (x, out[i])
    return out


class _GenericLogRatio:
    """log(p_new / p_old) for any distributions with ``sample`` and ``log_prob``."""

    def __init__(self, new, old):
        self.new, self.old = new, old
        self.full = type(new) is FullGaussian and type(old) is FullGaussian

    def of_rows(self, x, rows):
        if self.full:  # rows independent: cached (_cached_log_probs)
            return _cached_log_probs(self.new, [x])[0][rows] - _cached_log_probs(self.old, [x])[0][rows]
        block = x[rows]
        return self.new.log_prob(block) - self.old.log_prob(block)

    def sample(self, n, rng, out=None):
        x = self.new.sample(n, rng)
        if self.full:  # both densities in one call; draws are not kept (never asked for again)
            new, old = FullGaussianStack((self.new, self.old)).log_probs(x)
            return x, new - old
        return x, self.new.log_prob(x) - self.old.log_prob(x)


def _archived_log_probs(dists, xs) -> list:
    """``table[k][j]``: log p_j at the rows of archived array ``xs[k]``, for j <= k + 1 -- what a step of ``"exact"``
    asks for (``dists[0]`` the new distribution, ``dists[k]`` archive entry k - 1; FullGaussians), kept on each
    distribution between steps (:func:`_cached_log_probs`)."""
    per_dist = [_cached_log_probs(d, xs[max(0, j - 1) :]) for j, d in enumerate(dists)]
    return [[per_dist[j][k - max(0, j - 1)] for j in range(k + 2)] for k in range(len(xs))]


class _StepRatios:
    """The log-ratios of one ``"exact"`` step between its distributions -- ``dists[0]`` the new one, ``dists[k]``
    archive entry k - 1 -- at the archived samples ``xs`` and at rule-2 draws.

    Between FullGaussians, the log-density of archived array k under every distribution that step asks for (the
    new one and those of entries 0..k) is looked up once per step (:func:`_cached_log_probs`: kept on each
    distribution, only the new distribution's computed, in one call); a batch of rule-2 draws is taken under every
    distribution of the step in one compiled call (:class:`FullGaussianStack`: the region test needs the older ones
    too), and not kept. Otherwise the ratio objects of :func:`_log_ratio`. The same numbers either way, bit for bit.
    """

    def __init__(self, dists, xs):
        self.dists, self.xs = list(dists), xs
        self.stack = None
        if all(type(d) is FullGaussian for d in self.dists):
            self.stack = FullGaussianStack(self.dists)
            self.table = _archived_log_probs(self.dists, xs)

    def archived(self, a: int, b: int, k: int, rows: np.ndarray) -> np.ndarray:
        """log(p_a / p_b) at the rows ``rows`` of archived array ``k`` (a, b <= k + 1)."""
        if self.stack is None:
            return _log_ratio(self.dists[a], self.dists[b]).of_rows(self.xs[k], rows)
        return self.table[k][a][rows] - self.table[k][b][rows]

    def draw(self, n: int, rng: np.random.Generator):
        """``n`` draws from the new distribution, their log(p_new / p_1), and ``to(k, rows)``: log(p_new / p_k) at
        the draws ``rows``."""
        if self.stack is None:
            x, r_1 = _log_ratio(self.dists[0], self.dists[1]).sample(n, rng)
            return x, r_1, lambda k, rows: _log_ratio(self.dists[0], self.dists[k]).of_rows(x, rows)
        x = self.dists[0].sample(n, rng)
        lp = self.stack.log_probs(x)
        return x, lp[0] - lp[1], lambda k, rows: lp[0][rows] - lp[k][rows]


def _log_ratio(new_dist, old_dist):
    """The ratio object of rules 1 and 2: fast and float32-safe between two DiagonalGaussians."""
    if type(new_dist) is type(old_dist) is DiagonalGaussian:
        return new_dist.log_ratio_to(old_dist)
    return _GenericLogRatio(new_dist, old_dist)


class _Builder:
    """Accumulates the members of the new generation in a preallocated array.

    Rows are copied once, when accepted, straight into their final place: at d = 10^6 a
    second copy of the generation would cost a sizeable fraction of drawing it.
    """

    def __init__(self, popsize: int, dim: int, dtype):
        self.popsize = popsize
        self.samples = np.empty((popsize + 1, dim), dtype=dtype)  # one spare row: a last step may accept two
        self.source = np.zeros(popsize + 1, dtype=np.int64)
        self.index = np.full(popsize + 1, -1, dtype=np.int64)
        self.size = 0

    @property
    def missing(self) -> int:
        return self.popsize - self.size

    def not_yet_taken(self, samples: np.ndarray) -> np.ndarray:
        """Mask of the rows of ``samples`` not already reused into the new generation.

        An archive holds the same point in several entries when it was itself reused; EIM
        must take such a point at most once.
        """
        reused = np.flatnonzero(self.source[: self.size] > 0)
        free = np.ones(samples.shape[0], dtype=bool)
        if reused.size == 0:
            return free
        # Rows whose key is a taken row's key are candidates. Each is paired with the (first)
        # taken row of its key and the whole rows are compared at once; only a candidate whose
        # pair differs (a key collision: in practice never) is compared with every taken row.
        first_with_key = {}
        for m, key in zip(reused.tolist(), _row_keys(self.samples[reused]).tolist()):
            first_with_key.setdefault(key, m)
        keys = _row_keys(samples).tolist()
        pairs = [(i, first_with_key[key]) for i, key in enumerate(keys) if key in first_with_key]
        if not pairs:
            return free
        candidates, partners = np.array(pairs, dtype=np.int64).T
        same = self._rows_equal(samples, candidates, partners)
        free[candidates[same]] = False
        for i in candidates[~same]:
            free[i] = not any(np.array_equal(samples[i], self.samples[m]) for m in reused)
        return free

    def _rows_equal(self, samples: np.ndarray, rows: np.ndarray, members: np.ndarray) -> np.ndarray:
        """``np.array_equal(samples[rows[k]], self.samples[members[k]])`` for each k."""
        dim = samples.shape[1]
        if rows.size * dim <= _SCRATCH_ELEMENTS:
            return np.all(samples[rows] == self.samples[members], axis=1)
        return np.array([np.array_equal(samples[r], self.samples[m]) for r, m in zip(rows, members)], dtype=bool)

    def add(self, rows: np.ndarray, source=0, index=-1) -> None:
        """Append the rows (2-D); ``source``/``index``: their archive entry and row (scalars or arrays)."""
        n = rows.shape[0]
        members = slice(self.size, self.size + n)
        self.samples[members] = rows
        self.source[members] = source
        self.index[members] = index
        self.size += n

    def drop_random(self, rng: np.random.Generator) -> None:
        """Remove one member chosen uniformly at random (Algorithm 2, overfull last step)."""
        victim = int(rng.integers(self.size))
        last = self.size - 1
        for arr in (self.samples, self.source, self.index):
            arr[victim:last] = arr[victim + 1 : last + 1]
        self.size -= 1

    def finish(self, new_dist, rng, trials) -> Generation:
        if self.missing > 0:  # fill with plain draws from the new distribution, all accepted
            self.samples[self.size : self.popsize] = new_dist.sample(self.missing, rng)
            self.size = self.popsize
        n = self.popsize
        return Generation(self.samples[:n], self.source[:n].copy(), self.index[:n].copy(), new_dist, trials)


def _log_uniform(rng: np.random.Generator, n: int) -> np.ndarray:
    return xp.log(rng.random(n))  # log(0) = -inf is a valid, always-accepting draw; libm's log, as on every CPU


def _alternate_rules(builder: _Builder, new_dist, old_dist, old_samples, entry_number, rng) -> int:
    """Algorithm 2's loop over one old generation: at step i, rule 1 on old sample i, then rule 2
    on a fresh draw; stop as soon as the generation is full (it may then hold one member too many).

    The steps are evaluated in vectorised blocks: a block's acceptances are computed at once and
    the block is cut at the step where the generation fills, exactly as the step-by-step loop
    would. Returns the number of steps taken.
    """
    n_old, dim = old_samples.shape
    order = rng.permutation(n_old)  # "taken uniformly from g_old"
    log_u1 = _log_uniform(rng, n_old)
    u2 = rng.random(n_old)
    eligible = builder.not_yet_taken(old_samples)
    log_ratio = _log_ratio(new_dist, old_dist)
    missing = builder.missing
    # About one member is accepted per step, so a block spans the missing count; at large d it
    # is also capped to a few rows, whose fresh draws go to one reused scratch buffer.
    max_block = max(1, min(n_old, missing, _SCRATCH_ELEMENTS // max(dim, 1)))
    scratch = np.empty((max_block, dim), dtype=builder.samples.dtype)
    # Rule 1 at step i only involves old sample order[i] and its own uniform. Between diagonal
    # Gaussians a row's log-ratio is a per-row sum, the same number whichever rows it is computed
    # with; so at small d, rule 1 is decided for every step at once (one kernel call instead of
    # one per block; at large d only the rows actually visited are worth computing).
    upfront = isinstance(log_ratio, DiagonalLogRatio) and n_old * dim <= _UPFRONT_ELEMENTS
    if upfront:
        accept_old_all = eligible[order] & (log_u1 < log_ratio.of_rows(old_samples, order))  # rule 1
    step = 0
    while step < n_old and missing > 0:
        stop = min(n_old, step + min(missing, max_block))
        size = stop - step
        rows = order[step:stop]
        if upfront:
            accept_old = accept_old_all[step:stop]
        else:
            accept_old = eligible[rows] & (log_u1[step:stop] < log_ratio.of_rows(old_samples, rows))  # rule 1
        candidates, cand_log_ratio = log_ratio.sample(size, rng, out=scratch[:size])
        accept_new = u2[step:stop] < -xp.expm1(-np.maximum(cand_log_ratio, 0.0))  # rule 2: 1 - p_old/p_new
        filled = np.cumsum(accept_old.astype(np.int64) + accept_new)
        taken = min(size, int(np.searchsorted(filled, missing)) + 1)  # steps until full
        kept_old = rows[:taken][accept_old[:taken]]
        builder.add(old_samples[kept_old], entry_number, kept_old)
        builder.add(candidates[:taken][accept_new[:taken]])
        step += taken
        missing = builder.missing
    return step


def _sun2009(builder: _Builder, new_dist, old_dist, old_samples, alpha, rng) -> int:
    """Sun et al. (2009): rule 1 over the whole previous generation, then rule 2 until full."""
    n_old = old_samples.shape[0]
    log_ratio = _log_ratio(new_dist, old_dist)
    with np.errstate(divide="ignore"):
        log_keep = xp.log1p(-alpha)
    accepted = np.flatnonzero(_log_uniform(rng, n_old) < log_keep + log_ratio.of_rows(old_samples, np.arange(n_old)))
    if accepted.size > builder.popsize:  # only possible if the old generation was larger
        accepted = np.sort(rng.choice(accepted, builder.popsize, replace=False))
    builder.add(old_samples[accepted], 1, accepted)
    max_trials = _SUN2009_MAX_TRIALS_PER_MEMBER * max(builder.missing, 1)
    trials = 0
    while builder.missing > 0 and trials < max_trials:
        n = builder.missing
        candidates, cand_log_ratio = log_ratio.sample(n, rng)
        accept_prob = np.maximum(alpha, -xp.expm1(-np.maximum(cand_log_ratio, 0.0)))
        accept_new = np.flatnonzero(rng.random(n) < accept_prob)[: builder.missing]
        builder.add(candidates[accept_new])
        trials += n
    return n_old


def _heights(entry, rng) -> np.ndarray:
    """An archive entry's persistent log-heights, drawn once (and kept on a Generation) if it has none.

    A plain ``(dist, samples)`` pair cannot keep them: each call then treats it as a fresh,
    independent sample of its ``dist`` (which is what such a pair usually is).
    """
    log_u = getattr(entry, "log_u", None)
    if log_u is None:
        log_u = _log_uniform(rng, _unpack_entry(entry)[1].shape[0])
        if isinstance(entry, Generation):
            entry.log_u = log_u
    return log_u


def _multi_generation(builder: _Builder, new_dist, archive, depth: int, rng) -> int:
    """The ``"exact"`` rule: Sun et al.'s step from the previous generation, then the leftover filled by
    rule 2, with rule-2 draws that land in an older generation's exclusive region swapped for an
    unused old member of the same region (module docstring, "Multi-generation mixing").
    Returns the number of rule-2 candidates drawn.
    """
    entries = list(archive[:depth])
    dists = [_unpack_entry(e)[0] for e in entries]
    xs = [_unpack_entry(e)[1] for e in entries]
    heights = [_heights(e, rng) for e in entries]
    ratios = _StepRatios([new_dist, *dists], xs)  # log(p_a / p_b): 0 the new distribution, k >= 1 archive entry k - 1

    # The previous generation: every member below the new graph is kept (count ~ Binomial(N, lambda)).
    r_1 = ratios.archived(0, 1, 0, np.arange(xs[0].shape[0]))
    kept = np.flatnonzero(heights[0] < r_1)
    if kept.size > builder.popsize:  # only possible if the old generation was larger
        kept = np.sort(rng.choice(kept, builder.popsize, replace=False))
    builder.add(xs[0][kept], 1, kept)
    if builder.missing == 0:
        return 0

    # Older generations: the members that no newer archived generation's region covers, and that
    # lie below the new graph, are the substitutes (in a random order) for rule-2 draws of their region.
    pools = []
    for k in range(1, len(entries)):
        rows = np.arange(xs[k].shape[0])
        for j in range(k):  # drop rows covered by newer generation j
            rows = rows[heights[k][rows] >= ratios.archived(j + 1, k + 1, k, rows)]
        r_new = ratios.archived(0, k + 1, k, rows)
        below = heights[k][rows] < r_new
        order = rng.permutation(int(np.count_nonzero(below)))
        pools.append(list(rows[below][order]))

    max_draws = _SUN2009_MAX_TRIALS_PER_MEMBER * builder.missing
    draws = 0
    while builder.missing > 0 and draws < max_draws:
        n = builder.missing
        candidates, cand_r_1, ratio_to = ratios.draw(n, rng)
        log_u = _log_uniform(rng, n)
        leftover = np.flatnonzero(log_u >= -cand_r_1)[: builder.missing]  # rule 2: above the previous graph
        draws += n
        if leftover.size == 0:
            continue
        # Newest older generation whose region holds each candidate (-1: none).
        region = np.full(leftover.size, -1)
        for k in range(1, len(entries)):
            open_rows = np.flatnonzero(region < 0)
            if open_rows.size == 0:
                break
            rows = leftover[open_rows]
            inside = log_u[rows] < -ratio_to(k + 1, rows)
            region[open_rows[inside]] = k
        for pos, k in zip(leftover.tolist(), region.tolist()):
            if k > 0 and pools[k - 1]:
                row = pools[k - 1].pop()
                builder.add(xs[k][row : row + 1], k + 1, row)
            else:
                builder.add(candidates[pos : pos + 1])
    return draws


def _whitened(dist, x: np.ndarray) -> np.ndarray:
    """``x`` in the coordinates in which ``dist`` is N(0, I) (a pushforward's: its base's, at ``T^-1 x``)."""
    if type(dist) is AffinePushforward:
        return _whitened(dist.base, dist.pulled_back(x))
    if type(dist) is DiagonalGaussian:
        return (x - dist.mean) / dist.std
    if type(dist) is FullGaussian:
        return xp.lower_solve_rows(dist.chol, x - dist.mean)
    raise ValueError(f'variant "conditional" needs Gaussian search distributions, got {type(dist).__name__}')


def _conditional(builder: _Builder, new_dist, entry, rng: np.random.Generator) -> int:
    """The ``"conditional"`` rule (module docstring, "Reuse inside the loop"): Sun et al.'s step slot by
    slot, each old member taken as a draw from its law q_i given the move of the mean it took part in.
    Returns the number of rule-2 candidates drawn."""
    old_dist, x = _unpack_entry(entry)
    n, dim = x.shape
    ratio = _log_ratio(new_dist, old_dist)
    weights = getattr(entry, "mean_weights", None)
    informed = weights is not None and np.any(weights != 0)
    if informed:
        weights = np.asarray(weights, dtype=np.float64)
        if weights.shape != (n,):
            raise ValueError(f"mean_weights has shape {weights.shape}, expected ({n},)")
        z = _whitened(old_dist, x)
        total = xp.dot(weights, weights)
        pull = weights / total  # a_i
        known = np.minimum(weights * weights / total, 1.0 - 1e-12)  # b_i < 1: q_i stays a density
        move = xp.vec_mat(weights, z)  # s

    def log_q_over_old(slots, z_rows):
        """log q_i(x) - log p_old(x) for slot i = slots[k] at the whitened row z_rows[k]."""
        if not informed:
            return np.zeros(len(slots))
        dev = z_rows - pull[slots, None] * move
        return -0.5 * xp.row_sq_norms(dev) / (1.0 - known[slots]) + 0.5 * xp.row_sq_norms(z_rows) - 0.5 * dim * xp.log(1.0 - known[slots])

    slots = np.sort(rng.permutation(n)[: builder.popsize]) if n > builder.popsize else np.arange(n)
    r_old = ratio.of_rows(x, slots)
    keep = _log_uniform(rng, slots.size) < r_old - log_q_over_old(slots, z[slots] if informed else None)  # rule 1 with q_i
    builder.add(x[slots[keep]], 1, slots[keep])
    pending = slots[~keep]
    draws = 0
    for _ in range(_SUN2009_MAX_TRIALS_PER_MEMBER):  # rule 2 against each slot's own q_i
        if pending.size == 0:
            break
        candidates, cand_r = ratio.sample(pending.size, rng)
        lq = log_q_over_old(pending, _whitened(old_dist, candidates) if informed else None)
        accept = _log_uniform(rng, pending.size) >= lq - cand_r  # u >= q_i / p_new
        builder.add(candidates[accept])
        draws += pending.size
        pending = pending[~accept]
    return draws  # slots still pending: filled with plain draws by builder.finish


# ------------------------------------------------------------------------------ the variants
# Each variant's numpy step: fills ``builder`` from the non-empty archive (``entries``: its (dist, samples)
# pairs; ``depth``: how many it may look back at) and returns the number of trials.
def _step_alternate(builder: _Builder, new_dist, archive, entries, depth: int, alpha: float, rng) -> int:
    """``"paper"`` (depth 1) and ``"eim_paper"``: Algorithm 2's alternation over the entries in turn, newest first."""
    trials = 0
    for number, (old_dist, old_samples) in enumerate(entries[:depth], start=1):
        trials += _alternate_rules(builder, new_dist, old_dist, old_samples, number, rng)
        if builder.missing <= 0:
            break
    if builder.missing < 0:  # both rules accepted on the last step
        builder.drop_random(rng)
    return trials


def _step_sun2009(builder: _Builder, new_dist, archive, entries, depth: int, alpha: float, rng) -> int:
    old_dist, old_samples = entries[0]
    return _sun2009(builder, new_dist, old_dist, old_samples, alpha, rng)


def _step_conditional(builder: _Builder, new_dist, archive, entries, depth: int, alpha: float, rng) -> int:
    return _conditional(builder, new_dist, archive[0], rng)


def _step_exact(builder: _Builder, new_dist, archive, entries, depth: int, alpha: float, rng) -> int:
    return _multi_generation(builder, new_dist, list(archive), depth, rng)


@dataclass(frozen=True)
class Variant:
    """A mixing variant, ``mix(..., variant=name)`` (module docstring, "Variants").

    Attributes
    ----------
    name : str
        What :func:`mix`, :class:`~imix_cli.core.mixing.generation.MixingSettings` and a RunSpec's ``variant`` call it.
    looks_back : bool
        Draws from up to ``eim_generations`` archived generations; else from the previous one only
        (:meth:`depth`, the archive a search keeps).
    kernel : int
        Its step's number in the compiled code: :data:`imix_cli.core.mixing.kernels.KERNELS` (one step, taken
        between float64 DiagonalGaussians) and the compiled generation loop
        (:mod:`imix_cli.running.loop.compiled_loop`, which branches on it); 0: no compiled step, numpy only.
    heights : bool
        Keeps each archived member's height (``Generation.log_u``) from one call to the next.
    uses_alpha : bool
        Takes ``alpha``, the minimal refresh rate (``im_alpha``).
    step : callable
        Its numpy step.
    selected_by : tuple of str
        The mixing schemes (``"im"``, ``"eim"``: :data:`imix_cli.core.registry.MIXING_SPECS`) whose config key
        ``<scheme>_variant`` offers it (:func:`config_variants`).
    config_name : str
        Its value there; its ``name`` unless given (only ``"eim_paper"`` differs: ``eim_variant=paper``).
    weights : bool
        Not a mixing rule: the archive is weighted into the ES's update (:mod:`imix_cli.core.mixing.weighted_reuse`, the
        generation scheme :class:`~imix_cli.core.mixing.generation.WeightedScheme`); its ``step`` is None and :func:`mix`
        refuses it.
    """

    name: str
    looks_back: bool
    kernel: int
    heights: bool
    uses_alpha: bool
    step: Callable[..., int] | None
    selected_by: tuple[str, ...] = ()
    config_name: str = ""
    weights: bool = False

    def __post_init__(self):
        if not self.config_name:
            object.__setattr__(self, "config_name", self.name)

    def depth(self, eim_generations: int) -> int:
        """The archived generations it reads, and so a search with it keeps."""
        return eim_generations if self.looks_back else 1


#: Every variant, by name, in the order of the module docstring (each scheme's default: :data:`MIXING_DEFAULTS`).
VARIANT_SPECS: dict[str, Variant] = {
    v.name: v
    for v in (
        Variant("paper", looks_back=False, kernel=1, heights=False, uses_alpha=False, step=_step_alternate, selected_by=("im",)),
        Variant("sun2009", looks_back=False, kernel=2, heights=False, uses_alpha=True, step=_step_sun2009, selected_by=("im",)),
        Variant("exact", looks_back=True, kernel=3, heights=True, uses_alpha=False, step=_step_exact, selected_by=("eim",)),
        Variant("conditional", looks_back=False, kernel=0, heights=False, uses_alpha=False, step=_step_conditional,
                selected_by=("im", "eim")),
        # Algorithm 3; "paper" is Algorithm 2's name, so eim_variant=paper selects it under another name
        Variant("eim_paper", looks_back=True, kernel=0, heights=False, uses_alpha=False, step=_step_alternate,
                selected_by=("eim",), config_name="paper"),
        # not a rule of mix(): the archive weighted into the update (imix_cli.core.mixing.weighted_reuse)
        Variant("weighted", looks_back=True, kernel=0, heights=False, uses_alpha=False, step=None, selected_by=("eim",), weights=True),
    )
}  # fmt: skip
#: The names of the variants :func:`mix` runs (every one but the weighted ones).
VARIANTS = tuple(name for name, v in VARIANT_SPECS.items() if not v.weights)


@dataclass(frozen=True)
class MixingDefaults:
    """Every mixing setting's default, declared once (:data:`MIXING_DEFAULTS`).

    Why one record: :func:`mix`, :class:`~imix_cli.core.mixing.ask_tell.MixingES`,
    :class:`~imix_cli.core.mixing.generation.MixingSettings`, the ``imix run`` keys
    (:mod:`imix_cli.running.config.keys`) and the RunSpec each take these settings; each reads its default here, so
    a library user gets the rule ``imix run eim=true`` runs (tests/test_mixing_defaults.py compares them all).

    Attributes
    ----------
    variant : str
        The library's variant (:func:`mix`, :class:`~imix_cli.core.mixing.ask_tell.MixingES`) and ``eim=true``'s
        (``eim_variant``): ``"exact"``, unbiased over chains of generations.
    im_variant : str
        ``im=true``'s (``im_variant``): ``"paper"``, the paper's Algorithm 2.
    eim_generations : int
        K, the archived generations ``"exact"`` and ``"eim_paper"`` reuse from.
    alpha : float
        ``"sun2009"``'s minimal refresh rate (``im_alpha``).
    min_fresh : int
        Fresh members of every mixed generation, at least (module docstring, "A minimal refresh"): 1, so a
        distribution that stops moving cannot make a fixed point; 0 is the rules alone.
    reeval_age, reeval_prob, reeval_count
        Re-evaluation of reused members (:class:`~imix_cli.core.mixing.generation.MixingSettings`): none.
    """

    variant: str = "exact"
    im_variant: str = "paper"
    eim_generations: int = 3
    alpha: float = 0.0
    min_fresh: int = 1
    reeval_age: int | None = None
    reeval_prob: float = 0.0
    reeval_count: int = 0


#: The defaults of every mixing setting: the one declaration (:class:`MixingDefaults`).
MIXING_DEFAULTS = MixingDefaults()


def config_variants(scheme: str) -> dict[str, Variant]:
    """The values of ``<scheme>_variant`` (``scheme``: ``"im"`` or ``"eim"``) -> the :class:`Variant` each selects, in
    the order of :data:`VARIANT_SPECS` (each scheme's default: :data:`MIXING_DEFAULTS`)."""
    return {v.config_name: v for v in VARIANT_SPECS.values() if scheme in v.selected_by}


def variant_spec(name: str) -> Variant:
    """The :class:`Variant` called ``name``; ValueError naming the valid ones otherwise."""
    try:
        return VARIANT_SPECS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown mixing variant {name!r}; valid: {', '.join(VARIANTS)}") from None


def _refresh(samples: np.ndarray, source: np.ndarray, index: np.ndarray, new_dist, min_fresh: int, rng) -> None:
    """The minimal refresh (module docstring): ``min_fresh`` slots drawn uniformly at random, independently
    of the members; the member in each, reused or fresh, is replaced in place by a fresh draw from ``new_dist``."""
    if min_fresh <= 0:
        return
    slots = rng.permutation(samples.shape[0])[:min_fresh]
    samples[slots] = new_dist.sample(slots.size, rng)
    source[slots] = 0
    index[slots] = -1


def _compiled_applies(new_dist, entries, popsize: int, variant: Variant) -> bool:
    """Whether :mod:`imix_cli.core.mixing.kernels` computes this step (see ``mix``'s ``compiled``)."""
    if not variant.kernel or not entries or type(new_dist) is not DiagonalGaussian or new_dist.dtype != np.float64:
        return False
    archived = 0
    for dist, samples in entries:
        if type(dist) is not DiagonalGaussian or samples.dtype != np.float64 or samples.shape[0] > popsize:
            return False
        archived += samples.size
    return archived <= COMPILED_MAX_ELEMENTS


def _compiled_full_applies(new_dist, entries, popsize: int, variant: Variant) -> bool:
    """Whether :func:`imix_cli.core.mixing.kernels.mix_full_exact` computes this step: ``"exact"`` between float64
    FullGaussians (pycma's adapter, imix's CMA-ES), archived generations of at most ``popsize`` members."""
    if variant.kernel != 3 or not entries or type(new_dist) is not FullGaussian or new_dist.dtype != np.float64:
        return False
    for dist, x in entries:  # a loop, not all() of generators: called every generation
        if type(dist) is not FullGaussian or dist.dtype != np.float64 or x.dtype != np.float64 or x.shape[0] > popsize:
            return False
    return True


def mix(
    new_dist,
    archive,
    popsize: int,
    rng: np.random.Generator,
    variant: str = MIXING_DEFAULTS.variant,
    alpha: float = MIXING_DEFAULTS.alpha,
    eim_generations: int = MIXING_DEFAULTS.eim_generations,
    compiled: bool | None = None,
    min_fresh: int = MIXING_DEFAULTS.min_fresh,
) -> Generation:
    """Build a generation of ``popsize`` members distributed as ``new_dist``, reusing archived samples.

    Parameters
    ----------
    new_dist : DiagonalGaussian or FullGaussian, or any :class:`~imix_cli.core.distributions.SearchDistribution`
        (``sample(n, rng)``, ``log_prob(x)``, ``dim``, optionally ``dtype``).
        The search distribution of the new generation.
    archive : list of ``(dist, samples[n, d])`` pairs or :class:`Generation` objects
        Earlier generations, newest first; ``dist`` is the distribution that generation is distributed as.
        An empty archive gives a generation of fresh draws.
    popsize : int
        Size N of the new generation.
    rng : numpy.random.Generator
        Source of all randomness (acceptance tests, fresh draws, orderings).
    variant : {"exact", "paper", "sun2009", "conditional", "eim_paper"}
        See the module docstring; default ``"exact"``, as ``imix run eim=true`` (:data:`MIXING_DEFAULTS`).
        ``"paper"``, ``"sun2009"`` and ``"conditional"`` use ``archive[0]`` only
        (``"conditional"`` reads its ``mean_weights`` if it is a Generation),
        ``"exact"`` and ``"eim_paper"`` up to ``eim_generations`` entries. ``"exact"`` keeps each
        Generation's heights in it (``log_u``): pass the same Generation objects again; a
        plain ``(dist, samples)`` pair is taken as a fresh independent sample at every call.
    alpha : float in [0, 1)
        Minimal refresh rate of ``"sun2009"`` (ignored by the other variants).
    eim_generations : int >= 1
        K, the number of archived generations ``"exact"`` and ``"eim_paper"`` may draw from (default 3).
    min_fresh : int >= 0
        The minimal refresh (module docstring): this many slots, drawn at random, hold fresh members
        whenever the archive is not empty; default 1, as ``imix run`` (0: none, the rules alone). The generation
        keeps its law.
    compiled : bool or None
        None (default): take the compiled step (:mod:`imix_cli.core.mixing.kernels`) where it
        applies -- ``"paper"``, ``"sun2009"``, ``"exact"`` between float64 DiagonalGaussians,
        archived generations of at most ``popsize`` members, up to 2^20 archived numbers --
        and the numpy step otherwise. Both give the same generation from the same ``rng``
        (to round-off in the log-ratios). False: always numpy; True: compiled or ValueError.

    Returns
    -------
    Generation
        ``.samples``, ``.source`` (0 fresh, k >= 1 from ``archive[k-1]``), ``.index``.
    """
    spec = variant_spec(variant)
    if spec.weights:
        raise ValueError(
            f"variant {variant!r} builds no generation: it weights the archive into the update (imix_cli.core.mixing.weighted_reuse; use MixingES)"
        )
    if popsize < 1:
        raise ValueError(f"popsize must be >= 1, got {popsize}")
    if not 0.0 <= alpha < 1.0:
        raise ValueError(f"alpha must be in [0, 1), got {alpha}")
    if eim_generations < 1:
        raise ValueError(f"eim_generations must be >= 1, got {eim_generations}")
    if min_fresh < 0:
        raise ValueError(f"min_fresh must be >= 0, got {min_fresh}")
    dim = new_dist.dim
    entries = [_unpack_entry(e) for e in archive]
    for number, (_, samples) in enumerate(entries, start=1):
        if samples.ndim != 2 or samples.shape[1] != dim:
            raise ValueError(f"archive[{number - 1}] samples have shape {samples.shape}, expected (n, {dim})")

    depth = spec.depth(eim_generations)
    if compiled is not False and _compiled_applies(new_dist, entries[:depth], popsize, spec):
        from imix_cli.core.mixing.kernels import mix_diagonal  # numba: imported on first use only

        used = list(archive[:depth])
        heights = [_heights(e, rng) for e in used] if spec.heights else None
        dists, samples = zip(*entries[:depth])
        x, source, index, trials = mix_diagonal(new_dist, dists, samples, heights, popsize, rng, spec.kernel, alpha, min_fresh)
        return Generation(x, source, index, new_dist, trials)
    if compiled is not False and _compiled_full_applies(new_dist, entries[:depth], popsize, spec):
        # the whole step in one compiled call: at d = 10 the numpy step's few hundred small calls were most of the
        # pycma adapter's overhead over pycma's own ask and tell (issue 45). The same numbers as the numpy step, bit for bit.
        from imix_cli.core.mixing.kernels import mix_full_exact

        used = list(archive[:depth])
        heights = [_heights(e, rng) for e in used]
        dists, samples = zip(*entries[:depth])
        table = None  # small d: the archived log-densities computed in the compiled step, cheaper than keeping them
        if dim >= _KEEP_LOG_PROBS_FROM_DIM:
            table = np.zeros((len(samples), len(samples) + 1, max(x.shape[0] for x in samples)))
            for k, row in enumerate(_archived_log_probs([new_dist, *dists], samples)):
                for j, values in enumerate(row):
                    table[k, j, : values.shape[0]] = values
        x, source, index, trials = mix_full_exact(new_dist, dists, samples, heights, table, popsize, rng, min_fresh)
        return Generation(x, source, index, new_dist, trials)
    if compiled:
        raise ValueError(f"the compiled mixing step does not apply to variant {variant!r} with {type(new_dist).__name__} and this archive")

    builder = _Builder(popsize, dim, getattr(new_dist, "dtype", np.float64))
    trials = spec.step(builder, new_dist, archive, entries, depth, alpha, rng) if entries else 0
    generation = builder.finish(new_dist, rng, trials)
    if entries:
        _refresh(generation.samples, generation.source, generation.index, new_dist, min_fresh, rng)
    return generation
