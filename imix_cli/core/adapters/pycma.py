"""pycma's ``CMAEvolutionStrategy`` as an ES that :class:`~imix_cli.MixingES` mixes for.

Why an adapter and not pycma's own ask: importance mixing must know the density the next
generation is drawn from, draw the fresh members itself (rule 2 keeps a fresh draw only where the
new density exceeds the old) and tell the ES members it never asked for. pycma allows the last
(``tell`` takes any solutions), so the adapter reads the distribution from pycma's state after
each tell and hands pycma the whole mixed generation::

    es = cma.CMAEvolutionStrategy(10 * [1.0], 0.5, {"seed": 1, "verbose": -9})
    m = imix_cli.MixingES(es, "exact", rng=0)        # the one new line: wraps es in PycmaES
    while not m.stop():
        x = m.ask()                                   # only the points that need an evaluation
        m.tell(x, [cma.ff.sphere(xi) for xi in x])    # pycma's convention: minimised values

The distribution read is the one pycma's ``ask`` would sample from, computed by pycma's own
code: what ``ask_geno`` does before drawing (alleviating the conditioning of C, the sampler's
lazy eigendecomposition), then the sampler applied to the identity (its linear map, B D for the
full sampler, the square root of the diagonal for ``CMA_diagonal``), scaled by ``sigma_vec`` and
``sigma`` and mapped through pycma's genotype-phenotype map (``scaling_of_variables``,
``typical_x`` and the linear map ``alleviate_conditioning`` moves into it: all affine). Where
pycma's samples are not an independent Gaussian sample, reuse cannot be exact, and the adapter
refuses with one line (:data:`REFUSED_OPTIONS`).

Told as pycma's own draws. Every member is told with ``check_points=False``: pycma's ``tell`` otherwise
*repairs* the solutions it did not sample itself (``repair_genotype`` shortens steps whose Mahalanobis length
it finds too long), which pycma never does to its own samples. Reused and fresh members are exact draws of
pycma's distribution, so a repair only bends the update: on bbob's sharp ridge f13 (d = 5) the repaired
updates let the mean run away (4e9 after 900 generations) until the covariance broke and the adapter raised
(issue 45; tests/test_adapters_pycma.py, ``test_the_sharp_ridge_runs_to_the_end_where_pycma_runs_bbob_f13``).
The distribution is read from pycma's own factor (:func:`gaussian_from_factor`), never C = A^T A factored
again, and where that factor is singular the generation is drawn without reuse (:attr:`PycmaES.mixable`).

Ties. Members are told in a random order (:meth:`PycmaES._tell_order`): pycma keeps ties in the order told.

Termination. pycma's criteria that read f-values read the fresh evaluations only (:class:`FreshRecord`).

pycma counts every member told in ``countevals``; the adapter sets it back to the evaluations
made (fresh and re-evaluated members, and the two TPA points), so ``maxfevals`` and
``es.result.evaluations`` count real evaluations.

Step size under reuse (``step_size=``). pycma's CSA reads sigma from the members' steps; reused
members are not fresh draws given the loop (imix_cli/core/algorithms/cmaes.py, "Two-point step-size
adaptation"; docs/research/bias.md), and CSA misreads them. Offered:

``"pycma"`` (the default: measured below)
    pycma's step-size control as configured: CSA by default; with ``AdaptSigma=
    cma.sigma_adaptation.CMAAdaptSigmaTPA`` pycma's TPA, whose two points pycma itself places as
    the first two members it is told (they are evaluated afresh and never reused or archived:
    the mixed generation is the other popsize - 2 members).
``"tpa"``
    imix's remedy for its own CMA-ES: two points m +- sigma r u per generation (u the last move of
    the mean, unit length in sigma^2 C's metric, r the length of a fresh N(0, I) draw), evaluated
    afresh beside the members, never told to pycma as members, never reused; sigma changes by
    pycma 4.5's TPA rule from their ranks among the generation, and pycma's own change of sigma in
    that tell is discarded (its CSA path still runs: hsig reads it).

Measured (docs/adapters.md, ``benchmarks/adapters.py stepsize``; d = 10, default popsize, 5
seeds, evaluations to f(mean) <= 1e-8, median): pycma's CSA with mixing needs the fewest --
sphere 768 (pycma alone 1,350), elli 3,336 (3,870) -- against pycma's TPA with mixing (1,133;
3,922) and imix's TPA (1,948; 4,770), which imix chose for its own CMA-ES on RL tasks where CSA
collapsed under reuse; it costs two evaluations per generation. Whether CSA with mixing also
holds on such tasks with pycma was not measured here: ``step_size="tpa"`` is there for them.
"""

