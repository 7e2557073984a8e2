"""Statistics shared by the runner's summary and the plots (a bottom layer: imports nothing of imix)."""

from __future__ import annotations

import numpy as np


def mean_ci(values, level: float = 0.68, axis: int = 0):
    """Mean, CI half-width and seed count along ``axis`` (NaN/inf entries ignored).

    The half-width is ``t.ppf((1 + level) / 2, n - 1) * std(ddof=1) / sqrt(n)``
    (Student t interval of the mean); NaN where fewer than two finite values.
    ``mean_ci([1, 2, 3, 4])`` -> ``(2.5, 1.18893 * 0.645497, 4)``.
    """
    from scipy import stats  # here, not at import: every spawned worker imports this module

    arr = np.asarray(values, dtype=float)
    arr = np.where(np.isfinite(arr), arr, np.nan)
    n = np.sum(np.isfinite(arr), axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        total = np.nansum(arr, axis=axis)
        mean = np.where(n > 0, total / np.maximum(n, 1), np.nan)
        dev = np.where(np.isfinite(arr), arr - np.expand_dims(mean, axis), 0.0)
        var = np.sum(dev**2, axis=axis) / np.maximum(n - 1, 1)
        sem = np.sqrt(var) / np.sqrt(np.maximum(n, 1))
        tq = stats.t.ppf(0.5 + level / 2.0, np.maximum(n - 1, 1))
        half = np.where(n >= 2, tq * sem, np.nan)
    if np.ndim(mean) == 0:
        return float(mean), float(half), int(n)
    return mean, half, n
