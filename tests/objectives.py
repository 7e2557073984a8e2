"""Test functions for the evolution strategies, to be *minimised* (the ES maximise -f).

All take a batch ``x`` of shape (n, d) and return shape (n,); the optimum is f(0) = 0.
"""

from __future__ import annotations

import numpy as np


def sphere(x) -> np.ndarray:
    """f(x) = sum_i x_i^2."""
    x = np.atleast_2d(x)
    return np.einsum("ij,ij->i", x, x)


class RotatedEllipsoid:
    """f(x) = sum_i cond^(i/(d-1)) (R x)_i^2 with a fixed random rotation R (seeded).

    ``cond`` is the condition number of the Hessian (axis-length ratio sqrt(cond)).
    ``rotate=False`` keeps R = I (axis-aligned: a diagonal covariance can fit it).
    """

    def __init__(self, dim: int, cond: float = 1e3, seed: int = 0, rotate: bool = True):
        if rotate:
            q, r = np.linalg.qr(np.random.default_rng(seed).standard_normal((dim, dim)))
            self.rotation = q * np.sign(np.diag(r))  # Haar-distributed orthogonal matrix
        else:
            self.rotation = np.eye(dim)
        self.scales = cond ** (np.arange(dim) / max(dim - 1, 1))
        self.cond = cond

    def __call__(self, x) -> np.ndarray:
        y = np.atleast_2d(x) @ self.rotation.T
        return (y * y) @ self.scales


def rastrigin(x) -> np.ndarray:
    """f(x) = 10 d + sum_i (x_i^2 - 10 cos(2 pi x_i)); local minima near every integer point."""
    x = np.atleast_2d(x)
    return 10.0 * x.shape[1] + np.sum(x * x - 10.0 * np.cos(2.0 * np.pi * x), axis=1)
