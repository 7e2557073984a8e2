"""Batched MLP policies: one flat parameter vector per population member.

Architecture (Pourchot et al. 2018, sec. 4.1): two tanh hidden layers of 8 units and a
linear output layer. A member's flat parameter vector is laid out as::

    W1 (obs_dim x h1, row-major), b1 (h1), W2 (h1 x h2), b2 (h2), W3 (h2 x out_dim), b3 (out_dim)

so that ``y = tanh(tanh(obs @ W1 + b1) @ W2 + b2) @ W3 + b3``. With ``hidden=(8, 8)``
that is 130 parameters for CartPole (obs 4, 2 actions) and 155 for Acrobot (obs 6,
3 actions).

Other sizes (config key ``policy.hidden``) keep the same layout, layer after layer: any
number of tanh hidden layers, and ``hidden=()`` is the linear policy ``y = obs @ W + b``
(Mania et al. 2018's ARS policies on MuJoCo). :func:`num_params` and this layout are the
contract with every rollout (the numpy one here and compiled ones): do not change them.

Actions:

* discrete: ``argmax(y)``, computed by comparisons: output j replaces the best so far only
  if strictly greater, so ties go to the lowest index (as ``np.argmax``) and NaN outputs
  never take over (a NaN ``y[0]`` keeps action 0; ``np.argmax`` would instead pick the
  first NaN; this only matters for non-finite parameters);
* continuous, ``output="tanh"`` (the default): ``tanh(y)``, mapped affinely onto ``[low, high]``
  when bounds are given (``high * tanh(y)`` when ``low == -high``, so ``[-1, 1]`` is exactly
  ``tanh(y)``);
* continuous, ``output="clip"`` (config key ``policy.output``): ``y`` clipped to ``[low, high]``
  (``[-1, 1]`` without bounds). This is ARS's linear policy (Mania et al. 2018; sb3-contrib's
  ``ARSLinearPolicy``): the action is ``M s`` itself until it reaches the actuator's limit, where
  a tanh would already have bent it.

A policy without biases (``policy.bias=false``, ARS's ``a = M s``) keeps this layout: the
evolution strategy searches the weights only (:func:`weight_columns`) and
:func:`with_zero_biases` puts them back into the layout with zero biases, so every rollout,
saved policy and normaliser fold stays the same code.

Every member has its own weights: :class:`BatchPolicy` unpacks a ``(B, d)`` parameter
matrix once per rollout into member-last weight stacks and evaluates all members with one
``einsum`` per layer. That sums each member's products in a fixed sequential order, so a
member's actions never depend on which other members share its batch (BLAS-backed
``matmul`` would be no faster and gives no such guarantee). :func:`unpack` gives the
per-layer weights in the natural ``(B, in, out)`` layout, for inspection and tests.

Observation normalisation, and how reuse stays honest (``policy.obs_norm``, ``policy.obs_norm_freeze``)
----------------------------------------------------------------------------------------------------
Why. ES on MuJoCo needs normalised observations (Salimans et al. 2017; Mania et al. 2018): the
raw coordinates differ in scale by orders of magnitude, and one sigma cannot fit them all.
The policy then sees ``(obs - mean) / std`` with running statistics of the observations
seen so far. That makes the policy *function* of a parameter vector depend on the
statistics -- and importance mixing reuses a member's stored return as if it had been
measured under the current policy function. A normaliser that keeps changing (as in ARS) under an
archive left as it was silently turns every reused return into the return of another policy.

How: two ways, each exact where it applies. During a warm-up of ``policy.obs_norm_warmup``
generations the statistics absorb the observations of every episode and the runner does not mix
(every member is fresh, nothing is archived); after it:

* frozen (``policy.obs_norm_freeze=true``, the default; :class:`ObsNormalizer`): the statistics
  never change again, and only generations evaluated entirely under the frozen statistics enter
  the archive. Every reused return was measured under the very policy function the member has now;
  exact for every policy, with or without biases, and free after the warm-up. Its price is that the
  statistics describe the early, clumsy policies' states. With ARS V2-t on Hopper that price came
  from the variance floor, not from freezing: a coordinate that barely moves while the early hoppers
  fall is scaled by the floor's 1/0.1 instead of its own 1/std (OBS_VAR_FLOOR below,
  ``policy.obs_var_floor``); with ARS's floor of ~1e-8, statistics frozen after 5 generations did as
  well as statistics updated every generation (docs/ars.md, "Hopper"). (tests/test_mujoco.py checks
  that every reused member's policy function equals the one its return was measured under.)
* updated (``policy.obs_norm_freeze=false``, as ARS V2 and sb3-contrib's VecNormalize): the statistics
  keep absorbing every generation's observations, and after each change every archived member is
  *re-expressed* as the same policy under the new statistics. The first layer's pre-activation
  ``((obs - m) / s) @ W1 + b1`` is the same function under ``(m', s')`` with ``W1' = diag(s'/s) W1`` and
  ``b1' = b1 + ((m' - m) / s) @ W1`` (:class:`NormalizerChange`, an affine map T of the flat parameter
  vector); each archived member becomes T(theta) -- the same policy, so the same return from the same
  episode -- and its generation's distribution the pushforward of the one it was drawn from
  (:class:`imix_cli.core.distributions.AffinePushforward`: ``log p'(x) = log p(T^-1 x) - log|det T|``),
  so the archived generations are still samples of their (re-expressed) distributions and mixing stays
  exact for every variant (the heights ``log(y / p(x))`` of ``"exact"`` are ratios to the density and do
  not change; ``"conditional"`` whitens through T^-1). The ES's own state is not re-expressed: it moves in
  the coordinates the statistics of the moment give (what ARS does). Exact only for a policy with
  biases: without one (``policy.bias=false``, ARS's ``a = M s``), a change of the mean is an offset the
  policy cannot express, so ``imix run`` refuses this key with mixing and ``policy.bias=false``; without
  mixing nothing is reused and any policy may keep updating. (tests/test_obs_norm_reexpress.py checks
  that every reused member's stored return is the return of its re-expressed parameters under the
  current statistics.)

Alternatives weighed: re-measuring archived members after every change defeats the purpose of reuse;
clearing the archive at each change (say every K generations) only delays the same trade-off, costs a
full generation per change, and makes reuse rates depend on K.

The normalisation is folded into the first layer (:func:`fold_normalizer`):
``((obs - m) / s) @ W1 + b1 == obs @ (W1 / s) + (b1 - (m / s) @ W1)``, so rollouts --
numpy, compiled, or remote -- only ever see plain flat parameter vectors.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from imix_cli.core import numerics as xp

HIDDEN: tuple[int, ...] = (8, 8)

#: Continuous action maps (``policy.output``): see the module docstring.
OUTPUTS = ("tanh", "clip")

__all__ = [
    "HIDDEN", "OUTPUTS", "num_params", "weight_columns", "searched_params", "with_zero_biases", "unpack", "BatchPolicy", "forward", "act",
    "policy_output", "policy_action", "ObsNormalizer", "fold_normalizer", "NormalizerChange",
]  # fmt: skip


def num_params(obs_dim: int, out_dim: int, hidden: Sequence[int] = HIDDEN) -> int:
    """Number of parameters of the MLP ``obs_dim -> hidden... -> out_dim`` (with biases)."""
    sizes = [int(obs_dim), *map(int, hidden), int(out_dim)]
    return sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:]))


def weight_columns(obs_dim: int, out_dim: int, hidden: Sequence[int] = HIDDEN) -> np.ndarray:
    """Indices of the weights (not the biases) in the flat layout: what a bias-free policy's ES searches."""
    sizes = [int(obs_dim), *map(int, hidden), int(out_dim)]
    columns, k = [], 0
    for a, b in zip(sizes[:-1], sizes[1:]):
        columns.append(np.arange(k, k + a * b))
        k += a * b + b
    return np.concatenate(columns)


