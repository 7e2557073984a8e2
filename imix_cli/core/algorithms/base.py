"""The ask/tell base class shared by every evolution strategy in imix.

An ES here sees only two things: its current search distribution, and the
(samples, fitness) of the generation it is told. It never knows whether a
member was freshly drawn or reused by importance mixing -- that is what lets
:mod:`imix_cli.core.mixing` stay independent of the algorithms.

Fitness is *maximised*. Before an ES sees it, :meth:`EvolutionStrategy.tell`
turns raw fitness into per-member *utilities* (higher is better) through
weight decay and centred-rank fitness shaping, as in the paper's section 4.1:

``weight_decay_form="estool"`` (default)
    The authors' estool-derived code: centred ranks of the raw fitness, then
    -w * mean(theta^2) is added to the ranks. The paper's published curves come from
    this form (docs/reproducing.md, "Which weight decay").
``weight_decay_form="paper"``
    The paper's text: the penalty -w * ||theta||^2 is added to each raw fitness,
    then the penalised fitness is turned into centred ranks.

Both forms, and the fitness shaping (centred ranks), are pieces registered by name
(:data:`WEIGHT_DECAY_FORMS`, :data:`FITNESS_SHAPINGS`) and chosen by the ES's :class:`Params`,
the one record of the hyper-parameters every ES shares (documented field by field, with the
paper's values as defaults); each ES extends it with its own options.

Tied fitness values are ranked in a random order keyed on the members' parameters
(:func:`centered_ranks`, :func:`member_keys`), so no ES depends on the order of the
population it is told, and no tiny term (the estool penalty) decides every tie.

Non-finite fitness (NaN, +-inf from a user's environment) is ranked last
(worst) and counted in :attr:`EvolutionStrategy.nonfinite_fitness_count`.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, replace
from dataclasses import fields as fields_of
from typing import NamedTuple

import numpy as np
from numba import njit

from imix_cli.core.bounds import Bound
from imix_cli.core.distributions import DiagonalGaussian
from imix_cli.core.numerics import elementary as el
from imix_cli.core.numerics import linalg_kernels as lk


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
    (measured: CMA-ES + EIM ended at 181.8 instead of 196, sigma 3x too large). And why the
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


def hash_multipliers(dim: int) -> np.ndarray:
    """:func:`member_keys`' fixed random odd multiplier per coordinate, for rows of ``dim`` numbers
    (drawn once per dimension and kept; :mod:`imix_cli.running.loop.compiled_loop` hashes with the same array)."""
    mult = _HASH_MULTIPLIERS.get(dim)
    if mult is None:
        mult = np.random.default_rng(0x5EED).integers(0, 2**64, size=dim, dtype=np.uint64, endpoint=False) | np.uint64(1)
        _HASH_MULTIPLIERS[dim] = mult
    return mult


def member_keys(samples: np.ndarray, salt: int = 0) -> np.ndarray:
    """A pseudo-random 64-bit key per row that depends only on the row's values (its float64 bits) and ``salt``.

    A fixed random odd multiplier per coordinate, a wrapping sum over the row, ``salt`` times
    splitmix64's increment added, then splitmix64's finaliser: two members get the same key
    only if their parameters are equal (or by a 2^-64 accident), and the keys carry no
    information about the members' size or position, so ordering tied members by them is a
    random tie-break that no reordering of the population can change.

    Why a salt. :meth:`EvolutionStrategy.utilities` passes ``generation + 1``, so a member's
    place inside a tie is drawn anew every generation. With the parameters alone as the key, a
    member reused by importance mixing kept the same place in every tie it entered, generation
    after generation -- on CartPole, where ~40 of 50 members tie at the maximum return, the same
    few reused members stayed the elites and kept pulling the mean the same way. Measured
    (defaults, 25 seeds, CartPole): CMA-ES + EIM's step size collapsed in 25/25 seeds (median
    final sigma 8.7e-7, three seeds stuck near 100); with the salt it stays near the no-mixing
    value (docs/research/bias.md, "Reused returns and the search").
    """
    bits = np.ascontiguousarray(samples, dtype=np.float64).view(np.uint64)
    h = (bits * hash_multipliers(bits.shape[1])).sum(axis=1, dtype=np.uint64)
    h += np.uint64((salt * 0x9E3779B97F4A7C15) % 2**64)  # splitmix64's increment, salt times (Python ints: no overflow warning)
    h ^= h >> np.uint64(30)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(27)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(31)
    return h


@njit(cache=True)
def member_keys_kernel(samples, mult, salt_term):
    """:func:`member_keys` compiled: ``mult`` is :func:`hash_multipliers`, ``salt_term`` the uint64 ``salt *
    0x9E3779B97F4A7C15`` (wrapping uint64 arithmetic: the same keys)."""
    n, d = samples.shape
    bits = samples.view(np.uint64)
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


@njit(cache=True)
def estool_centered_ranks_kernel(samples, fitness, generation, weight_decay, mult):
    """:meth:`EvolutionStrategy.utilities` compiled, for ``fitness_shaping="centered_ranks"`` and
    ``weight_decay_form="estool"`` and finite ``fitness``: centred ranks (ties ordered by :func:`member_keys`
    salted with ``generation + 1``) minus ``weight_decay * mean(x_i^2)``, with numpy's own summation order
    in the mean (:func:`imix_cli.core.numerics.linalg_kernels.numpy_sum`): the same bits as the Python method."""
    n, d = samples.shape
    keys = member_keys_kernel(samples, mult, np.uint64(generation + 1) * np.uint64(0x9E3779B97F4A7C15))
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
            sq[j] = samples[i, j] * samples[i, j]
        u[i] = u[i] - weight_decay * (lk.numpy_sum(sq) / d)
    return u


def rank_weights(utilities: np.ndarray, weights_by_rank: np.ndarray) -> np.ndarray:
    """The weight of each member when the best gets ``weights_by_rank[0]``, the next ``[1]``, ...

    ``weights_by_rank`` has one entry per member (pad with zeros for non-elites). Members with
    tied utilities share equally the weights of the rank positions they occupy, so the
    result does not depend on the order of the members (see :func:`centered_ranks`). This
    is what selection-based ES (CEM's elites, CMA-ES's recombination) use instead of an
    ``argsort`` that would break ties by position.
    """
    utilities = np.ascontiguousarray(utilities, dtype=np.float64).reshape(-1)
    n = utilities.shape[0]
    weights_by_rank = np.ascontiguousarray(weights_by_rank, dtype=np.float64)
    if weights_by_rank.shape != (n,):
        raise ValueError(f"weights_by_rank must have shape ({n},), got {weights_by_rank.shape}")
    return rank_weights_kernel(utilities, weights_by_rank)


@njit(cache=True)
def rank_weights_kernel(utilities, weights_by_rank):
    """:func:`rank_weights` compiled (its one copy; compiled ES updates call it): the utilities sorted best
    first (stable, NaN last), each run of equal ones given the mean of the weights of the positions it spans;
    the running sum over ``weights_by_rank`` is ``np.cumsum``'s, left to right."""
    n = utilities.shape[0]
    order = np.argsort(-utilities, kind="mergesort")  # np.argsort(kind="stable"): ties keep their order, NaN last
    cumulative = np.empty(n + 1)
    cumulative[0] = 0.0
    acc = 0.0
    for r in range(n):
        acc += weights_by_rank[r]
        cumulative[r + 1] = acc
    weights = np.empty(n)
    start = 0
    while start < n:
        end = start + 1
        while end < n and utilities[order[end]] == utilities[order[end - 1]]:  # a NaN is a run of its own
            end += 1
        mean = (cumulative[end] - cumulative[start]) / (end - start)
        for r in range(start, end):
            weights[order[r]] = mean
        start = end
    return weights