from __future__ import annotations

import math

import numpy as np

from imix_cli.core import numerics as xp
from imix_cli.core.distributions import DiagonalGaussian, FullGaussian

__all__ = ["FreshRecord", "PycmaES", "gaussian_from_factor", "REFUSED_OPTIONS", "STEP_SIZES", "is_pycma"]

#: ``step_size`` values (module docstring); the first is the default.
STEP_SIZES = ("pycma", "tpa")


def _truthy_list(value) -> bool:
    return value is not None and len(value) > 0


#: pycma options under which its samples are not N(m, sigma^2 C) drawn independently, and why:
#: option -> (is it set?, reason). Checked once, when the adapter is made.
REFUSED_OPTIONS = {
    "bounds": (lambda es: es.boundary_handler is not None and es.boundary_handler.has_bounds(), "bounded samples are repaired or penalised"),
    "integer_variables": (lambda es: _truthy_list(es.opts["integer_variables"]), "integer variables are rounded and get an extra mutation"),
    "fixed_variables": (lambda es: bool(es.opts["fixed_variables"]), "fixed variables are not sampled"),
    "transformation": (lambda es: es.opts["transformation"] is not None, "a user transformation is not affine"),
    "CMA_mirrors": (lambda es: es.sp.lam_mirr > 0, "mirrored samples are not independent (pycma mirrors by default when popsize < 6: set CMA_mirrors=0)"),
    "CMA_elitist": (lambda es: bool(es.opts["CMA_elitist"]), "the elitist is injected, not sampled"),
    "mean_shift_line_samples": (lambda es: bool(es.opts["mean_shift_line_samples"]), "line samples along the mean shift are not sampled"),
}


def _pycma_class(es):
    """pycma's own ``CMAEvolutionStrategy`` among the classes of ``es`` (None if it is not one), found without
    importing cma. The adapter calls its methods, not the instance's: a subclass (:func:`imix_cli.fmin2`'s) may
    route its own ``tell``/``stop`` through the adapter."""
    return next((c for c in type(es).__mro__ if c.__module__.startswith("cma.") and c.__name__ == "CMAEvolutionStrategy"), None)


def is_pycma(es) -> bool:
    """Whether ``es`` is a pycma ``CMAEvolutionStrategy`` (checked without importing cma)."""
    return _pycma_class(es) is not None


