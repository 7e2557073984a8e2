"""Batched MLP policies: one flat parameter vector per population member.

Architecture (Pourchot et al. 2018, sec. 4.1): two tanh hidden layers of 8 units and a
linear output layer. A member's flat parameter vector is laid out as::

    W1 (obs_dim x h1, row-major), b1 (h1), W2 (h1 x h2), b2 (h2), W3 (h2 x out_dim), b3 (out_dim)

so that ``y = tanh(tanh(obs @ W1 + b1) @ W2 + b2) @ W3 + b3``. With ``hidden=(8, 8)``
that is 130 parameters for CartPole (obs 4, 2 actions) and 155 for Acrobot (obs 6,
3 actions).

Actions:

* discrete: ``argmax(y)``, computed by comparisons: output j replaces the best so far only
  if strictly greater, so ties go to the lowest index (as ``np.argmax``) and NaN outputs
  never take over (a NaN ``y[0]`` keeps action 0; ``np.argmax`` would instead pick the
  first NaN; this only matters for non-finite parameters);
* continuous: ``tanh(y)``, mapped affinely onto ``[low, high]`` when bounds are given
  (``high * tanh(y)`` when ``low == -high``, so ``[-1, 1]`` is exactly ``tanh(y)``).

Every member has its own weights: :class:`BatchPolicy` unpacks a ``(B, d)`` parameter
matrix once per rollout into member-last weight stacks and evaluates all members with one
``einsum`` per layer. That sums each member's products in a fixed sequential order, so a
member's actions never depend on which other members share its batch (BLAS-backed
``matmul`` would be no faster and gives no such guarantee). :func:`unpack` gives the
per-layer weights in the natural ``(B, in, out)`` layout, for inspection and tests.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

HIDDEN: tuple[int, ...] = (8, 8)

__all__ = ["HIDDEN", "num_params", "unpack", "BatchPolicy", "forward", "act"]


def num_params(obs_dim: int, out_dim: int, hidden: Sequence[int] = HIDDEN) -> int:
    """Number of parameters of the MLP ``obs_dim -> hidden... -> out_dim`` (with biases)."""
    sizes = [int(obs_dim), *map(int, hidden), int(out_dim)]
    return sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:]))


def unpack(
    params: np.ndarray, obs_dim: int, out_dim: int, hidden: Sequence[int] = HIDDEN
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Split ``params`` (B, d) into per-layer ``(W (B, in, out), b (B, out))`` copies (float64)."""
    params = np.asarray(params, dtype=np.float64)
    if params.ndim != 2:
        raise ValueError(f"params must be 2-D (B, d), got shape {params.shape}")
    d = num_params(obs_dim, out_dim, hidden)
    if params.shape[1] != d:
        raise ValueError(
            f"params have {params.shape[1]} columns, the {obs_dim}->{tuple(hidden)}->{out_dim} MLP needs {d}"
        )
    sizes = [int(obs_dim), *map(int, hidden), int(out_dim)]
    layers, k, n = [], 0, params.shape[0]
    for a, b in zip(sizes[:-1], sizes[1:]):
        W = np.ascontiguousarray(params[:, k : k + a * b]).reshape(n, a, b)
        k += a * b
        bias = np.ascontiguousarray(params[:, k : k + b])
        k += b
        layers.append((W, bias))
    return layers


def _argmax_cols(y: np.ndarray) -> np.ndarray:
    """Column-wise argmax of a (k, n) array by comparisons (see the module docstring)."""
    k, n = y.shape
    if k == 1:
        return np.zeros(n, dtype=np.int64)
    if k == 2:
        return (y[1] > y[0]).astype(np.int64)
    better = y[1] > y[0]
    a = better.astype(np.int64)
    best = np.where(better, y[1], y[0])
    for j in range(2, k):
        np.greater(y[j], best, out=better)
        np.copyto(a, j, where=better)
        np.copyto(best, y[j], where=better)
    return a


