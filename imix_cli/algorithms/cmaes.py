"""CMA-ES through pycma, told populations that it did not sample itself.

Hansen & Ostermeier (2001), "Completely derandomized self-adaptation in evolution
strategies", Evolutionary Computation 9(2); Hansen (2016), "The CMA Evolution Strategy:
A Tutorial", arXiv:1604.00772. Implementation: pycma (``cma``, Hansen et al.). Paper
section 2.1.4 of Pourchot, Perrin & Sigaud (2018): full covariance, rank-based
recombination weights, evolution paths, step-size control.

pycma does all of the maths (weights, mean, p_c, p_sigma, rank-one + rank-mu + active
update, CSA); this module only drives it so that *we* sample (our rng, possibly members
reused by importance mixing) and pycma only updates. See :class:`CMAES` for what was
verified in pycma's source to make that legitimate.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

import numpy as np

from imix_cli.algorithms.base import EvolutionStrategy
from imix_cli.distributions import FullGaussian

if TYPE_CHECKING:
    import cma


def _pycma():
    """pycma, imported on first use: ``import cma`` pulls in scipy.stats and matplotlib (~1 s),
    which every spawned worker of a non-CMA-ES run would otherwise pay at start-up."""
    import cma
    import cma.options_parameters
    import cma.utilities.utils

    return cma

#: options we set and the caller may not override: quiet, no files, no pycma sampling
#: or global reseeding, nothing that would change the sampling distribution
#: (mirrors, bounds) or need pycma's own ask (TPA injections).
_PINNED_OPTIONS = ("popsize", "verbose", "verb_disp", "verb_log", "seed", "randn", "CMA_mirrors", "bounds", "AdaptSigma")


def _pycma_must_not_sample(*args, **kwargs):
    """pycma's ``randn`` option: we sample ourselves; any draw by pycma is a bug."""
    raise RuntimeError("pycma tried to draw random numbers; imix's CMAES samples with its own rng")


