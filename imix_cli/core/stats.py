"""Statistics shared by the runner's summary, the plots and `imix eval` (a bottom layer: imports nothing of imix).

Two families: the mean with a Student t CI over seeds (what the paper reports), and the robust
aggregates of Agarwal et al. (2021) with stratified-bootstrap CIs (section below).
"""

from __future__ import annotations

import math

import numpy as np


def mean_ci(values, level: float = 0.68, axis: int = 0):
    """Mean, CI half-width and seed count along ``axis`` (NaN/inf entries ignored).

    The half-width is ``t.ppf((1 + level) / 2, n - 1) * std(ddof=1) / sqrt(n)``
    (Student t interval of the mean); NaN where fewer than two finite values.
    ``mean_ci([1, 2, 3, 4])`` -> ``(2.5, 1.18893 * 0.645497, 4)``.
    """
    # scipy.special's Student t quantile is what ``scipy.stats.t.ppf`` calls (the same values), and
    # importing it costs ~0.3 s less than scipy.stats: every run's summary pays that import.
    from scipy.special import stdtrit

    arr = np.asarray(values, dtype=float)
    arr = np.where(np.isfinite(arr), arr, np.nan)
    n = np.sum(np.isfinite(arr), axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        total = np.nansum(arr, axis=axis)
        mean = np.where(n > 0, total / np.maximum(n, 1), np.nan)
        dev = np.where(np.isfinite(arr), arr - np.expand_dims(mean, axis), 0.0)
        var = np.sum(dev**2, axis=axis) / np.maximum(n - 1, 1)
        sem = np.sqrt(var) / np.sqrt(np.maximum(n, 1))
        tq = stdtrit(np.maximum(n - 1, 1), 0.5 + level / 2.0)
        half = np.where(n >= 2, tq * sem, np.nan)
    if np.ndim(mean) == 0:
        return float(mean), float(half), int(n)
    return mean, half, n


# ----------------------------------------------------------------------------- Agarwal et al. 2021
# "Deep RL at the edge of the statistical precipice" (NeurIPS 2021): robust aggregates with
# stratified-bootstrap CIs, the probability of improvement and performance profiles. rliable
# implements them, but its last release (1.2.0) needs arch<8, and arch 7.x fails to import with
# pandas 3 (the project's pandas): hence this small re-implementation, checked against rliable's
# own `metrics` functions (which need only scipy) in tests/test_stats.py.
#
# Data layout (as rliable's): ``scores`` is a list of 1-D arrays, one per *task* (stratum: an env,
# say), each holding one value per run (seed). Strata may hold different numbers of runs; a 2-D
# array (runs, tasks) is taken as its columns. Bootstrap resamples the runs of each stratum
# independently, with replacement, keeping every stratum's size (stratified bootstrap), and the CI
# is the percentile interval of the statistic over ``reps`` resamples. Seeded: same input, same CI.


def _strata(scores) -> list[np.ndarray]:
    if isinstance(scores, np.ndarray) and scores.ndim == 2:
        return [np.asarray(scores[:, j], dtype=float) for j in range(scores.shape[1])]
    if (isinstance(scores, np.ndarray) and scores.ndim == 1) or all(np.ndim(s) == 0 for s in scores):
        return [np.asarray(scores, dtype=float).reshape(-1)]  # one stratum of runs
    out = [np.asarray(s, dtype=float).reshape(-1) for s in scores]
    if not out or any(s.size == 0 for s in out):
        raise ValueError("every stratum needs at least one run")
    return out


def iqm(values, axis=None):
    """Interquartile mean: the mean of the middle 50 % (``scipy.stats.trim_mean(x, 0.25)``, as rliable).

    ``int(0.25 * n)`` values are cut at each end, so ``iqm([1, ..., 8]) == 4.5``. Robust to up to
    25 % of outliers at either end, including ``+inf`` (a seed that never reaches a threshold).
    """
    from scipy import stats

    arr = np.asarray(values, dtype=float)
    if axis is None:
        arr = arr.reshape(-1)
        axis = 0
    with np.errstate(invalid="ignore"):  # inf - inf in a column that keeps two infs: NaN, reported as such
        return stats.trim_mean(arr, 0.25, axis=axis)


def _resample(strata, reps: int, rng) -> list[np.ndarray]:
    """Per stratum a (reps, n_j) array of its runs drawn with replacement."""
    return [s[rng.integers(0, s.size, size=(reps, s.size))] for s in strata]


def _percentile_ci(samples: np.ndarray, level: float) -> tuple[float, float]:
    finite = samples[~np.isnan(samples)]
    if finite.size == 0:
        return math.nan, math.nan
    with np.errstate(invalid="ignore"):  # +inf samples (never reached): inf - inf while interpolating
        lo, hi = np.percentile(finite, [50.0 * (1.0 - level), 50.0 * (1.0 + level)])
    return float(lo), float(hi)


def iqm_ci(scores, level: float = 0.95, reps: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """``(IQM over all runs of all strata, CI low, CI high)``, stratified percentile bootstrap."""
    strata = _strata(scores)
    point = float(iqm(np.concatenate(strata)))
    boot = iqm(np.concatenate(_resample(strata, reps, np.random.default_rng(seed)), axis=1), axis=1)
    return (point, *_percentile_ci(np.asarray(boot, dtype=float), level))


def mean_bootstrap_ci(scores, level: float = 0.95, reps: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """``(mean over all runs, CI low, CI high)``, stratified percentile bootstrap (the mean's robust-CI twin)."""
    strata = _strata(scores)
    point = float(np.mean(np.concatenate(strata)))
    boot = np.mean(np.concatenate(_resample(strata, reps, np.random.default_rng(seed)), axis=1), axis=1)
    return (point, *_percentile_ci(boot, level))


def _poi_batched(xs: list[np.ndarray], ys: list[np.ndarray]) -> np.ndarray:
    """P(X > Y) + P(X = Y) / 2 per stratum, averaged over strata; inputs (reps, n) arrays."""
    per_task = []
    for x, y in zip(xs, ys):
        gt = (x[:, :, None] > y[:, None, :]).mean(axis=(1, 2))
        eq = (x[:, :, None] == y[:, None, :]).mean(axis=(1, 2))
        per_task.append(gt + 0.5 * eq)
    return np.mean(per_task, axis=0)


def probability_of_improvement(x, y) -> float:
    """P(X > Y): the chance that a run of X scores higher than a run of Y on the same task.

    Per task the Mann-Whitney U statistic of X against Y divided by ``n_x * n_y`` (ties count
    half), averaged over tasks -- rliable's definition. ``x``/``y``: lists of strata, as above.
    """
    xs, ys = _strata(x), _strata(y)
    if len(xs) != len(ys):
        raise ValueError(f"x has {len(xs)} strata, y has {len(ys)}")
    return float(_poi_batched([s[None, :] for s in xs], [s[None, :] for s in ys])[0])


def probability_of_improvement_ci(x, y, level: float = 0.95, reps: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """``(P(X > Y), CI low, CI high)``: X's and Y's runs resampled independently within each stratum."""
    xs, ys = _strata(x), _strata(y)
    point = probability_of_improvement(xs, ys)
    rng = np.random.default_rng(seed)
    boot = _poi_batched(_resample(xs, reps, rng), _resample(ys, reps, rng))
    return (point, *_percentile_ci(boot, level))


def performance_profile(scores, taus) -> np.ndarray:
    """Fraction of runs scoring strictly above each ``tau`` (per stratum, then averaged over strata).

    rliable's ``run_score_distribution``: the empirical tail distribution of the scores.
    """
    taus = np.asarray(taus, dtype=float)
    return np.mean([(s[:, None] > taus[None, :]).mean(axis=0) for s in _strata(scores)], axis=0)


def performance_profile_ci(scores, taus, level: float = 0.95, reps: int = 2000, seed: int = 0):
    """``(profile (T,), low (T,), high (T,))``: :func:`performance_profile` with stratified-bootstrap bands."""
    strata = _strata(scores)
    taus = np.asarray(taus, dtype=float)
    point = performance_profile(strata, taus)
    resampled = _resample(strata, reps, np.random.default_rng(seed))
    boot = np.mean([(r[:, :, None] > taus[None, None, :]).mean(axis=1) for r in resampled], axis=0)  # (reps, T)
    lo, hi = np.percentile(boot, [50.0 * (1.0 - level), 50.0 * (1.0 + level)], axis=0)
    return point, lo, hi