def searched_params(obs_dim: int, out_dim: int, hidden: Sequence[int] = HIDDEN, bias: bool = True) -> int:
    """How many parameters an ES searches for this MLP: all of them, or (``bias=False``) its weights only."""
    return num_params(obs_dim, out_dim, hidden) if bias else weight_columns(obs_dim, out_dim, hidden).size


def with_zero_biases(weights: np.ndarray, obs_dim: int, out_dim: int, hidden: Sequence[int] = HIDDEN) -> np.ndarray:
    """Weights (B, len(weight_columns)) as full parameter vectors (B, num_params) whose biases are 0 (a new array)."""
    weights = np.asarray(weights, dtype=np.float64)
    columns = weight_columns(obs_dim, out_dim, hidden)
    if weights.ndim != 2 or weights.shape[1] != columns.size:
        raise ValueError(f"weights must have shape (B, {columns.size}) for the bias-free {obs_dim}->{tuple(hidden)}->{out_dim} MLP, got {weights.shape}")
    params = np.zeros((weights.shape[0], num_params(obs_dim, out_dim, hidden)))
    params[:, columns] = weights
    return params


def unpack(params: np.ndarray, obs_dim: int, out_dim: int, hidden: Sequence[int] = HIDDEN) -> list[tuple[np.ndarray, np.ndarray]]:
    """Split ``params`` (B, d) into per-layer ``(W (B, in, out), b (B, out))`` copies (float64)."""
    params = np.asarray(params, dtype=np.float64)
    if params.ndim != 2:
        raise ValueError(f"params must be 2-D (B, d), got shape {params.shape}")
    d = num_params(obs_dim, out_dim, hidden)
    if params.shape[1] != d:
        raise ValueError(f"params have {params.shape[1]} columns, the {obs_dim}->{tuple(hidden)}->{out_dim} MLP needs {d}")
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
        output: str = "tanh",
    ):
        if output not in OUTPUTS:
            raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}")
        self.obs_dim, self.out_dim, self.discrete, self.output = int(obs_dim), int(out_dim), bool(discrete), output
        self.hidden = tuple(int(h) for h in hidden)
        params = np.asarray(params, dtype=np.float64)
        if params.ndim != 2 or params.shape[1] != num_params(obs_dim, out_dim, self.hidden):
            raise ValueError(
                f"params must have shape (B, {num_params(obs_dim, out_dim, self.hidden)}) for the {obs_dim}->{self.hidden}->{out_dim} MLP, got {params.shape}"
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
        self._clip = (-np.ones((self.out_dim, 1)), np.ones((self.out_dim, 1)))  # output="clip" without bounds: [-1, 1]
        if not self.discrete and (low is not None or high is not None):
            lo = np.broadcast_to(np.asarray(low, dtype=np.float64), (self.out_dim,))
            hi = np.broadcast_to(np.asarray(high, dtype=np.float64), (self.out_dim,))
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo < hi)):
                raise ValueError(f"continuous actions need finite bounds low < high, got {lo}, {hi}")
            self._clip = (lo[:, None].copy(), hi[:, None].copy())
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
                xp.tanh(y, out=y)  # libm's: numpy's tanh differs between its AVX2 and baseline versions
            x = y
        return x if n > 1 else x[:, :1]

    def outputs(self, obs: np.ndarray) -> np.ndarray:
        """Raw network outputs y (n, out_dim) (a new array)."""
        return self.outputs_t(obs).T.copy()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        y = self.outputs_t(obs)
        if self.discrete:
            return _argmax_cols(y)
        if self.output == "clip":
            return np.ascontiguousarray(np.clip(y, *self._clip).T)
        a = xp.tanh(y)
        if self._offset is not None:  # low + (tanh + 1) * (high - low) / 2
            a += 1.0
            a *= self._scale
            a += self._offset
        elif self._scale is not None:  # symmetric bounds: high * tanh
            a *= self._scale
        return np.ascontiguousarray(a.T)