#: Adam's epsilon (Kingma & Ba 2015's default), added to sqrt(v) in every step.
ADAM_EPSILON = 1e-8


class AdamState(NamedTuple):
    """Adam's state for one parameter vector (Kingma & Ba 2015), a field of an ES's state record
    (:class:`CompiledStep`): :func:`adam_step` moves it in place."""

    #: first moment, shape (d,)
    m: np.ndarray
    #: second moment, shape (d,)
    v: np.ndarray
    #: steps taken, int64 of shape (1,) (an array, so that a compiled update can count in place)
    t: np.ndarray

    @classmethod
    def zeros(cls, dim: int) -> AdamState:
        """The state before the first step."""
        return cls(np.zeros(dim), np.zeros(dim), np.zeros(1, dtype=np.int64))


@njit(cache=True)
def adam_step(adam, lr, beta1, beta2, epsilon, grad):
    """One Adam step (Kingma & Ba 2015): ``adam`` (an :class:`AdamState`) in place; returns the increment to
    *add* to the parameters (gradient ascent). Every compiled ES update with Adam calls it."""
    m, v = adam.m, adam.v
    adam.t[0] += 1
    t = float(adam.t[0])
    step_size = lr * math.sqrt(1.0 - el.pow(beta2, t)) / (1.0 - el.pow(beta1, t))
    out = np.empty(grad.shape[0])
    for j in range(grad.shape[0]):
        m[j] = beta1 * m[j] + (1.0 - beta1) * grad[j]
        v[j] = beta2 * v[j] + (1.0 - beta2) * grad[j] * grad[j]
        out[j] = step_size * m[j] / (math.sqrt(v[j]) + epsilon)
    return out


