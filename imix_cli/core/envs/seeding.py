"""Episode seeding: ``np.random.default_rng(s).uniform(low, high, size)`` for many seeds at once.

gymnasium's ``reset(seed=s)`` seeds ``np.random.Generator(PCG64(SeedSequence(s)))``, the same
generator as ``np.random.default_rng(s)``; classic-control envs then draw their initial state
with ``uniform(low, high, size)``. Building one generator per episode costs ~8 us in Python,
more than a whole compiled CartPole episode of a good policy, so the same arithmetic is
compiled (:func:`imix_cli.core.envs.kernels.uniform_row`, used inside the episode kernels).
Re-exported as :func:`imix_cli.core.envs.seeded_uniform`; seeds must be integers in [0, 2**64).
"""

from __future__ import annotations

import numpy as np

__all__ = ["seeded_uniform"]


def seeded_uniform(seeds, low: float, high: float, size: int) -> np.ndarray:
    """(n, size) float64 array: row i equals ``np.random.default_rng(seeds[i]).uniform(low, high, size)``."""
    from imix_cli.core.envs.kernels import seeded_uniform_rows  # numba loads on first use, not on `import imix_cli`

    seeds = np.asarray(seeds).reshape(-1)
    if seeds.size and (seeds.dtype.kind not in "iu" or seeds.min() < 0):
        raise ValueError("seeds must be non-negative integers below 2**64")
    return seeded_uniform_rows(seeds.astype(np.uint64), float(low), float(high), int(size))