class CMAES(EvolutionStrategy):
    """CMA-ES (pycma): N(mean, sigma^2 C) with full C; pycma updates, we sample.

    What driving pycma with foreign samples needed, read from pycma 4.5's source
    (``cma/evolution_strategy.py``, ``cma/sampler.py``) and checked by
    ``tests/test_algorithms.py``:

    * ``tell(solutions, f, check_points=False)``: with ``check_points=None`` (the default)
      every solution pycma did not hand out in ``ask`` goes through ``repair_genotype``,
      which clips its Mahalanobis distance to sqrt(d) + 2d/(d+2) -- that would shrink
      legitimate reused members. ``False`` skips both repair loops; the points enter the
      update unchanged. (Ordinary tail draws also exceed that radius: with ``None``
      even the ask/tell equivalence test below fails.) The test gives pycma a population it produced itself through
      ``ask`` (solutions it knows are never repaired) that contains far-away points, and
      shows that our ``tell`` of the same points yields the same mean, sigma, C and paths,
      while pycma's default ``check_points`` on unknown points would have moved the mean.
    * No re-weighting: negative weights are multiplied by ``CMA_active_injected`` only for
      solutions registered through ``inject``, which we never call; every row gets the
      rank weight of its (-utility) rank.
    * ``tell`` without ``ask``: ``ask_geno`` sets a little bookkeeping (``_flgtelldone``,
      ``number_of_injections``, ``number_of_solutions_asked``, ``_is_independent_sample``,
      ``evaluations_per_f_value``, ``timer``) that ``tell`` reads; ``_emulate_ask``
      sets exactly these, without sampling. Before sampling, ``ask`` also alleviates
      extreme conditioning and brings the sampler's eigendecomposition (B, D) up to date
      (``tell`` uses B, D for p_sigma and the active update); ``_prepare_sampler`` does
      the same after each ``tell``. The test checks that our trajectory equals, to
      round-off, pycma's own ask/tell loop fed the same samples.
    * pycma never draws random numbers here: its ``randn`` option is a function that
      raises, and ``seed=nan`` keeps it from reseeding numpy's global RNG.
    * Sampling distribution: ``ask`` returns mean + sigma * sigma_vec * B (D z), z ~ N(0, I)
      (geno = pheno: no bounds, no ``transformation``, no fixed variables; no mirrors,
      no TPA injections). So ``distribution`` is FullGaussian(mean, A A^T) with
      A = sigma diag(sigma_vec) B diag(D), i.e. sigma^2 C with the decomposed C. (pycma's
      initial C is diag(exp(1e-4 k / d)), k = 0..d-1, not exactly I: a 1e-4 relative
      tie-breaking hack, reproduced as is.)
    * Utilities: pycma minimises and uses only the ranking of what it is told (plus
      termination diagnostics we do not use), so it gets -utilities: the base class's
      weight decay, centred ranks and non-finite handling decide the ranking.
    * Populations whose size differs from ``popsize``: n >= mu uses pycma's own handling
      (same mu and positive weights, negative weights trimmed or zero-padded); for
      3 <= n < mu pycma refuses, so that one tell runs with pycma's strategy parameters
      for popsize n. pycma needs n >= 3.

    Parameters
    ----------
    dim, popsize, sigma, lr, weight_decay, weight_decay_form, mean
        See :class:`~imix_cli.algorithms.base.EvolutionStrategy`. ``popsize`` is
        pycma's population size lambda (mu = lambda/2 positive weights), ``sigma`` its
        sigma0 and ``mean`` its x0; ``lr`` is ignored.
    cma_options : dict, optional
        Further pycma options (``cma.CMAOptions()``), e.g. ``{"CMA_active": False}``.
        The options in ``_PINNED_OPTIONS`` are set here and may not be given.
        ``updatecovwait`` defaults to 0: decompose C after every update. pycma's
        default lazy gap, 1 / (10 d (c1 + cmu)), is < 1 generation -- i.e. the same --
        for lambda = 50 up to d ~ 260 (0.60 at d = 155).
    """

    name = "cmaes"

    def __init__(
        self,
        dim: int,
        popsize: int = 50,
        sigma: float = 0.25,
        lr: float = 0.01,
        weight_decay: float = 0.05,
        weight_decay_form: str = "estool",
        mean=None,
        cma_options: dict | None = None,
    ):
        super().__init__(dim, popsize, sigma, lr, weight_decay, weight_decay_form, mean)
        if self.popsize < 3:
            raise ValueError(f"CMAES needs popsize >= 3 (pycma), got {self.popsize}")
        user = dict(cma_options or {})
        pinned = sorted(set(user) & set(_PINNED_OPTIONS))
        if pinned:
            raise ValueError(f"cma_options may not set {pinned}: CMAES pins them")
        opts = {"updatecovwait": 0}
        opts.update(user)
        opts.update(
            popsize=self.popsize,
            verbose=-9,  # no messages
            verb_disp=0,  # no console table
            verb_log=0,  # no outcmaes/ files
            seed=np.nan,  # "do nothing": leave numpy's global RNG alone
            randn=_pycma_must_not_sample,
            CMA_mirrors=0,  # no (antithetic) mirrored samples
            bounds=[None, None],
            AdaptSigma=True,  # CSA; TPA would need pycma's ask for its injected pair
        )
        self._es = _pycma().CMAEvolutionStrategy(self.initial_mean, self.sigma, opts)
        if not self._es.gp.isidentity or self._es.boundary_handler.has_bounds():
            raise ValueError("cma_options must not introduce a genotype-phenotype transformation or bounds")
        if not isinstance(self._es.sm, _pycma().sampler.GaussFullSampler):
            # e.g. CMA_diagonal or CMA_sampler: another sampler, another sampling formula
            raise ValueError("CMAES supports pycma's full-covariance sampler (GaussFullSampler) only")
        self._prepare_sampler()

    # ------------------------------------------------------------ distribution
    @property
    def distribution(self) -> FullGaussian:
        return self._dist

    @property
    def pycma(self) -> cma.CMAEvolutionStrategy:
        """The wrapped ``cma.CMAEvolutionStrategy`` (read it; do not call its ask/tell)."""
        return self._es

    def _prepare_sampler(self) -> None:
        """Do what pycma's ``ask`` does before it samples, then cache the sampling distribution."""
        es = self._es
        if es.opts["conditioncov_alleviate"]:
            es.alleviate_conditioning_in_coordinates(es.opts["conditioncov_alleviate"][0])
            es.alleviate_conditioning(es.opts["conditioncov_alleviate"][-1])
        es.sm.update_now()  # eigendecomposition C = B D^2 B^T, as sm.sample() would
        es._updateBDfromSM(es.sm)
        # ask: x = mean + sigma * sigma_vec * (B @ (D * z)), so x ~ N(mean, A A^T)
        scaling = np.broadcast_to(np.asarray(es.sigma_vec.scaling, dtype=np.float64), (self.dim,))
        a = es.sigma * scaling[:, None] * (es.sm.B * es.sm.D)
        self._dist = FullGaussian(np.array(es.mean, dtype=np.float64), a @ a.T)

    # ------------------------------------------------------------------ update
    def _emulate_ask(self, n: int) -> None:
        """Set the bookkeeping pycma's ``ask`` leaves for ``tell`` (n i.i.d. samples, no injections)."""
        es = self._es
        if es.countiter == 0:
            es.timer = _pycma().utilities.utils.ElapsedWCTime()
        else:
            es.timer.tic  # noqa: B018  (a property with a side effect: pycma's ask calls it too)
        es._flgtelldone = False
        es.ary = []
        es.number_of_injections = 0
        es.number_of_solutions_asked = n
        es._is_independent_sample = n * [True]
        es.evaluations_per_f_value = 1

    def _update(self, samples: np.ndarray, utilities: np.ndarray) -> None:
        n = samples.shape[0]
        if n < 3:
            raise ValueError(f"CMAES.tell needs at least 3 samples (pycma), got {n}")
        es = self._es
        costs = -utilities  # pycma minimises; only the ranking matters
        self._emulate_ask(n)
        sp = es.sp
        try:
            with warnings.catch_warnings():
                # pycma warns when n differs from popsize by > 2; here that is deliberate
                warnings.filterwarnings("ignore", message="The number of solutions passed to `tell`")
                if n < sp.weights.mu:
                    es.sp = self._parameters_for(n)
                es.tell(samples.copy(), costs.tolist(), check_points=False)
        finally:
            es.sp = sp
        if es.pop_injection_directions or es.pop_injection_solutions:
            raise RuntimeError("pycma queued injections for its own ask; CMAES cannot honour them")
        self._prepare_sampler()

    def _parameters_for(self, n: int):
        """pycma's strategy parameters (weights, c1, cmu, cc, ...) for a population of n."""
        es = self._es
        cma = _pycma()
        opts = cma.CMAOptions(es.opts)
        opts["popsize"] = n
        sp = cma.options_parameters.CMAParameters(es.N, opts, verbose=False)
        p = es.sm.parameters(mueff=sp.weights.mueff, lam=sp.weights.lambda_)
        sp.weights.finalize_negative_weights(es.N, p["c1"], p["cmu"])
        return sp
