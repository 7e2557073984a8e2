"""Importance mixing around any evolution strategy, as one more ask/tell object.

Why a wrapper: with importance mixing, part of every generation is taken from earlier
generations whose returns are already known, so a user's loop would have to keep the archive,
the heights and ages of its members, and put the stored and the new returns back together in
the generation's order before telling the ES. :class:`MixingES` does that bookkeeping with the
very functions the runner uses for every seed (:func:`imix_cli.core.mixing.generation.plan_generation` and
:func:`imix_cli.core.mixing.generation.finish_generation`), and shows the user only what costs an episode:
``ask()`` returns the members to evaluate, ``tell()`` takes their returns. A plain ask/tell loop
becomes a mixing one by wrapping the ES::

    es = MixingES(make_es("cem", dim=10, popsize=20), "exact", rng=0)   # the one new line
    for generation in range(100):
        x = es.ask()                 # only the members that need an evaluation
        es.tell(x, fitness(x))       # their returns (es.tell(fitness(x)) works too)

The generations, updates and reuse are exactly the runner's for the same ES, random stream and
returns (tests/test_ask_tell.py checks it against ``imix run``'s CSV on CartPole for all four ES).
"""

from __future__ import annotations

import numpy as np

from imix_cli.core.mixing import MIXING_DEFAULTS
from imix_cli.core.mixing.generation import Archive, MixingSettings, Plan, finish_generation, plan_generation

__all__ = ["MixingES"]