class BatchPolicy:
    """Unpacked weights of n members, evaluated together; see the module docstring.

    ``policy(obs)`` maps observations (n, obs_dim) (any float dtype) to actions: int64 (n,)
    if discrete, float64 (n, out_dim) otherwise. :meth:`select` keeps only some members
    (compaction).

    Internally weights are stored member-last ("structure of arrays": W (in, out, m),
    b (out, m)) and each layer is one ``einsum("ijb,ib->jb")``. With the member axis
    innermost, einsum's loop runs over members and accumulates over ``i`` sequentially
    (bit-identical to ``sum_i W[i] * x[i]``), so a member's result never depends on the
    others. A lone member is stored twice (m = 2): with a single member *and* a single
    output, einsum would switch to an unrolled dot-product kernel that sums in another
    order (tests/test_envs.py checks alone == in batch). float64 throughout.
    """

    def __init__(
        self,
        params: np.ndarray,
        obs_dim: int,
        out_dim: int,
        *,
        discrete: bool = True,
        hidden: Sequence[int] = HIDDEN,
        low: np.ndarray | float | None = None,
        high: np.ndarray | float | None = None,
    ):
        self.obs_dim, self.out_dim, self.discrete = int(obs_dim), int(out_dim), bool(discrete)
        self.hidden = tuple(int(h) for h in hidden)
        params = np.asarray(params, dtype=np.float64)
        if params.ndim != 2 or params.shape[1] != num_params(obs_dim, out_dim, self.hidden):
            raise ValueError(
                f"params must have shape (B, {num_params(obs_dim, out_dim, self.hidden)}) for the "
                f"{obs_dim}->{self.hidden}->{out_dim} MLP, got {params.shape}"
            )
        sizes = [self.obs_dim, *self.hidden, self.out_dim]
        n = params.shape[0]
        flat = np.ascontiguousarray(params[[0, 0]].T if n == 1 else params.T)  # (d, m)
        self.layers: list[tuple[np.ndarray, np.ndarray]] = []
        k = 0
        for a, b in zip(sizes[:-1], sizes[1:]):
            W = flat[k : k + a * b].reshape(a, b, -1)
            k += a * b
            self.layers.append((W, flat[k : k + b]))
            k += b
        self._alloc(n)
        self._scale = self._offset = None
        if not self.discrete and (low is not None or high is not None):
            lo = np.broadcast_to(np.asarray(low, dtype=np.float64), (self.out_dim,))
            hi = np.broadcast_to(np.asarray(high, dtype=np.float64), (self.out_dim,))
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo < hi)):
                raise ValueError(f"continuous actions need finite bounds low < high, got {lo}, {hi}")
            if np.array_equal(lo, -hi):
                self._scale = None if np.all(hi == 1.0) else hi[:, None].copy()
            else:
                self._scale, self._offset = ((hi - lo) / 2.0)[:, None], lo[:, None].copy()

    def _alloc(self, n: int) -> None:
        self.n = n
        m = self.layers[0][0].shape[2]  # max(n, 2)
        self._x = np.zeros((self.obs_dim, m))
        self._bufs = [np.empty((W.shape[1], m)) for W, _ in self.layers]

    def select(self, rows: np.ndarray) -> None:
        """Keep only the members at ``rows`` (indices into the current members), in that order."""
        rows = np.asarray(rows)
        cols = rows[[0, 0]] if len(rows) == 1 else rows
        self.layers = [(np.ascontiguousarray(W[:, :, cols]), np.ascontiguousarray(b[:, cols])) for W, b in self.layers]
        self._alloc(len(rows))

    def outputs_t(self, obs: np.ndarray) -> np.ndarray:
        """Raw network outputs, transposed: y (out_dim, n), for observations (n, obs_dim).

        The returned array is an internal buffer, overwritten by the next call.
        """
        x = self._x
        n = self.n
        np.copyto(x[:, :n], np.asarray(obs).reshape(n, self.obs_dim).T)
        last = len(self.layers) - 1
        for i, (W, b) in enumerate(self.layers):
            y = self._bufs[i]
            np.einsum("ijb,ib->jb", W, x, out=y)
            np.add(y, b, out=y)
            if i < last:
                np.tanh(y, out=y)
            x = y
        return x if n > 1 else x[:, :1]

    def outputs(self, obs: np.ndarray) -> np.ndarray:
        """Raw network outputs y (n, out_dim) (a new array)."""
        return self.outputs_t(obs).T.copy()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        y = self.outputs_t(obs)
        if self.discrete:
            return _argmax_cols(y)
        a = np.tanh(y)
        if self._offset is not None:  # low + (tanh + 1) * (high - low) / 2
            a += 1.0
            a *= self._scale
            a += self._offset
        elif self._scale is not None:  # symmetric bounds: high * tanh
            a *= self._scale
        return np.ascontiguousarray(a.T)


def forward(
    params: np.ndarray, obs: np.ndarray, out_dim: int, hidden: Sequence[int] = HIDDEN
) -> np.ndarray:
    """Raw outputs (B, out_dim) of B members on their own observations (B, obs_dim)."""
    obs = np.asarray(obs)
    return BatchPolicy(params, obs.shape[1], out_dim, hidden=hidden).outputs(obs)


def act(
    params: np.ndarray,
    obs: np.ndarray,
    out_dim: int,
    discrete: bool = True,
    hidden: Sequence[int] = HIDDEN,
    low=None,
    high=None,
) -> np.ndarray:
    """Actions of B members on their own observations (B, obs_dim).

    Discrete: int64 (B,) argmax of the outputs. Continuous: float64 (B, out_dim),
    ``tanh`` of the outputs, mapped onto ``[low, high]`` if given. For a rollout, build
    a :class:`BatchPolicy` once instead (this unpacks the parameters on every call).
    """
    obs = np.asarray(obs)
    pol = BatchPolicy(params, obs.shape[1], out_dim, discrete=discrete, hidden=hidden, low=low, high=high)
    return pol(obs)