def forward(params: np.ndarray, obs: np.ndarray, out_dim: int, hidden: Sequence[int] = HIDDEN) -> np.ndarray:
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
    output: str = "tanh",
) -> np.ndarray:
    """Actions of B members on their own observations (B, obs_dim).

    Discrete: int64 (B,) argmax of the outputs. Continuous: float64 (B, out_dim),
    ``tanh`` of the outputs mapped onto ``[low, high]`` if given, or (``output="clip"``) the
    outputs clipped to them. For a rollout, build a :class:`BatchPolicy` once instead (this
    unpacks the parameters on every call).
    """
    obs = np.asarray(obs)
    pol = BatchPolicy(params, obs.shape[1], out_dim, discrete=discrete, hidden=hidden, low=low, high=high, output=output)
    return pol(obs)


# ------------------------------------------------------------------ observation normalisation
#: Default lower bound of the variance used to scale an observation coordinate
#: (``policy.obs_var_floor``; Salimans et al. 2017's 1e-2): a coordinate that barely moves during the
#: warm-up is not blown up by 1/std. ARS (its paper's code: std < 1e-7 counts as infinite;
#: sb3-contrib's VecNormalize: var + 1e-8) effectively has none, and on Hopper that matters: with
#: statistics frozen after 5 generations of falling hoppers, several coordinates' variances sit
#: below 1e-2, the floor shrinks them, and ARS V2-t reached a mean-policy return of 622 (mean of 40
#: seeds, 1,600 episodes) against 1,809 with ARS's 1e-8 (20 seeds) and sb3-contrib's 1,528 (20
#: seeds; docs/ars.md, "What freezing cost on Hopper"). The ARS V2 presets therefore set 1e-8.
OBS_VAR_FLOOR = 1e-2