def _is_record(value) -> bool:
    return isinstance(value, tuple) and hasattr(value, "_fields")


def flatten_record(record, prefix: str = "") -> dict:
    """An ES's state record (a NamedTuple of arrays, nested records allowed) as a flat state dict: a copy of
    each array under its dotted path (``mean``, ``mu_adam.m``, ...). The checkpoint of an ES is this dict."""
    out = {}
    for name, value in zip(record._fields, record):
        if _is_record(value):
            out.update(flatten_record(value, f"{prefix}{name}."))
        else:
            out[f"{prefix}{name}"] = np.array(value, copy=True)
    return out


def record_from_flat(template, state: dict, prefix: str = ""):
    """The record of ``template``'s type read back from :func:`flatten_record`'s dict: every array present,
    of ``template``'s shape and dtype (a checkpoint is read from a file: a wrong one is refused here, by a
    KeyError or a ValueError naming it, rather than as a broadcasting error generations later)."""
    fields = []
    for name, ref in zip(template._fields, template):
        if _is_record(ref):
            fields.append(record_from_flat(ref, state, f"{prefix}{name}."))
            continue
        key = f"{prefix}{name}"
        if key not in state:
            raise KeyError(f"state has no {key!r}")
        value = np.asarray(state[key])
        if value.shape != ref.shape or value.dtype != ref.dtype:
            raise ValueError(f"state {key!r} is {value.dtype}{list(value.shape)}, expected {ref.dtype}{list(ref.shape)}")
        fields.append(np.array(value, copy=True))
    return type(template)(*fields)


def copy_record(record):
    """A deep copy of a state record (its arrays copied): the compiled loop moves the copy and hands it back."""
    return type(record)(*(copy_record(v) if _is_record(v) else v.copy() for v in record))


# ------------------------------------------------------------------------ pluggable pieces
#: Fitness shaping: ``shape(values, tie_break) -> utilities`` (higher is better), by name
#: (:attr:`Params.fitness_shaping`). Register another one here to select it by name.
FITNESS_SHAPINGS: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {"centered_ranks": centered_ranks}