class PycmaES:
    """A ``cma.CMAEvolutionStrategy`` with imix's ES protocol (``ask(rng)``, ``tell(samples, fitness)``,
    ``distribution``, ``popsize``, ``probes(rng)``); fitness is pycma's (minimised).

    Parameters
    ----------
    es : cma.CMAEvolutionStrategy
        Built by the user, not yet asked (pycma's own options as usual); refused with one line
        (ValueError) under the options of :data:`REFUSED_OPTIONS`.
    step_size : {"pycma", "tpa"}
        Step-size control under reuse (module docstring).
    """

    name = "pycma"
    generation_scheme = None  # independent members (imix_cli.core.mixing.generation.scheme_of); said, not looked up and missed twice a generation

    def __init__(self, es, step_size: str = STEP_SIZES[0]):
        if not is_pycma(es):
            raise TypeError(f"PycmaES takes a cma.CMAEvolutionStrategy, got {type(es).__name__}")
        if step_size not in STEP_SIZES:
            raise ValueError(f"step_size={step_size!r}: must be one of {STEP_SIZES}")
        for option, (is_set, why) in REFUSED_OPTIONS.items():
            if is_set(es):
                raise ValueError(f"pycma option {option}={es.opts[option]!r}: {why}, so reuse cannot be exact; importance mixing refuses it")
        if es.countiter:
            raise ValueError(f"the CMAEvolutionStrategy has already been told {es.countiter} generations: wrap it before its first ask")
        from cma.sigma_adaptation import CMAAdaptSigmaTPA

        self.es = es
        self._pycma = _pycma_class(es)
        self.step_size = step_size
        self.dim = int(es.N)
        self.pycma_tpa = isinstance(es.adapt_sigma, CMAAdaptSigmaTPA)
        if self.pycma_tpa and step_size == "tpa":
            raise ValueError("step_size='tpa' with pycma's AdaptSigma=CMAAdaptSigmaTPA: two TPAs; use step_size='pycma' for pycma's")
        self.generation = 0
        self.mean_weights = None  # pycma's weight of each member told last ("conditional" mixing): _mean_weights
        # imix's TPA (step_size="tpa"): pycma 4.5's CMAAdaptSigmaTPA constants, its state s and the last move
        self.tpa_damp = 0.7 + 2 * math.log(self.dim) + 2 * math.log(max(1, es.popsize - self.dim))
        self.tpa_s = 0.0
        self.tpa_move = np.zeros(self.dim)
        self._dist = None
        self._degenerate = False  # pycma's current factor is singular: no density, this generation draws without reuse
        self._probes = None
        self._countevals = None
        self._tie_rng = None  # the order members are told in (ties: _tell_order)
        self._rank_weights = None  # (key, pycma's weights, the weight of each rank): _mean_weights
        self._fresh = FreshRecord(es, self._pycma.stop)  # what pycma's termination criteria read (stop(): "Termination under reuse")

    # ------------------------------------------------------------------ the ES protocol
    @property
    def popsize(self) -> int:
        """Members mixed per generation: pycma's popsize, less pycma's two TPA points when it runs TPA."""
        return int(self.es.popsize) - (2 if self.pycma_tpa else 0)

    @property
    def probe_count(self) -> int:
        return 2 if (self.step_size == "tpa" or self.pycma_tpa) else 0

    @property
    def distribution(self):
        """The Gaussian pycma's next ``ask`` samples from (module docstring): a DiagonalGaussian when
        its covariance is diagonal (``CMA_diagonal``), else a FullGaussian."""
        if self._dist is None:
            self._dist = self._read_distribution()
        return self._dist

    @property
    def mixable(self) -> bool:
        """Whether the current distribution has a density to mix with: False where pycma's own factor is
        singular (its state degenerate), and the generation is then drawn without reuse, as pycma would go on
        drawing (:func:`imix_cli.core.mixing.generation.plan_generation` reads it)."""
        self.distribution  # noqa: B018 (reads the factor)
        return not self._degenerate

    def ask(self, rng: np.random.Generator) -> np.ndarray:
        return self.distribution.sample(self.popsize, rng)

    def probes(self, rng: np.random.Generator) -> np.ndarray | None:
        """The two TPA points of this generation (imix's or pycma's, ``step_size``), or None."""
        self._probes = None
        if self._tie_rng is None:  # a child stream: the mixing stream itself draws exactly what it drew before
            self._tie_rng = _child_stream(rng)
        if self.pycma_tpa:  # pycma's own: its ask of 2 gives them (2 plain draws before the mean has moved)
            self._probes = np.vstack(self.es.ask(2))
            if not np.all(np.isfinite(self._probes)):  # the mean did not move (a fully reused generation): no direction
                self._probes[:] = self.distribution.mean  # two equal points tie: sigma stays
        elif self.step_size == "tpa" and np.any(self.tpa_move) and self.mixable:
            dist = self.distribution
            length = _mahalanobis(dist, self.tpa_move)
            draw = rng.standard_normal(self.dim)
            y = self.tpa_move * (math.sqrt(float(draw @ draw)) / length)
            self._probes = np.vstack([dist.mean + y, dist.mean - y])
        return self._probes

    def tell(self, samples, fitness, probe_fitness=None) -> None:
        """pycma's ``tell`` of the whole generation (pycma's TPA points first when it runs TPA)."""
        es = self.es
        samples = np.asarray(samples, dtype=np.float64)
        fitness = np.asarray(fitness, dtype=np.float64).reshape(-1)
        order = self._tell_order(samples.shape[0])
        solutions, values = list(samples[order]), list(fitness[order])
        if self.pycma_tpa and probe_fitness is not None:
            solutions, values = [*self._probes, *solutions], [*np.asarray(probe_fitness, dtype=np.float64), *values]
        # read even where nothing needs the mean: it brings pycma's lazy state up to date, as pycma's ask would, where
        # tell comes without an ask (tests/test_adapters_pycma.py, the order test)
        mean_before, sigma_before = self.distribution.mean.copy(), float(es.sigma)
        self._countevals = int(es.countevals)
        # what pycma's ask would have recorded: the members were drawn here, independently
        es._flgtelldone = False
        if not hasattr(es, "timer"):  # pycma's ask starts its clock
            from cma.utilities.utils import ElapsedWCTime

            es.timer = ElapsedWCTime()
        elif not self.pycma_tpa:
            es.timer.tic  # noqa: B018 (a property that restarts the clock)
        if not es.number_of_solutions_asked:
            es.number_of_injections = 0
        es.number_of_solutions_asked += samples.shape[0]
        es.evaluations_per_f_value = 1
        es._is_independent_sample = [False] * (len(solutions) - samples.shape[0]) + [True] * samples.shape[0]
        self._pycma.tell(es, solutions, values, check_points=False)  # no repair (module docstring, "Told as pycma's own draws")
        self.mean_weights = self._mean_weights(len(solutions) - samples.shape[0], order)
        if self.step_size == "tpa" and not self.pycma_tpa:
            step = self._tpa_step(probe_fitness, fitness)
            es.sigma = sigma_before * math.exp(min(max(step, -1.0), 1.0))
        self._dist = None
        self._probes = None
        if self.step_size == "tpa" and not self.pycma_tpa:
            self.tpa_move = self.distribution.mean - mean_before
        self.generation += 1

    def count_evaluations(self, evaluated: int, values=None) -> None:
        """Set pycma's ``countevals`` to the evaluations made for the generation just told, and record their
        ``values`` (fresh information: :class:`FreshRecord`); MixingES calls it after each tell."""
        if self._countevals is not None:
            self.es.countevals = self._countevals + int(evaluated)
            self._countevals = None
        if values is not None:
            self._fresh.add(np.asarray(values, dtype=np.float64).reshape(-1))

    def stop(self):
        """pycma's termination criteria (a dict, empty while none holds), those that read f-values judged on
        the fresh evaluations only (:class:`FreshRecord`)."""
        return self._fresh.stop()

    @property
    def mean(self) -> np.ndarray:
        return self.distribution.mean

    # ------------------------------------------------------------------ internals
    def _mean_weights(self, probes: int, order: np.ndarray) -> np.ndarray:
        """c_j of each member of the generation just told (in the generation's order): pycma's positive
        recombination weight of its rank, 0 beyond mu -- what variant ``"conditional"`` conditions on
        (:mod:`imix_cli.core.mixing`, "Reuse inside the loop"). ``probes``: pycma's TPA points told first."""
        es = self.es
        idx = np.asarray(es.fit.idx)  # idx[r]: the member told at rank r
        told = idx.size
        key = (id(es.sp.weights), told)
        if self._rank_weights is None or self._rank_weights[0] != key:  # the weight of each rank, made once
            weights = np.asarray(es.sp.weights, dtype=np.float64)
            by_rank = np.arange(told)
            self._rank_weights = (key, es.sp.weights, np.where(by_rank < es.sp.weights.mu, weights[np.minimum(by_rank, weights.size - 1)], 0.0))
        c = np.empty(told)
        c[idx] = self._rank_weights[2]  # each member told, its rank's weight
        c = c[probes:]
        out = np.empty(c.size)
        out[order] = c
        return out

    def _tell_order(self, n: int) -> np.ndarray:
        """The order the members are told to pycma in: a random permutation.

        Why: pycma ranks with ``np.argsort``, which keeps ties in the order told (insertion sort below 16
        members), and a mixed generation lists its reused members first. On a plateau (bbob's step ellipsoid
        f7) a reused member and a fresh one often have the same value, and the reused one -- a point of an
        earlier, worse-centred generation -- then always wins the tie: the mean is pulled back and the run
        stalls (pycma 3/3 hits on f7, d = 5, wrapped 0/3). pycma's own members are independent draws, so its
        ties fall in a random order; a random order of the told members gives the same. Without ties the
        order changes nothing (ranks, and so pycma's update, are the same bit for bit).
        """
        if self._tie_rng is None:
            return np.arange(n)
        return self._tie_rng.permutation(n)

    def _tpa_step(self, probe_fitness, fitness) -> float:
        """log sigma's change (before clipping) from the two points' values (pycma 4.5's
        CMAAdaptSigmaTPA.update2, minimising): z = (#{f < f_behind} - #{f < f_ahead}) / (n - 1)."""
        if probe_fitness is None:
            return 0.0
        f = np.concatenate([np.asarray(probe_fitness, dtype=np.float64).reshape(-1), fitness])
        f = np.where(np.isnan(f), np.inf, f)
        z = (np.count_nonzero(f < f[1]) - np.count_nonzero(f < f[0])) / (f.size - 1)
        self.tpa_s = (1 - 0.3) * self.tpa_s + 0.3 * math.copysign(abs(z) ** 0.5, z)
        return self.tpa_s / self.tpa_damp

    def _read_distribution(self):
        es = self.es
        # what ask_geno does before it draws (it may move conditioning from C into sigma_vec or the phenotype map)
        if es.opts["conditioncov_alleviate"]:
            es.alleviate_conditioning_in_coordinates(es.opts["conditioncov_alleviate"][0])
            es.alleviate_conditioning(es.opts["conditioncov_alleviate"][-1])
        rows = np.asarray(_sampler_map(es.sm, self.dim), dtype=np.float64)  # row i: the draw for z = e_i
        es._updateBDfromSM(es.sm)
        rows = np.asarray(es.sigma_vec * rows, dtype=np.float64) * float(es.sigma)
        mean_geno = np.asarray(es.mean, dtype=np.float64)
        mean = np.asarray(es.gp.pheno(mean_geno), dtype=np.float64)
        if not es.gp.isidentity:  # an affine phenotype map: the images of the columns
            rows = np.array([np.asarray(es.gp.pheno(mean_geno + r), dtype=np.float64) - mean for r in rows])
        # a diagonal map (CMA_diagonal, or C still the identity): the std is the map itself; a non-finite diagonal is
        # not one. Checked in one compiled pass with the finiteness gaussian_from_factor requires.
        kind = xp.factor_kind(rows)
        if kind == 0:
            return DiagonalGaussian(mean, np.abs(np.diag(rows)))
        # pycma's factor itself, never C = rows^T rows factored again (gaussian_from_factor: that squares the condition)
        try:
            self._degenerate = False
            if kind == 2:
                raise ValueError("the covariance factor is not finite")
            return _gaussian_from_rows(mean, rows)
        except ValueError:  # a singular (or non-finite) factor: pycma goes on drawing from it, so does the adapter, without reuse
            self._degenerate = True
            return _Degenerate(mean, rows)