def fold_normalizer(params: np.ndarray, obs_dim: int, out_dim: int, hidden: Sequence[int], mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Parameters (B, d) whose policy on raw observations equals ``params``' policy on ``(obs - mean) / std``.

    Only the first layer changes (see the module docstring); a new array is returned.
    """
    params = np.array(params, dtype=np.float64, ndmin=2)
    d = num_params(obs_dim, out_dim, hidden)
    if params.shape[1] != d:
        raise ValueError(f"params have {params.shape[1]} columns, the {obs_dim}->{tuple(hidden)}->{out_dim} MLP needs {d}")
    h1 = int(hidden[0]) if len(hidden) else int(out_dim)
    mean = np.asarray(mean, dtype=np.float64).reshape(obs_dim)
    std = np.asarray(std, dtype=np.float64).reshape(obs_dim)
    n = params.shape[0]
    k = obs_dim * h1
    W1 = params[:, :k].reshape(n, obs_dim, h1)
    params[:, k : k + h1] -= np.einsum("i,bij->bj", mean / std, W1)
    params[:, :k] = (W1 / std[None, :, None]).reshape(n, k)
    return params


class NormalizerChange:
    """The affine map T of flat parameter vectors that keeps a policy's function across a change of statistics.

    A policy's first layer sees ``(obs - mean0) / std0``: pre-activation ``((obs - mean0) / std0) @ W1 + b1``.
    Under ``(mean1, std1)`` the same function has ``W1' = diag(std1 / std0) W1`` (row ``i`` of W1, the
    weights of input ``i``, times ``std1_i / std0_i``) and ``b1' = b1 + ((mean1 - mean0) / std0) @ W1``; every
    other parameter stays. T is affine, ``theta' = A theta + c``, with A block-triangular (b1' depends on b1
    with coefficient 1 and on W1): ``log|det A| = h1 * sum_i log(std1_i / std0_i)`` (:attr:`log_det`).

    Exact only for the full parameter vector of :func:`num_params`' layout (``policy.bias=true``): without a
    bias to take it, the offset of a change of mean cannot be re-expressed. Every row is mapped on its own, by
    elementwise operations in a fixed order, so a row's image never depends on the rows mapped with it (an
    archive holding the same member twice maps it to the same bits twice). ``then`` composes two changes into
    the one from the first's statistics to the second's (what an archived distribution keeps: its own
    statistics and today's, :class:`imix_cli.core.distributions.AffinePushforward`).
    """

    def __init__(self, obs_dim: int, out_dim: int, hidden: Sequence[int], mean0, std0, mean1, std1):
        self.obs_dim, self.out_dim, self.hidden = int(obs_dim), int(out_dim), tuple(int(h) for h in hidden)
        self.h1 = self.hidden[0] if self.hidden else self.out_dim
        self.dim = num_params(self.obs_dim, self.out_dim, self.hidden)
        shape = (self.obs_dim,)
        self.mean0, self.std0, self.mean1, self.std1 = (np.array(v, dtype=np.float64).reshape(shape) for v in (mean0, std0, mean1, std1))
        if not (np.all(np.isfinite(self.mean0)) and np.all(np.isfinite(self.mean1)) and np.all(self.std0 > 0) and np.all(self.std1 > 0)
                and np.all(np.isfinite(self.std0)) and np.all(np.isfinite(self.std1))):  # fmt: skip
            raise ValueError("NormalizerChange: statistics must be finite, standard deviations > 0")
        self.ratio = self.std1 / self.std0  # row i of W1 scales by this
        self.shift = (self.mean1 - self.mean0) / self.std0  # b1 moves by shift @ W1 (the old W1)
        self.log_det = float(self.h1 * xp.dot(np.ones(self.obs_dim), xp.log(self.ratio)))

    def _checked(self, x) -> np.ndarray:
        x = np.array(x, dtype=np.float64, ndmin=2)  # a copy: the caller's array is never changed
        if x.ndim != 2 or x.shape[1] != self.dim:
            raise ValueError(f"NormalizerChange: parameters of shape {x.shape}, expected (n, {self.dim})")
        return x

    def _bias_move(self, W1: np.ndarray) -> np.ndarray:
        """``shift @ W1`` for each row's W1 (n, obs_dim, h1), summed over inputs in order."""
        move = np.zeros((W1.shape[0], self.h1))
        for i in range(self.obs_dim):
            move += self.shift[i] * W1[:, i, :]
        return move

    def forward(self, x) -> np.ndarray:
        """T(x): parameter rows (n, d) under the old statistics -> the same policies under the new (a new array)."""
        x = self._checked(x)
        n, k = x.shape[0], self.obs_dim * self.h1
        W1 = x[:, :k].reshape(n, self.obs_dim, self.h1)
        x[:, k : k + self.h1] += self._bias_move(W1)  # with the old W1
        x[:, :k] = (W1 * self.ratio[None, :, None]).reshape(n, k)
        return x

    def inverse(self, y) -> np.ndarray:
        """T^-1(y): parameter rows under the new statistics -> the same policies under the old (a new array)."""
        y = self._checked(y)
        n, k = y.shape[0], self.obs_dim * self.h1
        W1 = y[:, :k].reshape(n, self.obs_dim, self.h1) / self.ratio[None, :, None]  # the old W1
        y[:, :k] = W1.reshape(n, k)
        y[:, k : k + self.h1] -= self._bias_move(W1)
        return y

    def then(self, later: NormalizerChange) -> NormalizerChange:
        """The change from this one's old statistics to ``later``'s new ones (``later`` starts where this one ends)."""
        return NormalizerChange(self.obs_dim, self.out_dim, self.hidden, self.mean0, self.std0, later.mean1, later.std1)

    def to_state(self) -> dict:
        """The layout and the two statistics (checkpoints: data, not pickles)."""
        return {
            "obs_dim": self.obs_dim, "out_dim": self.out_dim, "hidden": list(self.hidden),
            "mean0": self.mean0.copy(), "std0": self.std0.copy(), "mean1": self.mean1.copy(), "std1": self.std1.copy(),
        }  # fmt: skip

    @classmethod
    def from_state(cls, state: dict) -> NormalizerChange:
        return cls(int(state["obs_dim"]), int(state["out_dim"]), [int(h) for h in state["hidden"]], state["mean0"], state["std0"], state["mean1"],
                   state["std1"])  # fmt: skip

    def __repr__(self) -> str:
        return f"NormalizerChange(obs_dim={self.obs_dim}, hidden={self.hidden}, out_dim={self.out_dim}, log_det={self.log_det:.4g})"


class ObsNormalizer:
    """Running mean and std of observations: frozen after ``warmup`` generations, or (``freeze=False``) updated
    for the whole run (module docstring).

    ``add(sums, sumsqs, counts)`` takes per-member sums over each episode's observations (in
    member order, so the statistics do not depend on how the episodes were split over
    processes); ``end_generation()`` closes a generation and, with ``freeze``, freezes the statistics after the
    ``warmup``-th. A frozen normaliser ignores ``add``: nothing can change it any more. :attr:`warming`: the
    warm-up is not over (the runner does not mix).
    """

    def __init__(self, obs_dim: int, warmup: int, var_floor: float = OBS_VAR_FLOOR, freeze: bool = True):
        if warmup < 1:
            raise ValueError(f"warmup must be >= 1 generation, got {warmup}")
        if not (np.isfinite(var_floor) and var_floor > 0):
            raise ValueError(f"var_floor must be a finite number > 0, got {var_floor}")
        self.obs_dim, self.warmup, self.var_floor, self.freeze = int(obs_dim), int(warmup), float(var_floor), bool(freeze)
        self.count = 0
        self.sum = np.zeros(self.obs_dim)
        self.sumsq = np.zeros(self.obs_dim)
        self.generations = 0

    def to_state(self) -> dict:
        """Its statistics as arrays and scalars (checkpoints: data, not pickles)."""
        return {
            "obs_dim": self.obs_dim,
            "warmup": self.warmup,
            "var_floor": self.var_floor,
            "freeze": self.freeze,
            "count": self.count,
            "sum": self.sum.copy(),
            "sumsq": self.sumsq.copy(),
            "generations": self.generations,
        }

    @classmethod
    def from_state(cls, state: dict) -> ObsNormalizer:
        norm = cls(int(state["obs_dim"]), int(state["warmup"]), float(state.get("var_floor", OBS_VAR_FLOOR)),  # older checkpoints: the defaults
                   bool(state.get("freeze", True)))  # fmt: skip
        norm.count, norm.generations = int(state["count"]), int(state["generations"])
        norm.sum, norm.sumsq = np.asarray(state["sum"], dtype=np.float64), np.asarray(state["sumsq"], dtype=np.float64)
        if norm.sum.shape != (norm.obs_dim,) or norm.sumsq.shape != (norm.obs_dim,):
            raise ValueError(f"ObsNormalizer state: statistics of shape {norm.sum.shape}, expected ({norm.obs_dim},)")
        return norm

    @property
    def warming(self) -> bool:
        """The warm-up is not over: no mixing, nothing archived."""
        return self.generations < self.warmup

    @property
    def frozen(self) -> bool:
        return self.freeze and not self.warming

    def add(self, sums: np.ndarray, sumsqs: np.ndarray, counts: np.ndarray) -> None:
        if self.frozen:
            return
        sums, sumsqs = np.asarray(sums, np.float64).reshape(-1, self.obs_dim), np.asarray(sumsqs, np.float64).reshape(-1, self.obs_dim)
        for s, q, c in zip(sums, sumsqs, np.asarray(counts).reshape(-1)):
            if c > 0 and np.all(np.isfinite(s)) and np.all(np.isfinite(q)):
                self.sum += s
                self.sumsq += q
                self.count += int(c)

    def end_generation(self) -> None:
        self.generations += 1

    @property
    def mean(self) -> np.ndarray:
        return self.sum / self.count if self.count else np.zeros(self.obs_dim)

    @property
    def std(self) -> np.ndarray:
        if not self.count:
            return np.ones(self.obs_dim)
        var = np.maximum(self.sumsq / self.count - self.mean**2, 0.0)
        return np.sqrt(np.maximum(var, self.var_floor))

    def fold(self, params: np.ndarray, out_dim: int, hidden: Sequence[int]) -> np.ndarray:
        """``params`` with the current statistics folded in (:func:`fold_normalizer`)."""
        return fold_normalizer(params, self.obs_dim, out_dim, hidden, self.mean, self.std)

    def change(self, mean0: np.ndarray, std0: np.ndarray, out_dim: int, hidden: Sequence[int]) -> NormalizerChange:
        """The :class:`NormalizerChange` from statistics ``(mean0, std0)`` to the current ones."""
        return NormalizerChange(self.obs_dim, out_dim, hidden, mean0, std0, self.mean, self.std)


# ------------------------------------------------------------------ one policy
def policy_output(params: np.ndarray, obs: np.ndarray, out_dim: int, hidden: Sequence[int] = HIDDEN) -> np.ndarray:
    """Raw outputs of ONE policy: ``params`` (d,) on one observation (obs_dim,) -> (out_dim,), or on
    several (T, obs_dim) -> (T, out_dim). :func:`forward` is the batched form (one member per row)."""
    params, obs = np.asarray(params, dtype=np.float64), np.asarray(obs, dtype=np.float64)
    if params.ndim != 1:
        raise ValueError(f"params must be one policy's (d,) vector, got shape {params.shape}; forward() takes (B, d)")
    rows = np.atleast_2d(obs)
    y = forward(np.broadcast_to(params, (rows.shape[0], params.shape[0])), rows, out_dim, hidden)
    return y[0] if obs.ndim == 1 else y


def policy_action(params: np.ndarray, obs: np.ndarray, out_dim: int, discrete: bool = True, hidden: Sequence[int] = HIDDEN, low=None, high=None, output="tanh"):
    """The action of ONE policy ``params`` (d,) on one observation (obs_dim,): an int (discrete: the
    argmax of the outputs) or an (out_dim,) array (continuous, as :func:`act`); with (T, obs_dim)
    observations, one action per row. Saved policies: ``np.load("policy_0_mean.npz")["params"]``."""
    params, obs = np.asarray(params, dtype=np.float64), np.asarray(obs, dtype=np.float64)
    if params.ndim != 1:
        raise ValueError(f"params must be one policy's (d,) vector, got shape {params.shape}; act() takes (B, d)")
    rows = np.atleast_2d(obs)
    a = act(np.broadcast_to(params, (rows.shape[0], params.shape[0])), rows, out_dim, discrete, hidden, low, high, output)
    if obs.ndim == 1:
        return int(a[0]) if discrete else a[0]
    return a