class MixingES:
    """An evolution strategy with importance mixing: ``ask()`` returns only the members to evaluate.

    Parameters
    ----------
    es
        Any ES of :mod:`imix_cli.core.algorithms` (or an object with ``ask(rng)``, ``tell(samples,
        fitness)``, ``distribution`` and ``popsize``), a pycma ``CMAEvolutionStrategy`` (wrapped in
        :class:`~imix_cli.core.adapters.pycma.PycmaES`), or another library's ES through its adapter
        (:mod:`imix_cli.core.adapters`). Fitness is the ES's own: maximised for imix's, minimised for
        pycma's and evosax's.
    variant : {"exact", "sun2009", "paper", "conditional", "eim_paper", None}
        The :func:`~imix_cli.core.mixing.mix` variant (``"exact"``, the default: ``imix run eim=true``; ``"paper"``:
        ``im=true``; :data:`~imix_cli.core.mixing.VARIANT_SPECS`); None draws every generation fresh, i.e. the plain ES.
        Every default here is :data:`~imix_cli.core.mixing.MIXING_DEFAULTS`' (``imix run``'s).
    rng : numpy Generator, int or None
        The stream that draws and mixes the generations (an int seeds a new Generator).
    eim_generations : int
        K, the archived generations ``"exact"`` and ``"eim_paper"`` reuse from (default 3; the config key of the same
        name; :class:`~imix_cli.core.mixing.generation.MixingSettings`).
    alpha : float
        ``"sun2009"``'s minimal refresh rate in [0, 1) (the config key ``im_alpha``).
    reeval_age : int or None
        Re-evaluate a reused member whose return is older than this many generations (None: never).
    reeval_prob : float
        Re-evaluate each reused member with this probability.
    reeval_count : int
        Re-evaluate this many reused members every generation and tell the others calibrated on them.
    min_fresh : int
        At least this many members of every mixed generation are fresh, in slots drawn at random (default 1,
        as ``imix run``): without it a distribution that stops moving reuses every member and CEM or CMA-ES
        repeats its update (:mod:`imix_cli.core.mixing`, "A minimal refresh"); 0: the rules alone.
    """

    def __init__(self, es, variant: str | None = MIXING_DEFAULTS.variant, *, rng=None, eim_generations: int = MIXING_DEFAULTS.eim_generations,
                 alpha: float = MIXING_DEFAULTS.alpha, reeval_age: int | None = MIXING_DEFAULTS.reeval_age,
                 reeval_prob: float = MIXING_DEFAULTS.reeval_prob, reeval_count: int = MIXING_DEFAULTS.reeval_count,
                 min_fresh: int = MIXING_DEFAULTS.min_fresh):  # fmt: skip
        from imix_cli.core.adapters import adapt

        # Every argument is checked here, with imix run's bounds (MixingSettings: imix_cli.core.mixing.generation.MIXING_BOUNDS):
        # a bad one is one error naming it now, not at the first ask() or deep inside it.
        es = adapt(es)
        missing = [name for name in ("ask", "tell", "distribution", "popsize") if not hasattr(es, name)]
        if missing:
            raise TypeError(f"es must be an evolution strategy (imix_cli.core.algorithms.make_es), got {type(es).__name__} without {', '.join(missing)}")
        self.es = es
        self.settings = MixingSettings(variant=variant, eim_generations=eim_generations, alpha=alpha, reeval_age=reeval_age,
                                       reeval_prob=reeval_prob, reeval_count=reeval_count, min_fresh=min_fresh)  # fmt: skip
        if isinstance(rng, bool) or not (rng is None or isinstance(rng, (np.random.Generator, int, np.integer, np.random.SeedSequence))):
            raise TypeError(f"rng must be a numpy Generator, an int seed or None, got {rng!r}")
        try:
            self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        except ValueError as err:  # a negative seed
            raise ValueError(f"rng: {err}") from None
        self.archive = Archive()
        self.plan: Plan | None = None  # the generation asked and not yet told
        self._last = None  # the last generation asked
        #: episodes asked for so far (fresh members and re-evaluated ones)
        self.evaluations = 0
        #: members taken from earlier generations so far, and members in all generations told
        self.reused = 0
        self.members = 0

    @property
    def distribution(self):
        """The current search distribution (its ``mean`` is the policy one deploys)."""
        return self.es.distribution

    @property
    def popsize(self) -> int:
        return self.es.popsize

    def ask(self, rng: np.random.Generator | None = None) -> np.ndarray:
        """The members of the next generation that need an evaluation, one row each (fresh ones, and
        reused ones that ``reeval_age``/``reeval_prob`` measure again), then any points the ES asks
        for besides its members (CMA-ES with ``step_size_control="tpa"``: two). ``rng``: this call's
        stream instead of the one given at construction."""
        if self.plan is not None:
            raise RuntimeError("ask() twice without tell(): tell the returns of the members asked first")
        self.plan = plan_generation(self.es, self.archive, self.settings, self.rng if rng is None else rng)
        self._last = self.plan.generation
        return self.plan.points

    def tell(self, samples_or_returns, returns=None) -> np.ndarray:
        """Tell the returns of the members :meth:`ask` returned, as ``tell(returns)`` (in the order asked) or, like
        pycma's ``tell``, ``tell(samples, returns)``: the pairs in any order, each sample one of the points asked
        (matched exactly; a sample never asked is refused in one line). Returns must be real numbers: None, strings
        and complex values are refused in one line naming the first. The ES is told the whole generation, reused
        members with their stored returns; returns the fitness of every member."""
        if self.plan is None:
            raise RuntimeError("tell() before ask(): ask for the members to evaluate first")
        asked = self.plan.points
        order = None
        if returns is None:
            returns = samples_or_returns
        else:
            order = _asked_order(samples_or_returns, asked)
        returns = _numbers(returns)
        if returns.shape[0] != asked.shape[0]:
            raise ValueError(f"tell(): {returns.shape[0]} returns for the {asked.shape[0]} members ask() returned")
        if order is not None:  # the pairs (x, f) in any order, as pycma's tell takes them: back in the asked order
            in_order = np.empty_like(returns)
            in_order[order] = returns
            returns = in_order
        plan, self.plan = self.plan, None
        fitness = finish_generation(self.es, self.archive, self.settings, plan, returns)
        if hasattr(self.es, "count_evaluations"):  # an adapter whose library counts evaluations (pycma's countevals)
            self.es.count_evaluations(asked.shape[0], values=returns)
        self.evaluations += asked.shape[0]
        self.reused += plan.generation.reused
        self.members += plan.generation.samples.shape[0]
        return fitness

    def stop(self):
        """The wrapped ES's termination criteria (pycma's ``stop()``: a dict, empty while none holds);
        an empty dict for an ES without them."""
        stop = getattr(self.es, "stop", None)
        return stop() if stop is not None else {}

    def optimize(self, objective, iterations: int | None = None, callback=None):
        """pycma's ``es.optimize``: ask, evaluate ``objective`` on every point asked, tell, until
        :meth:`stop` (or ``iterations`` generations); ``callback(self)`` after each. Returns self."""
        if iterations is None and not hasattr(self.es, "stop"):
            raise ValueError("optimize(): this ES has no termination criteria; give iterations=")
        done = 0
        while (iterations is None or done < iterations) and not self.stop():
            x = self.ask()
            self.tell(x, [objective(xi) for xi in x])
            done += 1
            if callback is not None:
                callback(self)
        return self

    @property
    def generation(self):
        """The last generation asked (:class:`~imix_cli.core.mixing.Generation`: samples, source, index), or None."""
        return self._last

    @property
    def reuse(self) -> float:
        """Fraction of the members told so far that were reused (not evaluated)."""
        return self.reused / self.members if self.members else 0.0

    def __getattr__(self, name):
        """What the wrapper lacks is the wrapped ES's: its adapter's, then its library's own object -- for pycma
        ``es.result`` (``evaluations`` counts only the episodes run, the adapter keeps ``countevals`` so),
        ``es.logger``/``cma.plot()``, ``es.disp()``, ``es.sigma``; for imix's ES its attributes. Why: a user
        who wraps the ES they had keeps the tools they had around it."""
        if name.startswith("__") or "es" not in self.__dict__:  # copy/pickle probes, or a half-built object
            raise AttributeError(name)
        for owner in (self.__dict__["es"], getattr(self.__dict__["es"], "es", None)):
            if owner is not None and hasattr(owner, name):
                return getattr(owner, name)
        raise AttributeError(f"'MixingES' object has no attribute {name!r}, nor has the ES it wraps")