class _Degenerate:
    """pycma's distribution where its factor is singular: drawn from as pycma draws (mean + z A), without a
    density (no reuse: :attr:`PycmaES.mixable`)."""

    def __init__(self, mean: np.ndarray, rows: np.ndarray):
        self.mean, self.rows, self.dtype = mean, rows, np.dtype(np.float64)

    @property
    def dim(self) -> int:
        return self.mean.shape[0]

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.sum(self.rows * self.rows, axis=0))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return self.mean + rng.standard_normal((n, self.dim)) @ self.rows

    def log_prob(self, x, rows=None):
        raise ValueError("pycma's covariance factor is singular: the distribution has no density")


class FreshRecord:
    """pycma's termination criteria under reuse: the f-values they read are the fresh evaluations only.

    Why. pycma's criteria that read f-values -- ``tolfun``, ``tolfunhist``, ``tolfunrel``, ``tolflatfitness``,
    ``tolstagnation`` -- read the sorted values of the last generation (``es.fit.fit``) and histories of its
    best and median (``fit.hist``, ``fit.histbest``, ``fit.histmedian``), and count flat generations in a row;
    each entry is meant as new information, lambda independent evaluations. A mixed generation repeats
    members of the generations before it with their stored values: the best member is often the same for
    several generations (``fit.hist`` constant: ``tolfunhist`` fires while the run still progresses), and two
    consecutive generations that share most members are flat together (on bbob, with mixing, 1,192 restarts
    against pycma's 436 and ``tolflatfitness`` 372 times against 93, issue 45).

    How. Every value evaluated afresh (fresh members, re-evaluated ones, TPA points) goes into a queue; each
    time lambda of them are queued they make one *fresh generation*, recorded exactly as pycma's ``tell``
    records a generation (the same fields, the same histories and lengths, ``histbest`` every fifth). While
    ``stop()`` runs, pycma reads this record instead of its own, and its flat-generation count advances once
    per fresh generation. So every criterion keeps its meaning -- "lambda new evaluations per entry" --
    and its threshold. The criteria that read the distribution (``tolx``, ``tolupsigma``, ``noeffect*``,
    ``tolconditioncov``, ``maxiter``, ``maxfevals``) are pycma's, untouched; pycma's update (``tell``) still
    ranks the whole mixed generation. Without reuse every generation is fresh and the record is pycma's own.
    Checked: tests/test_adapters_pycma.py (``test_reused_values_do_not_trip_pycma_stopping_rules``).
    """

    _FIELDS = ("fit", "hist", "histbest", "histmedian", "median", "median0", "median_min", "flatfit_iterations")

    def __init__(self, es, pycma_stop):
        self.es, self._pycma_stop = es, pycma_stop  # pycma's own stop(), unbound
        self.queue: list[float] = []
        self.record = {"fit": [], "hist": [], "histbest": [], "histmedian": [], "median": None, "median0": None,
                       "median_min": np.inf, "flatfit_iterations": 0}  # fmt: skip
        self.generations = 0
        self.new = False  # a fresh generation recorded since stop() last ran
        self.flat = False  # the newest fresh generation is flat (pycma's test)

    def add(self, values: np.ndarray) -> None:
        self.queue.extend(values.tolist())
        lam = int(self.es.popsize)
        while len(self.queue) >= lam:
            block, self.queue = self.queue[:lam], self.queue[lam:]
            self._record(sorted(block))

    def _record(self, fit: list) -> None:
        """pycma 4.5's ``tell``, "fitness histories", on one fresh generation."""
        r, n = self.record, int(self.es.N)
        r["fit"] = fit
        r["hist"].insert(0, fit[0])
        i = len(fit) // 2
        r["median"] = float(fit[i] if len(fit) % 2 else (fit[i - 1] + fit[i]) / 2)
        self.generations += 1
        if self.generations % 5 == 0:
            r["histbest"].insert(0, fit[0])
            r["histmedian"].insert(0, r["median"])
        if len(r["histbest"]) > 2e4:
            r["histbest"].pop()
            r["histmedian"].pop()
        if len(r["hist"]) > 10 + 30 * n / len(fit):
            r["hist"].pop()
        if r["median0"] is None:
            r["median0"] = r["median"]
        r["median_min"] = min(r["median_min"], r["median"])
        self.flat = not fit[0] < fit[int(0.75 * len(fit))]
        self.new = True

    def stop(self):
        """pycma's ``stop()`` with this record in place of its own (class docstring)."""
        es = self.es
        if not self.generations or es.countiter == getattr(es._stopdict, "lastiter", None):
            return self._pycma_stop(es)  # before any fresh generation (the first is all fresh); or pycma's answer of this iteration
        r = self.record
        if not self.new and self.flat:  # no new fresh generation: pycma's count must not advance on the same one again
            r["flatfit_iterations"] -= 1
        own = {name: getattr(es.fit, name) for name in self._FIELDS}
        for name in self._FIELDS:
            setattr(es.fit, name, r[name])
        try:
            return self._pycma_stop(es)
        finally:
            r["flatfit_iterations"] = es.fit.flatfit_iterations
            for name, value in own.items():
                setattr(es.fit, name, value)
            self.new = False


