"""The ask/tell base class shared by every evolution strategy in imix.

An ES here sees only two things: its current search distribution, and the
(samples, fitness) of the generation it is told. It never knows whether a
member was freshly drawn or reused by importance mixing -- that is what lets
:mod:`imix_cli.mixing` stay independent of the algorithms.

Fitness is *maximised*. Before an ES sees it, :meth:`EvolutionStrategy.tell`
turns raw fitness into per-member *utilities* (higher is better) through
weight decay and centred-rank fitness shaping, as in the paper's section 4.1:

``weight_decay_form="estool"`` (default)
    The authors' estool-derived code: centred ranks of the raw fitness, then
    -w * mean(theta^2) is added to the ranks. The paper's published curves come from
    this form (README, "Which weight decay").
``weight_decay_form="paper"``
    The paper's text: the penalty -w * ||theta||^2 is added to each raw fitness,
    then the penalised fitness is turned into centred ranks.

Tied fitness values are ranked in a random order keyed on the members' parameters
(:func:`centered_ranks`, :func:`member_keys`), so no ES depends on the order of the
population it is told, and no tiny term (the estool penalty) decides every tie.

Non-finite fitness (NaN, +-inf from a user's environment) is ranked last
(worst) and counted in :attr:`EvolutionStrategy.nonfinite_fitness_count`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

WEIGHT_DECAY_FORMS = ("paper", "estool")


def _tie_groups(values: np.ndarray):
    """``order, starts, ends, group_of``: ``values[order]`` ascending, tied runs ``[starts[g], ends[g])``.

    ``group_of[i]`` is the run holding position i of the sorted order.
    """
    order = np.argsort(values, kind="stable")
    ascending = values[order]
    first = np.ones(values.shape[0], dtype=bool)
    first[1:] = ascending[1:] != ascending[:-1]
    starts = np.flatnonzero(first)
    ends = np.append(starts[1:], values.shape[0])
    return order, starts, ends, np.cumsum(first) - 1


def centered_ranks(values: np.ndarray, tie_break: np.ndarray | None = None) -> np.ndarray:
    """Map values to ranks scaled into [-0.5, 0.5] (the worst gets -0.5, the best +0.5).

    Ties never depend on the order of the values. Without ``tie_break``, tied values get
    the average of the ranks they span ("fractional ranking"). With ``tie_break`` (one key
    per value), tied values are ordered by their keys -- :meth:`EvolutionStrategy.utilities`
    passes a hash of each member's parameters, i.e. a random order that is a function of the
    members, not of where they stand in the population.

    Why it matters: with importance mixing a generation lists its reused members first, and
    on CartPole ~40 of 50 members tie at the maximum return; breaking ties by position put
    the reused members at the bottom of the tie, i.e. made the fresh rule-2 draws (which sit
    where the new density exceeds the old) the elites, and pushed the distribution outward
    (issue 11: CMA-ES + EIM ended at 181.8 instead of 196, sigma 3x too large). And why the
    ES breaks ties at random rather than sharing ranks: the estool weight decay is then added
    to the ranks, and between exactly equal ranks that tiny penalty decides the order --
    CEM and CMA-ES then select the smallest members of every tie, which pulled CMA-ES on
    CartPole to a mean return of 60 (measured, 5 seeds).
    """
    values = np.asarray(values, dtype=np.float64)
    n = values.shape[0]
    if n == 1:
        return np.zeros(1)
    ranks = np.empty(n, dtype=np.float64)
    if tie_break is not None:
        ranks[np.lexsort((tie_break, values))] = np.arange(n, dtype=np.float64)
    else:
        order, starts, ends, group_of = _tie_groups(values)
        ranks[order] = ((starts + ends - 1) / 2.0)[group_of]
    return ranks / (n - 1) - 0.5


_HASH_MULTIPLIERS: dict[int, np.ndarray] = {}


def member_keys(samples: np.ndarray) -> np.ndarray:
    """A pseudo-random 64-bit key per row that depends only on the row's values (its float64 bits).

    A fixed random odd multiplier per coordinate, a wrapping sum over the row, then
    splitmix64's finaliser: two members get the same key only if their parameters are equal
    (or by a 2^-64 accident), and the keys carry no information about the members' size or
    position, so ordering tied members by them is a random tie-break that no reordering of
    the population can change.
    """
    bits = np.ascontiguousarray(samples, dtype=np.float64).view(np.uint64)
    dim = bits.shape[1]
    mult = _HASH_MULTIPLIERS.get(dim)
    if mult is None:
        mult = np.random.default_rng(0x5EED).integers(0, 2**64, size=dim, dtype=np.uint64, endpoint=False) | np.uint64(1)
        _HASH_MULTIPLIERS[dim] = mult
    h = (bits * mult).sum(axis=1, dtype=np.uint64)
    h ^= h >> np.uint64(30)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(27)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(31)
    return h


def rank_weights(utilities: np.ndarray, weights_by_rank: np.ndarray) -> np.ndarray:
    """The weight of each member when the best gets ``weights_by_rank[0]``, the next ``[1]``, ...

    ``weights_by_rank`` has one entry per member (pad with zeros for non-elites). Members with
    tied utilities share equally the weights of the rank positions they occupy, so the
    result does not depend on the order of the members (see :func:`centered_ranks`). This
    is what selection-based ES (CEM's elites, CMA-ES's recombination) use instead of an
    ``argsort`` that would break ties by position.
    """
    utilities = np.asarray(utilities, dtype=np.float64)
    n = utilities.shape[0]
    weights_by_rank = np.asarray(weights_by_rank, dtype=np.float64)
    if weights_by_rank.shape != (n,):
        raise ValueError(f"weights_by_rank must have shape ({n},), got {weights_by_rank.shape}")
    order, starts, ends, group_of = _tie_groups(-utilities)  # best first
    cumulative = np.concatenate([[0.0], np.cumsum(weights_by_rank)])
    group_mean = (cumulative[ends] - cumulative[starts]) / (ends - starts)
    weights = np.empty(n, dtype=np.float64)
    weights[order] = group_mean[group_of]
    return weights


class Adam:
    """Adam ascent on a parameter vector (Kingma & Ba 2015), as used by OpenES and SNES.

    ``step(grad)`` returns the increment to *add* to the parameters (gradient ascent).
    """

    def __init__(self, dim: int, lr: float, beta1: float = 0.99, beta2: float = 0.999, epsilon: float = 1e-8):
        self.lr, self.beta1, self.beta2, self.epsilon = lr, beta1, beta2, epsilon
        self.m = np.zeros(dim)
        self.v = np.zeros(dim)
        self.t = 0

    def step(self, grad: np.ndarray) -> np.ndarray:
        self.t += 1
        self.m = self.beta1 * self.m + (1.0 - self.beta1) * grad
        self.v = self.beta2 * self.v + (1.0 - self.beta2) * grad * grad
        step_size = self.lr * np.sqrt(1.0 - self.beta2**self.t) / (1.0 - self.beta1**self.t)
        return step_size * self.m / (np.sqrt(self.v) + self.epsilon)


class EvolutionStrategy(ABC):
    """Base class: owns the public ``ask``/``tell``; subclasses fill in ``distribution`` and ``_update``.

    Parameters (shared by every ES; pycma-style, documented where defined)
    ----------
    dim : int
        Number of optimised parameters d.
    popsize : int, default 50
        Population size N (paper 4.1).
    sigma : float, default 0.25
        Initial standard deviation; the initial covariance is sigma^2 I (paper 4.1).
    lr : float, default 0.01
        Adam learning rate of the gradient-based ES (OpenES, SNES); ignored by CEM and CMA-ES.
    weight_decay : float, default 0.05
        Weight-decay coefficient w; 0 disables it.
    weight_decay_form : {"estool", "paper"}, default "estool"
        How the penalty enters the utilities; see the module docstring.
    mean : array-like of shape (d,), optional
        Initial mean; zeros by default.
    """

    #: short name used by configs and CSVs ("openes", "snes", "cem", "cmaes")
    name: str = ""

    def __init__(
        self,
        dim: int,
        popsize: int = 50,
        sigma: float = 0.25,
        lr: float = 0.01,
        weight_decay: float = 0.05,
        weight_decay_form: str = "estool",
        mean=None,
    ):
        if dim < 1:
            raise ValueError(f"dim must be >= 1, got {dim}")
        if popsize < 2:
            raise ValueError(f"popsize must be >= 2, got {popsize}")
        if not sigma > 0:
            raise ValueError(f"sigma must be > 0, got {sigma}")
        if not lr > 0:
            raise ValueError(f"lr must be > 0, got {lr}")
        if weight_decay < 0:
            raise ValueError(f"weight_decay must be >= 0, got {weight_decay}")
        if weight_decay_form not in WEIGHT_DECAY_FORMS:
            raise ValueError(f"weight_decay_form must be one of {WEIGHT_DECAY_FORMS}, got {weight_decay_form!r}")
        self.dim = int(dim)
        self.popsize = int(popsize)
        self.sigma = float(sigma)
        self.lr = float(lr)
        self.weight_decay = float(weight_decay)
        self.weight_decay_form = weight_decay_form
        self.initial_mean = np.zeros(self.dim) if mean is None else np.array(mean, dtype=np.float64).reshape(self.dim)
        self.generation = 0
        self.nonfinite_fitness_count = 0

    # ------------------------------------------------------------------ public API
    @property
    @abstractmethod
    def distribution(self):
        """The current search distribution (a DiagonalGaussian or FullGaussian)."""

    def ask(self, rng: np.random.Generator) -> np.ndarray:
        """Draw a fresh generation of ``popsize`` independent samples (no antithetic pairs)."""
        return self.distribution.sample(self.popsize, rng)

    def tell(self, samples, fitness) -> None:
        """Update the search distribution from a generation's samples and their raw fitness (maximised).

        ``samples`` may mix fresh draws and members reused from earlier generations; the
        ES treats them alike. Its number of rows may differ from ``popsize``.
        """
        samples = np.asarray(samples, dtype=np.float64)
        fitness = np.asarray(fitness, dtype=np.float64).reshape(-1)
        if samples.ndim != 2 or samples.shape[1] != self.dim:
            raise ValueError(f"samples must have shape (n, {self.dim}), got {samples.shape}")
        if samples.shape[0] != fitness.shape[0]:
            raise ValueError(f"got {samples.shape[0]} samples but {fitness.shape[0]} fitness values")
        if samples.shape[0] < 2:
            raise ValueError("tell needs at least 2 samples")
        self._update(samples, self.utilities(samples, fitness))
        self.generation += 1

    def utilities(self, samples: np.ndarray, fitness: np.ndarray) -> np.ndarray:
        """Weight decay + centred-rank shaping; non-finite fitness ranks last. Higher is better."""
        finite = np.isfinite(fitness)
        self.nonfinite_fitness_count += int(np.count_nonzero(~finite))
        fitness = np.where(finite, fitness, -np.inf)
        keys = member_keys(samples)  # ties: a random order that the population's order cannot change
        if self.weight_decay_form == "paper":
            penalised = fitness - self.weight_decay * np.einsum("ij,ij->i", samples, samples)
            return centered_ranks(penalised, keys)
        return centered_ranks(fitness, keys) - self.weight_decay * np.mean(samples * samples, axis=1)

    # ------------------------------------------------------------ for subclasses
    @abstractmethod
    def _update(self, samples: np.ndarray, utilities: np.ndarray) -> None:
        """Move the search distribution; ``utilities`` are higher-is-better, one per row of ``samples``."""

    @property
    def mean(self) -> np.ndarray:
        """Mean of the current search distribution."""
        return self.distribution.mean