def _asked_order(samples, asked: np.ndarray) -> np.ndarray | None:
    """Where each row of ``samples`` is among the ``asked`` points (None: the same order); ValueError naming the
    first row that is not one of them. Rows are matched exactly, repeated points (two TPA points on one spot) in turn."""
    try:
        samples = np.asarray(samples, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"tell(samples, returns): samples are not an array of numbers ({err})") from None
    if samples.shape != asked.shape:
        raise ValueError(f"tell(samples, returns): samples have shape {samples.shape}, ask() returned {asked.shape}")
    if (samples == asked).all():  # np.array_equal's test (the shapes are equal), without its wrapper
        return None
    where: dict[bytes, list[int]] = {}
    for i, row in enumerate(asked):
        where.setdefault(row.tobytes(), []).append(i)
    order = np.empty(samples.shape[0], dtype=np.int64)
    for k, row in enumerate(samples):
        slots = where.get(row.tobytes())
        if not slots:
            raise ValueError(f"tell(samples, returns): samples[{k}] is not one of the points ask() returned (or is told twice)")
        order[k] = slots.pop(0)
    return order


def _numbers(returns) -> np.ndarray:
    """``returns`` as a float64 vector; None, strings and complex values refused in one line naming the first."""
    if isinstance(returns, np.ndarray) and returns.dtype.kind in "fiu":
        return returns.astype(np.float64, copy=False).reshape(-1)
    if type(returns) is list and all(isinstance(value, float) for value in returns):  # pycma's loop: a list of floats
        return np.array(returns, dtype=np.float64)
    values = np.asarray(returns, dtype=object).reshape(-1)
    for k, value in enumerate(values):
        if value is None or isinstance(value, (str, bytes, complex, np.complexfloating)) or not np.isscalar(value) and not isinstance(value, np.ndarray):
            raise TypeError(f"tell(): returns[{k}] = {str(value)[:40]!r} ({type(value).__name__}) is not a real number")
    try:
        return np.asarray(returns, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as err:
        raise TypeError(f"tell(): returns are not real numbers ({str(err)[:80]})") from None