def gaussian_from_factor(mean, factor) -> FullGaussian:
    """N(mean, A A^T) from any square root ``A`` of the covariance (pycma's B D), without forming A A^T.

    The QR factorisation A^T = Q R works at A's condition number and gives A A^T = R^T R: L = R^T, each column's sign
    flipped so that L's diagonal is positive (:meth:`FullGaussian.from_cholesky`). Factoring C = A A^T itself would
    work at the square of that condition number, where pycma's runs go (``tolconditioncov`` 1e14). ValueError if A
    is singular or not finite (the adapter then draws without reuse: :attr:`PycmaES.mixable`).
    """
    factor = np.asarray(factor, dtype=np.float64)
    if not np.isfinite(factor).all():
        raise ValueError("the covariance factor is not finite")
    return _gaussian_from_rows(mean, factor.T)


def _gaussian_from_rows(mean, rows: np.ndarray) -> FullGaussian:
    """:func:`gaussian_from_factor` of the factor ``rows.T``, its entries known to be finite.

    LAPACK's QR (geqrf) called as ``np.linalg.qr(rows, mode="r")`` calls it -- on a copy, under the same floating-point
    error state -- but without the wrapper's checks and conversions, and R's sign flips, L and its log-normaliser in
    one compiled call (:func:`imix_cli.core.numerics.lower_from_r`): at d = 10 ``np.linalg.qr`` and the dozen numpy
    calls after it were the largest part of the adapter's cost per generation. The same bits as before."""
    r = np.array(rows, dtype=np.float64, copy=True)  # geqrf overwrites its input, as np.linalg.qr's own copy
    try:
        with np.errstate(invalid="raise", over="ignore", divide="ignore", under="ignore"):  # np.linalg.qr's
            if _QR_R_RAW is None:
                r = np.linalg.qr(r, mode="r")
            else:
                _QR_R_RAW(r, signature="d->d")
        low, log_norm = xp.lower_from_r(r)
    except (FloatingPointError, np.linalg.LinAlgError):  # what from_cholesky checks of L
        raise ValueError("FullGaussian: the factor is not lower triangular with a positive diagonal (singular)") from None
    return FullGaussian.from_cholesky(mean, low, checked=False, log_norm=log_norm)