class WeightDecayForm(ABC):
    """How the weight-decay penalty enters the utilities (:attr:`Params.weight_decay_form`)."""

    @abstractmethod
    def apply(self, samples: np.ndarray, fitness: np.ndarray, weight_decay: float, shape: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """The utilities of ``samples`` from their fitness (-inf where non-finite); ``shape`` is the fitness shaping."""


class PaperWeightDecay(WeightDecayForm):
    """The paper's text: -w * ||theta||^2 is added to each raw fitness, then the result is shaped."""

    def apply(self, samples, fitness, weight_decay, shape):
        return shape(fitness - weight_decay * np.einsum("ij,ij->i", samples, samples))


class EstoolWeightDecay(WeightDecayForm):
    """The authors' estool-derived code: the raw fitness is shaped, then -w * mean(theta^2) is added."""

    def apply(self, samples, fitness, weight_decay, shape):
        return shape(fitness) - weight_decay * np.mean(samples * samples, axis=1)


#: ``weight_decay_form`` name -> its form (the config's choices, in this order). Register
#: another one here to select it by name.
WEIGHT_DECAY_FORMS: dict[str, WeightDecayForm] = {"paper": PaperWeightDecay(), "estool": EstoolWeightDecay()}


# ------------------------------------------------------------------------------ parameters
#: The largest initial standard deviation: the initial variance sigma^2 must be a finite float64 (sqrt(max) ~ 1.34e154);
#: above it the first tell divided by an infinite variance and raised deep inside, losing the generation.
MAX_SIGMA = 1e154

#: The range of each numeric field of :class:`Params`, checked when a record is made and by ``imix run``'s config
#: (:mod:`imix_cli.running.config.keys`): one copy of the numbers (:mod:`imix_cli.core.bounds`).
PARAM_BOUNDS = {
    "popsize": Bound(2, integer=True),  # an integer: 2.5 members was silently 2
    "sigma": Bound(0, low_inclusive=False, high=MAX_SIGMA),
    "lr": Bound(0, low_inclusive=False),
    "weight_decay": Bound(0),
}


@dataclass(frozen=True)
class Params:
    """The hyper-parameters every ES shares; the defaults are the paper's (section 4.1).

    This record is the one place those defaults are written down: ``imix run``'s key declarations
    (:mod:`imix_cli.running.config.keys`) read them from it, and conf/config.yaml is generated from those. Each ES extends it with its own options
    (``OpenES.Params``, ``CEM.Params``, ...): build one with ``CEM.Params(popsize=20,
    style="cemrl")``, or pass the fields to the ES or to ``make_es`` as keywords. Values are
    checked when the record is made (ValueError naming the field).
    """

    #: Population size N (paper 4.1); >= 2.
    popsize: int = 50
    #: Initial standard deviation; the initial covariance is sigma^2 I (paper 4.1); > 0.
    sigma: float = 0.25
    #: Adam learning rate of the gradient-based ES (OpenES, SNES); ignored by CEM and CMA-ES; > 0.
    lr: float = 0.01
    #: Weight-decay coefficient w; 0 disables it; >= 0.
    weight_decay: float = 0.05
    #: How the penalty enters the utilities, a key of :data:`WEIGHT_DECAY_FORMS`: "estool" (the
    #: authors' code: the paper's published curves) or "paper" (the paper's text); see the
    #: module docstring.
    weight_decay_form: str = "estool"
    #: Fitness shaping, a key of :data:`FITNESS_SHAPINGS`; "centered_ranks" (:func:`centered_ranks`).
    fitness_shaping: str = "centered_ranks"

    def __post_init__(self):
        for name, bound in PARAM_BOUNDS.items():  # the bounds imix run checks its keys with
            bound.check(name, getattr(self, name))
        if self.weight_decay_form not in WEIGHT_DECAY_FORMS:
            raise ValueError(f"weight_decay_form must be one of {tuple(WEIGHT_DECAY_FORMS)}, got {self.weight_decay_form!r}")
        if self.fitness_shaping not in FITNESS_SHAPINGS:
            raise ValueError(f"fitness_shaping must be one of {tuple(FITNESS_SHAPINGS)}, got {self.fitness_shaping!r}")


class CompiledStep(NamedTuple):
    """An ES's update as a numba function over its state record (:meth:`EvolutionStrategy.compiled_step`).

    Why: the compiled generation loop (:mod:`imix_cli.running.loop.compiled_loop`) runs many generations of
    a seed in one compiled call, so it needs the ES's update as compiled code; the ES's own
    :meth:`~EvolutionStrategy._update` calls the same function, so the update is written once and
    both loops give the same bits.

    The ES's search state is one record, :attr:`EvolutionStrategy.state`: a NamedTuple of numpy arrays
    (records nested in it allowed, e.g. :class:`AdamState`), which numba types field by field. Its first two
    fields are ``mean`` and ``std``, the diagonal Gaussian searched (the loop mixes and archives with them);
    the rest are the ES's own (Adam's moments, SNES's log sigma, ...). ``tell``, the compiled loop and the
    checkpoint (:func:`flatten_record`) all read and write that record, by name.

    ``update(samples, utilities, state, constants)`` moves the distribution in place of ``state``'s arrays;
    ``constants`` is a NamedTuple of floats, the hyper-parameters it reads (never written).

    ``mean_weights(utilities, constants)``: the weight of each member in the mean's move
    (:meth:`EvolutionStrategy._mean_weights`, which then runs it too), for an ES whose weights are not its
    utilities (CEM's elite weights); None, the default: the utilities themselves.

    ``full``: for an ES searching a full Gaussian (CMA-ES), whose state is its own (no ``mean``/``std``), the triple
    ``(distribution, probes, most_probes)``: the two compiled functions the loop needs besides the update, and the
    most points ``probes`` writes in a generation (an int, 0: none):
    ``distribution(state) -> (mean, cov, low, log_norm, ok)`` (the Gaussian, its Cholesky factor, log-normaliser; ``ok``
    False: not positive definite) and ``probes(rng, state, constants, out) -> count`` (points to evaluate besides the
    members, :meth:`EvolutionStrategy.probes`). Its ``update`` is then ``update(samples, utilities, fitness,
    probe_fitness, state, constants, mean_weights) -> ok``: it also takes the raw fitness and the probes' (size 0:
    none), writes each member's weight in the mean's move into ``mean_weights`` and returns False when the update
    failed (the Python path records the divergence). None, the default: a diagonal Gaussian.
    """

    update: Callable
    constants: tuple
    mean_weights: Callable | None = None
    full: tuple | None = None


class EvolutionStrategy(ABC):
    """Base class: owns the constructor and the public ``ask``/``tell``; a subclass gives its
    ``Params``, ``_setup``, ``distribution`` and ``_update``.

    ``ES(dim, params=None, *, mean=None, **fields)``

    Parameters
    ----------
    dim : int
        Number of optimised parameters d.
    params : ES.Params, optional
        The hyper-parameters (:class:`Params` and the subclass's own fields); default
        ``ES.Params()``, the paper's.
    mean : array-like of shape (d,), optional
        Initial mean; zeros by default.
    **fields
        Fields of ``ES.Params`` that replace those of ``params``, e.g. ``popsize=20``.

    Notes
    -----
    Every field is also an attribute of the ES (``es.popsize``, ``es.sigma``, ...; ``es.sigma``
    stays the initial value when the ES adapts its step size).
    """

    #: short name used by configs and CSVs ("openes", "snes", "cem", "cmaes")
    name: str = ""
    #: this ES's parameter record (a subclass of :class:`Params` with its own options)
    Params: type[Params] = Params
    #: how its generations are mixed and archived (:class:`imix_cli.core.mixing.generation.GenerationScheme`): None, the
    #: default, for members that are independent draws of :attr:`distribution`; ARS names its mirrored pairs'
    generation_scheme = None
    #: whether :meth:`_update` is linear in the utilities (a sum over members of u_k times a function of the member),
    #: so that ``tell(..., weights=)`` can weight members into it (:mod:`imix_cli.core.mixing.weighted_reuse`): None, no;
    #: "sum" if it sums over the members told (SNES), "mean" if it divides that sum by their number (OpenES)
    weights_utilities: str | None = None

    def __init__(self, dim: int, params: Params | None = None, *, mean=None, **fields):
        if dim < 1:
            raise ValueError(f"dim must be >= 1, got {dim}")
        if params is None:
            params = self.Params(**fields)
        elif not isinstance(params, self.Params):
            raise TypeError(f"{type(self).__name__} takes a {self.Params.__qualname__}, got {type(params).__name__}")
        elif fields:
            params = replace(params, **fields)
        self.params = params
        for f in fields_of(params):
            setattr(self, f.name, getattr(params, f.name))
        self.dim = int(dim)
        self.popsize = int(params.popsize)
        self.sigma = float(params.sigma)
        self.lr = float(params.lr)
        self.weight_decay = float(params.weight_decay)
        self._weight_decay = WEIGHT_DECAY_FORMS[params.weight_decay_form]
        self._shaping = FITNESS_SHAPINGS[params.fitness_shaping]
        self.initial_mean = np.zeros(self.dim) if mean is None else np.array(mean, dtype=np.float64).reshape(self.dim)
        self.generation = 0
        self.nonfinite_fitness_count = 0
        #: c_j of each member of the last generation told, in the mean's move (:meth:`_mean_weights`); None before
        self.mean_weights: np.ndarray | None = None
        self._setup()

    @abstractmethod
    def _setup(self) -> None:
        """Build the initial search state from ``self.params`` (the shared attributes are set)."""

    # ------------------------------------------------------------------ public API
    @property
    @abstractmethod
    def distribution(self):
        """The current search distribution (a DiagonalGaussian or FullGaussian)."""

    def ask(self, rng: np.random.Generator) -> np.ndarray:
        """Draw a fresh generation of ``popsize`` independent samples (no antithetic pairs)."""
        return self.distribution.sample(self.popsize, rng)

    #: Points :meth:`probes` gives per generation (once it gives any): episodes besides the members.
    probe_count = 0

    def probes(self, rng: np.random.Generator) -> np.ndarray | None:
        """Points to evaluate afresh with the next generation besides its members -- never members,
        never reused -- whose returns :meth:`tell` then takes as ``probe_fitness`` (CMA-ES's
        two-point step-size adaptation). None: none (every ES but CMA-ES with TPA)."""
        return None

    #: Added to every step's reward in training (:meth:`training_fitness`): 0 but for ARS's survival-bonus offset.
    reward_offset = 0.0

    def training_fitness(self, returns: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """The fitness the runner tells (and archives) for episodes of these ``returns`` and lengths
        ``steps``: return + :attr:`reward_offset` x length (the compiled loop computes the same). Measurements
        of the distribution mean always report the env's own return."""
        offset = self.reward_offset
        return returns if offset == 0.0 else np.asarray(returns, dtype=np.float64) + offset * np.asarray(steps, dtype=np.float64)

    def tell(self, samples, fitness, weights=None) -> None:
        """Update the search distribution from a generation's samples and their raw fitness (maximised).

        ``samples`` may mix fresh draws and members reused from earlier generations; the
        ES treats them alike. Its number of rows may differ from ``popsize``. ``weights``: one
        importance weight >= 0 per row (an ES with :attr:`weights_utilities` only; :meth:`weighted_utilities`).
        """
        samples = np.asarray(samples, dtype=np.float64)
        fitness = np.asarray(fitness, dtype=np.float64).reshape(-1)
        if samples.ndim != 2 or samples.shape[1] != self.dim:
            raise ValueError(f"samples must have shape (n, {self.dim}), got {samples.shape}")
        if samples.shape[0] != fitness.shape[0]:
            raise ValueError(f"got {samples.shape[0]} samples but {fitness.shape[0]} fitness values")
        if samples.shape[0] < 2:
            raise ValueError("tell needs at least 2 samples")
        utilities = self.utilities(samples, fitness) if weights is None else self.weighted_utilities(samples, fitness, weights)
        self._update(samples, utilities)
        self.mean_weights = self._mean_weights(utilities)
        self.generation += 1

    def weighted_utilities(self, samples: np.ndarray, fitness: np.ndarray, weights) -> np.ndarray:
        """The utilities of a weighted pool (:mod:`imix_cli.core.mixing.weighted_reuse`): centred ranks under the
        self-normalised ``weights`` (:func:`~imix_cli.core.mixing.weighted_reuse.weighted_centered_ranks`), weight decay as
        :meth:`utilities`, each times ``popsize * weight`` (an update that sums, :attr:`weights_utilities` "sum") or
        ``rows * weight`` (one that averages over the rows told, "mean"): the update then estimates the one of a
        generation of ``popsize`` members drawn from the current distribution, and equal weights over ``popsize`` rows
        give :meth:`utilities`."""
        from imix_cli.core.mixing.weighted_reuse import weighted_centered_ranks

        if not self.weights_utilities:
            raise ValueError(f"{self.name or type(self).__name__}'s update is not a weighted sum over its members: tell it no weights")
        if self.params.fitness_shaping != "centered_ranks":
            raise ValueError(f"weights need fitness_shaping='centered_ranks', not {self.params.fitness_shaping!r}")
        w = np.asarray(weights, dtype=np.float64).reshape(-1)
        if w.shape != fitness.shape or not np.all(np.isfinite(w)) or np.any(w < 0) or not w.sum() > 0:
            raise ValueError(f"weights must be {fitness.shape[0]} finite numbers >= 0, not all 0")
        w = w / w.sum()
        u = self._shaped(samples, fitness, lambda values, keys: weighted_centered_ranks(values, w, keys))
        return (self.popsize if self.weights_utilities == "sum" else w.shape[0]) * w * u

    def utilities(self, samples: np.ndarray, fitness: np.ndarray) -> np.ndarray:
        """Weight decay + fitness shaping (``params.weight_decay_form``, ``params.fitness_shaping``);
        non-finite fitness ranks last. Higher is better."""
        return self._shaped(samples, fitness, self._shaping)

    def _shaped(self, samples: np.ndarray, fitness: np.ndarray, shaping) -> np.ndarray:
        """:meth:`utilities` with the fitness shaping ``shaping(values, tie_keys)``: non-finite fitness counted and
        ranked last, ties keyed on the members (salted by generation), the weight-decay form applied."""
        finite = np.isfinite(fitness)
        self.nonfinite_fitness_count += int(np.count_nonzero(~finite))
        fitness = np.where(finite, fitness, -np.inf)
        # ties: a random order that the population's order cannot change, drawn anew each generation
        keys = member_keys(samples, salt=self.generation + 1)
        return self._weight_decay.apply(samples, fitness, self.weight_decay, lambda values: shaping(values, keys))

    # ------------------------------------------------------------ checkpoints
    # A state dict is flat: numpy arrays and JSON scalars under string keys (nested parts use
    # dotted prefixes), so a checkpoint is plain data (.npz + JSON) and never a pickle. It holds
    # only what changes during a run; the constructor's arguments come from the run's config.
    def state_dict(self) -> dict:
        """The ES's mutable state: counters here, the search state from :meth:`_state_dict`."""
        return {"generation": int(self.generation), "nonfinite_fitness_count": int(self.nonfinite_fitness_count), **self._state_dict()}

    def load_state_dict(self, state: dict) -> None:
        """Restore what :meth:`state_dict` returned (on an ES built with the same arguments).

        Raises ValueError or KeyError if ``state`` does not fit this ES.
        """
        self._load_state_dict(state)
        self.generation = int(state["generation"])
        self.nonfinite_fitness_count = int(state["nonfinite_fitness_count"])

    def _state_dict(self) -> dict:
        """The search state: :attr:`state` flattened (:func:`flatten_record`); an ES without a record gives its own."""
        if self.state is None:
            raise NotImplementedError(f"{type(self).__name__} cannot be checkpointed")
        return flatten_record(self.state)

    def _load_state_dict(self, state: dict) -> None:
        if self.state is None:
            raise NotImplementedError(f"{type(self).__name__} cannot be checkpointed")
        self.set_state(record_from_flat(self.state, state))

    # ------------------------------------------------------------ for subclasses
    @abstractmethod
    def _update(self, samples: np.ndarray, utilities: np.ndarray) -> None:
        """Move the search distribution; ``utilities`` are higher-is-better, one per row of ``samples``.
        An ES with a :meth:`compiled_step` implements it as ``self._update_compiled(samples, utilities)``."""

    # ------------------------------------------------------------ the state record and the compiled step
    #: The ES's search state, one record (a NamedTuple of arrays; :class:`CompiledStep` says why), set by
    #: :meth:`_setup`: what ``tell`` moves, the compiled loop runs on and the checkpoint saves. None for an ES
    #: that keeps its state otherwise (its own :meth:`_state_dict`; it runs in the Python loop only).
    state = None

    def set_state(self, state) -> None:
        """Adopt ``state``, a record of :attr:`state`'s type (the compiled loop hands back the copy it moved),
        and rebuild what derives from it (:meth:`_state_changed`)."""
        self.state = state
        self._state_changed()

    def _state_changed(self) -> None:
        """Rebuild what derives from :attr:`state` after it moved; by default the diagonal Gaussian of its
        ``mean`` and ``std`` (copies: the distributions archived by mixing must not move with the state)."""
        self._dist = DiagonalGaussian(self.state.mean, self.state.std)

    def compiled_step(self) -> CompiledStep | None:
        """This ES's update as compiled code over :attr:`state` (:class:`CompiledStep`); None: it has none, and
        its seeds run in the Python loop. An ES that gives one runs its own :meth:`_update` through it
        (:meth:`_update_compiled`)."""
        return None

    def _update_compiled(self, samples: np.ndarray, utilities: np.ndarray):
        """:meth:`_update` through :meth:`compiled_step`: the one copy of the update, on :attr:`state` in place; returns
        what the compiled update returns (ARS's sigma_R; None for the others)."""
        step = self.compiled_step()
        result = step.update(np.ascontiguousarray(samples, dtype=np.float64), np.ascontiguousarray(utilities, dtype=np.float64), self.state, step.constants)
        self._state_changed()
        return result

    def compiled_utilities(self):
        """:meth:`utilities` as compiled code -- ``utilities(samples, fitness, generation, weight_decay,
        hash_multipliers(d))`` for finite fitness -- when the ES's shaping and weight-decay form have one
        (centred ranks with the estool form: :func:`estool_centered_ranks_kernel`); None otherwise."""
        if self.params.fitness_shaping == "centered_ranks" and self.params.weight_decay_form == "estool":
            return estool_centered_ranks_kernel
        return None

    def _mean_weights(self, utilities: np.ndarray) -> np.ndarray:
        """The weight c_j of each member of the generation just told in the mean's move.

        The move of the mean caused by this generation is, in the coordinates whitened by the
        distribution the members were drawn from, proportional to ``sum_j c_j z_j`` (any scale:
        only ratios of the weights matter). Importance mixing's ``"conditional"`` rule reads it
        as :attr:`mean_weights` after :meth:`tell` (:mod:`imix_cli.core.mixing`, "Reuse inside the
        loop"). The gradient ES (OpenES, SNES) move the mean along ``sum_j u_j z_j``, so the
        default is the utilities themselves; selection-based ES override it.
        """
        return np.array(utilities, dtype=np.float64)

    @property
    def mean(self) -> np.ndarray:
        """Mean of the current search distribution."""
        return self.distribution.mean