try:  # the gufunc np.linalg.qr(a, mode="r") runs (numpy >= 1.22): LAPACK's geqrf, R in the upper triangle of a
    from numpy.linalg._umath_linalg import qr_r_raw as _QR_R_RAW
except ImportError:  # another numpy: np.linalg.qr itself, the same numbers
    _QR_R_RAW = None


def _child_stream(rng: np.random.Generator) -> np.random.Generator:
    """An independent stream spawned from ``rng``'s seed sequence: nothing is drawn from ``rng`` itself."""
    try:
        return rng.spawn(1)[0]
    except (AttributeError, TypeError, ValueError):  # a bit generator without a seed sequence
        return np.random.default_rng(0x1A2B)


def _sampler_map(sm, dim: int) -> np.ndarray:
    """The linear map pycma's sampler applies to its N(0, I) draws, as rows (row i: the draw for
    z = e_i), computed by the sampler itself (its lazy update included) with an identity in place
    of its random numbers."""
    had_own = "randn" in vars(sm)
    own = vars(sm).get("randn")
    sm.randn = lambda n, d: np.eye(dim)
    try:
        return sm.sample(dim)
    finally:
        if had_own:
            sm.randn = own
        else:
            del sm.randn


def _mahalanobis(dist, v: np.ndarray) -> float:
    """Length of ``v`` in ``dist``'s metric (sqrt(v^T cov^-1 v))."""
    if isinstance(dist, DiagonalGaussian):
        return float(np.sqrt(np.sum((v / dist.std) ** 2)))
    z = np.linalg.solve(dist.chol, v)
    return float(np.sqrt(z @ z))
