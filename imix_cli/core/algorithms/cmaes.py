"""CMA-ES in numpy: pycma 4.5's update, written out, for populations it did not sample.

Hansen & Ostermeier (2001), "Completely derandomized self-adaptation in evolution
strategies", Evolutionary Computation 9(2); Hansen (2016), "The CMA Evolution Strategy:
A Tutorial", arXiv:1604.00772 (cited below as [T], with equation numbers). Paper
section 2.1.4 of Pourchot, Perrin & Sigaud (2018): full covariance, rank-based
recombination weights, evolution paths, step-size control.

Why our own and not pycma (``cma``): driving pycma with samples it did not draw worked
(the previous version of this module did it), but its ``tell`` cost ~2.5 ms per generation
at d = 130, lambda = 50 -- 57-72 % of a CMA-ES + importance-mixing run -- mostly Python
bookkeeping around two O(d^3) steps, and its state is a Python object that can only be
pickled, while checkpoints are data. This module does the same maths in a few numpy calls
and keeps its state in arrays (:class:`CMAESState`).

Same maths as pycma: every constant and every formula below was read from pycma 4.5's
source (``cma/evolution_strategy.py`` ``tell``/``ask_geno``, ``cma/sampler.py``
``GaussFullSampler``, ``cma/recombination_weights.py``, ``cma/options_parameters.py``
``CMAParameters``, ``cma/sigma_adaptation.py`` ``CMAAdaptSigmaCSA``) with the options the
pycma wrapper used: default weights with active CMA (negative weights), CSA, rank-one +
rank-mu, hsig, no mirrors, ``updatecovwait=0`` (eigendecomposition after every update),
``conditioncov_alleviate=[1e8, 1e12]``, pycma's initial C = diag(exp(1e-4 k / d)) (a
tie-breaking hack for its eigensolver, kept for equality). ``tests/test_cmaes.py`` drives
pycma's own ask/tell loop and tells the same samples to this class: mean, sigma, C, p_sigma
and p_c agree to round-off over hundreds of generations at d = 10 and d = 130.

Where we differ from pycma, on purpose:

* Ties. pycma ranks by ``np.argsort`` (order among equal values: whatever the sort does).
  Here a group of tied utilities shares the weights of the rank positions it occupies
  (fractional ranking), so the update does not depend on the order of tied members. On
  CartPole ~40 of 50 members tie at the maximum return. A position's weight enters the
  covariance update through two parts -- positive weights as is, negative weights times
  the member's Mahalanobis rescaling d / ||C^-1/2 y||^2 -- so each member gets the mean
  positive part and the mean negative part of its group's positions: the expectation of
  pycma's update over all orders of the tied members. Without ties this is pycma's update.
* Step-size control is CSA at every d (pycma switches to TPA for d >= 300), unless
  ``step_size_control="tpa"`` (below).
* Two-point step-size adaptation (``step_size_control="tpa"``; ``imix run``'s default, with and
  without mixing, so that ``eim=false,true`` changes the mixing alone). Why: CSA compares the mean's step with the step of
  *fresh* randomly ranked members. Under importance mixing a third of CMA-ES's members are
  reused, and given the loop they are not fresh draws of the current distribution (they sit
  nearer its mean and ahead along the last move: constant fitness, d = 130, N = 50, E[z^2] 0.977,
  offset +0.05 spreads), so CSA misreads their steps: sigma shrank to 0.57x the run without
  mixing under constant fitness, collapsed on Acrobot (median final sigma 2.3e-4 against 0.19),
  and stayed 2.9x too large on the noise-free sphere, where the reused elites that pulled the
  mean keep pulling it. Normalising CSA's step by its length under random ranks of the same
  members fixed constant fitness and failed the sphere even without mixing
  (benchmarks/cma_step_size.py; docs/research/bias.md, "CMA-ES's step size"). TPA's signal
  does not come from the members at all: each generation two extra points m +- sigma r u are
  evaluated afresh, u the last move of the mean (unit length in sigma^2 C's metric) and r the
  length of a fresh N(0, I) draw, and sigma grows when the point ahead ranks better than the
  one behind, shrinks otherwise (Hansen 2008, "CMA-ES with two-point step-size adaptation";
  the constants, c = 0.3, |z|^0.5 and damp = 0.7 + 2 ln d + 2 ln max(1, lambda - d), are pycma
  4.5's ``CMAAdaptSigmaTPA``). Under random ranks the two points are exchangeable, so log sigma
  does not drift, whatever the members; under constant fitness they tie and sigma stays. The
  price: 2 episodes per generation. Measured on the paper's tasks (25 seeds,
  benchmarks/cma_step_size.py --tasks): docs/research/bias.md. Unlike pycma, the two points are
  not members of the generation: they take no part in the mean or covariance update and are
  never reused, so the generation stays a draw of the distribution. The z of a generation is
  computed on the raw fitness (stored returns for reused members), not on the weight-decayed
  utilities, whose decay term the points do not have.
* No termination criteria, no logging, no bounds, no integer variables, no elitism.
* Linear algebra: products, the eigendecomposition (EISPACK's tred2 + tql2 instead of LAPACK's
  dsyevd) and the sampler's Cholesky factor are :mod:`imix_cli.core.numerics.linalg_kernels`' compiled loops,
  whose order of summation does not depend on the BLAS kernel the CPU selects (so neither do a
  run's bits); they differ from pycma's numpy/LAPACK results by round-off only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from imix_cli.core import numerics as xp
from imix_cli.core.algorithms.base import CompiledStep, EvolutionStrategy, Params
from imix_cli.core.distributions import FullGaussian
from imix_cli.core.numerics import elementary as el
from imix_cli.core.numerics import linalg_kernels as lk


def _pow(x, y) -> float:
    """``x ** y`` of Python or numpy scalars as Python and numpy compute it (the C library's pow), but with
    :func:`imix_cli.core.numerics.elementary.pow`: the same bits on every CPU (pycma's formulas are kept as they are)."""
    return xp.power(float(x), float(y))


def _log(x) -> float:
    return xp.log(float(x))


#: Largest dimension CMAES accepts. Each seed keeps four d x d float64 matrices (C, its
#: eigenvectors, the distribution's covariance and Cholesky factor: 128 MB at d = 2000) and
#: eigendecomposes C every generation, O(d^3). Measured ``tell`` per generation, lambda = 50
#: (benchmarks/cmaes_speed.py --big 500 1000, quiet 2-core AMD EPYC VM, 2026-11-29): d = 500 0.074 s, 1000
#: 0.53 s (0.120 s and 0.94 s before tred2's loops went four rows at a time), i.e. ~30 min per seed for the
#: paper's 400 generations at d = 2000 (d^3 from 1000). The eigensolver (linalg_kernels.eigh: the same bits on
#: every CPU) is unblocked: LAPACK's took 0.03 s and 0.26 s at d = 500 and 1000 in an earlier session (shared
#: VM). Above the limit SNES/OpenES (O(d) per member) are the tools.
MAX_DIM = 2000

#: Smallest population CMAES accepts (lambda): its recombination weights need at least 2 parents and one non-parent.
MIN_POPSIZE = 3

#: CMA options this class implements (pycma option names and defaults).
SUPPORTED_OPTIONS = {
    # active CMA: negative recombination weights in the covariance update
    "CMA_active": True,
    # [coordinate condition, condition] of C above which pycma re-parametrises (see
    # _alleviate_conditioning_kernel); a false value switches it off
    "conditioncov_alleviate": (1e8, 1e12),
}

#: Values of :attr:`CMAESParams.step_size_control`.
STEP_SIZE_CONTROLS = ("csa", "tpa")


# pycma's GaussFullSampler raises when an eigenvalue is <= 0 and retries after adding the
# smallest previous eigenvalue to the diagonal; it recurses without limit, we give up here.
_MAX_EIGEN_REPAIRS = 20

#: No fitness: TPA's points when there are none (CSA, or before the mean has moved).
_NO_FITNESS = np.empty(0)


def check_dimension(dim: int) -> None:
    """Raise ValueError (one line) if CMA-ES is unreasonable in ``dim`` dimensions."""
    if dim > MAX_DIM:
        raise ValueError(
            f"algo=cmaes: d = {dim} parameters exceeds CMA-ES's limit of {MAX_DIM} "
            f"(a {dim}x{dim} covariance, O(d^3) per generation); use algo=snes or algo=openes (or cem)"
        )


def expected_norm(dim: int) -> float:
    """E||N(0, I_d)||, as pycma's ``Mh.chiN``: exact for d <= 100 (sqrt(2) Gamma((d+1)/2) / Gamma(d/2)),
    sqrt(d) (1 - 1/(4d) + 1/(32 d^2)) above (pycma's approximation, relative error < 1e-5)."""
    if dim <= 100:
        return math.sqrt(2.0) * _gamma((dim + 1) / 2) / _gamma(dim / 2)
    return _pow(dim, 0.5) * (1 - 1.0 / (4 * dim) + 1.0 / (32 * dim**2))


# Python's math.gamma for 0 < x <= 200 (CPython's m_tgamma: exact factorials for integers up to 23, else
# Lanczos' approximation with g = 6.0247, N = 13), with exp and pow from imix_cli.core.numerics.elementary instead of the
# C library's: the same values here, the same bits on every CPU.
_LANCZOS_G = 6.024680040776729583740234375
_LANCZOS_G_MINUS_HALF = 5.524680040776729583740234375
_LANCZOS_NUM = (
    23531376880.410759688572007674451636754734846804940, 42919803642.649098768957899047001988850926355848959,
    35711959237.355668049440185451547166705960488635843, 17921034426.037209699919755754458931112671403265390,
    6039542586.3520280050642916443072979210699388420708, 1439720407.3117216736632230727949123939715485786772,
    248874557.86205415651146038641322942321632125127801, 31426415.585400194380614231628318205362874684987640,
    2876370.6289353724412254090516208496135991145378768, 186056.26539522349504029498971604569928220784236328,
    8071.6720023658162106380029022722506138218516325024, 210.82427775157934587250973392071336271166969580291,
    2.5066282746310002701649081771338373386264310793408,
)  # fmt: skip
_LANCZOS_DEN = (0.0, 39916800.0, 120543840.0, 150917976.0, 105258076.0, 45995730.0, 13339535.0, 2637558.0, 357423.0, 32670.0, 1925.0, 66.0, 1.0)


def _gamma(x: float) -> float:
    """Gamma(x) for 0 < x <= 200, as Python's ``math.gamma`` computes it."""
    if x == math.floor(x) and x <= 23:
        return float(math.factorial(int(x) - 1))
    num = den = 0.0
    if x < 5.0:
        for a, b in zip(reversed(_LANCZOS_NUM), reversed(_LANCZOS_DEN)):
            num, den = num * x + a, den * x + b
    else:
        for a, b in zip(_LANCZOS_NUM, _LANCZOS_DEN):
            num, den = num / x + a, den / x + b
    y = x + _LANCZOS_G_MINUS_HALF
    z = (y - x) - _LANCZOS_G_MINUS_HALF if x > _LANCZOS_G_MINUS_HALF else (y - _LANCZOS_G_MINUS_HALF) - x
    z = z * _LANCZOS_G / y
    r = num / den / xp.exp(y)
    r += z * r
    if x < 140.0:
        return r * xp.power(y, x - 0.5)
    half = xp.power(y, x / 2.0 - 0.25)
    return r * half * half


class _Parameters:
    """Strategy parameters for population size ``lam`` in dimension ``dim`` (pycma's values).

    Attributes: ``weights`` (lam values, decreasing; positive ones sum to 1), ``mu`` (number
    of positive weights), ``mueff``, ``cc``, ``c1``, ``cmu``.
    """

    def __init__(self, dim: int, lam: int, active: bool):
        # [T] (49): w'_i = ln((lam + 1) / 2) - ln i; pycma normalises the positive ones to
        # sum 1 and the negative ones to sum -1 (RecombinationWeights.__init__), in Python
        # floats, summed left to right as pycma does.
        w = [_log((lam + 1) / 2.0) - _log(i) for i in range(1, lam + 1)]
        mu = sum(x > 0 for x in w)
        spos = sum(w[:mu])
        w = [x / spos for x in w]
        mueff = 1 / sum(_pow(x, 2) for x in w[:mu])  # [T] (8): variance effective selection mass
        sneg = sum(w[mu:])
        if sneg != 0:
            w[mu:] = [x / -sneg for x in w[mu:]]
        n = float(dim)
        # learning rates as pycma's sampler gives them (interfaces.parameters), [T] (56), (57)
        c1 = min((1, lam / 6)) * 2 / (_pow(n + 1.3, 2.0) + mueff)
        cmu = min((1 - c1, 2 * (0.25 + mueff - 2 + 1 / mueff) / (_pow(n + 2, 2) + 2 * mueff / 2)))
        # [T] (56) with pycma's limit_fac_cc = 4: cc = (4 + mueff/n) / (n + 4 + 2 mueff/n)
        cc = 1.0 * _pow(4.0 + mueff / n, 1.0) / (_pow(n, 1.0) + _pow(4.0 + 2 * mueff / n, 1.0))
        if w[-1] < 0:
            if active and cmu > 0:
                # RecombinationWeights.finalize_negative_weights, [T] (53): scale the negative
                # weights to sum -(1 + c1/cmu) (no decay of C), then cap their sum so that C
                # stays positive definite, and by 1 + 2 mueff^- / (mueff + 2).
                w = self._set_negative_sum(w, mu, 1 + c1 / cmu)
                w = self._limit_negative_sum(w, mu, (1 - c1 - cmu) / cmu / n)
                sneg = sum(w[mu:])
                mueff_minus = 0 if sneg == 0 else _pow(sneg, 2) / sum(_pow(x, 2) for x in w[mu:])
                w = self._limit_negative_sum(w, mu, 1 + 2 * mueff_minus / (mueff + 2))
            elif not active:
                w = [x if x >= 0 else 0.0 * x for x in w]  # zero_negative_weights
        self.lam, self.mu, self.mueff = lam, mu, mueff
        self.weights = w
        self.cc, self.c1, self.cmu = cc, c1, cmu

    @staticmethod
    def _set_negative_sum(w, mu, value):
        factor = abs(abs(value) / sum(w[mu:]))
        return w[:mu] + [x * factor for x in w[mu:]]

    @staticmethod
    def _limit_negative_sum(w, mu, value):
        value = abs(value)
        if sum(w[mu:]) >= -value:
            return w
        factor = abs(value / sum(w[mu:]))
        return w if factor >= 1 else w[:mu] + [x * factor for x in w[mu:]]

    def resized(self, n: int) -> list:
        """pycma's ``RecombinationWeights.__call__``: ``n`` weights for a population of ``n``
        (n >= mu): the mu positive weights, then the most negative ones, zeros padded in."""
        w, mu, lam = self.weights, self.mu, self.lam
        if n < lam:
            return w[:mu] + w[mu - n :]
        if n > lam:
            return w[:mu] + (n - lam) * [0] + w[mu:]
        return w


@dataclass(frozen=True)
class CMAESParams(Params):
    """:class:`~imix_cli.core.algorithms.base.Params` (``popsize`` is lambda, mu = lambda // 2
    positive weights; ``sigma`` the initial step size sigma0; ``lr`` is ignored) and CMA-ES's own options."""

    #: The pycma options of :data:`SUPPORTED_OPTIONS`, e.g. ``{"CMA_active": False}``; any
    #: other key is refused. None: pycma's defaults.
    cma_options: dict | None = None

    #: Step-size control: ``"csa"`` (pycma's cumulative step-size adaptation) or ``"tpa"``
    #: (two-point adaptation: two extra fresh evaluations per generation, :meth:`CMAES.probes`;
    #: module docstring). The class's default is pycma's rule, which a plain ask/tell loop needs
    #: (TPA asks for two extra evaluations); ``imix run``'s (``run_default``) is TPA with *and*
    #: without mixing: CSA misreads reused members, and an ``eim=false,true`` sweep whose arms ran
    #: two step-size rules would compare the rules as well as the mixing (docs/research/bias.md).
    step_size_control: str = field(default="csa", metadata={
        "choices": STEP_SIZE_CONTROLS, "run_default": "tpa", "short": "csa | tpa (default tpa, with and without mixing)",
        "doc": "`algo=cmaes` only: `tpa` (two-point adaptation: two extra fresh episodes per generation along the last move "
               "of the mean; its signal does not come from reused members; the default, with and without mixing, so that "
               "`eim=false,true` changes the mixing alone), `csa` (pycma's cumulative step-size adaptation, the paper's CMA-ES; "
               "with mixing it misreads reused members); docs/research/bias.md",
    })  # fmt: skip


class CMAESState(NamedTuple):
    """CMA-ES's search state, in pycma's genotype coordinates (x = T g): the one record the update moves and the
    checkpoint saves (:class:`~imix_cli.core.algorithms.base.CompiledStep` says why one record). :class:`CMAES` reads
    and writes its fields as attributes of the same names (``es.C``, ``es.step_size``, ...)."""

    #: the mean, shape (d,)
    mean_geno: np.ndarray
    #: C, shape (d, d)
    C: np.ndarray
    #: D, the square roots of C's eigenvalues, ascending, from the last decomposition (the next update uses it)
    eigenvalues_sqrt: np.ndarray
    #: B, C's eigenvectors as columns, shape (d, d)
    eigenvectors: np.ndarray
    #: pycma's sigma_vec (coordinate condition alleviation), shape (d,)
    scaling: np.ndarray
    #: the step-size path, shape (d,)
    p_sigma: np.ndarray
    #: the covariance path, shape (d,)
    p_c: np.ndarray
    #: pycma's sigma, shape (1,) (``CMAES.sigma`` stays sigma0)
    step_size: np.ndarray
    #: pycma's countiter, the number of updates, int64 of shape (1,)
    countiter: np.ndarray
    #: T and T^-1 once pycma's alleviate_conditioning has fired (``transformed``), else the identity; shape (d, d)
    transform: np.ndarray
    transform_inverse: np.ndarray
    transformed: np.ndarray
    #: TPA's last move of the mean (genotype) and its state s; shapes (d,) and (1,) with TPA, (0,) with CSA (so that
    #: a CSA state does not load into a TPA ES)
    tpa_move: np.ndarray
    tpa_s: np.ndarray


class CMAESConstants(NamedTuple):
    """What :func:`cmaes_update` reads and never writes: pycma's strategy parameters for the population told
    (:meth:`CMAES._constants`, one record per population size) and the ES's own constants."""

    #: the position weights of the n members told, best first (pycma's ``RecombinationWeights``, resized to n)
    weights: np.ndarray
    mueff: float
    cc: float
    c1: float
    cmu: float
    cs: float
    damps: float
    #: E||N(0, I_d)||
    chi_d: float
    #: the step-size control is TPA (else CSA), and TPA's damping
    tpa: bool
    tpa_damp: float
    #: sigma0 (pycma's redistribution of a huge sigma into C compares with it)
    sigma0: float
    #: ``conditioncov_alleviate``'s two limits (0: off)
    coordinate_limit: float
    condition_limit: float


@njit(cache=True)
def _maximum(a, b):
    """``np.maximum`` of two numbers: a NaN ``a`` kept, ``b`` when they compare equal (numpy's: maximum(-0.0, 0.0) is
    0.0, which matters for the -0.0 weights of ``CMA_active=False``)."""
    return a if (a > b or math.isnan(a)) else b


@njit(cache=True)
def _minimum(a, b):
    """``np.minimum`` of two numbers, as :func:`_maximum` (minimum(-0.0, 0.0) is 0.0)."""
    return a if (a < b or math.isnan(a)) else b


@njit(cache=True)
def _shared_among_ties_kernel(weights, sorted_utilities):
    """Per position of a best-first ranking: the mean positive and mean negative weight of the group of tied
    utilities the position belongs to (fractional ranking); without ties, max(w, 0) and min(w, 0) themselves."""
    n = weights.shape[0]
    w_pos = np.empty(n)
    w_neg = np.empty(n)
    all_new = True
    for i in range(n):
        w_pos[i] = _maximum(weights[i], 0.0)
        w_neg[i] = _minimum(weights[i], 0.0)
        if i > 0 and not (sorted_utilities[i] != sorted_utilities[i - 1]):
            all_new = False
    if all_new:
        return w_pos, w_neg
    group = np.empty(n, np.int64)
    g = -1
    for i in range(n):
        if i == 0 or sorted_utilities[i] != sorted_utilities[i - 1]:
            g += 1
        group[i] = g
    sums_pos = np.zeros(g + 1)
    sums_neg = np.zeros(g + 1)
    sizes = np.zeros(g + 1)
    for i in range(n):
        sums_pos[group[i]] += w_pos[i]
        sums_neg[group[i]] += w_neg[i]
        sizes[group[i]] += 1.0
    shared_pos = np.empty(n)
    shared_neg = np.empty(n)
    for i in range(n):
        shared_pos[i] = sums_pos[group[i]] / sizes[group[i]]
        shared_neg[i] = sums_neg[group[i]] / sizes[group[i]]
    return shared_pos, shared_neg


@njit(cache=True)
def _decompose_kernel(state):
    """C = B D^2 B^T on the symmetrised C, eigenvalues ascending (pycma's ``GaussFullSampler._decompose_C``), in place
    of ``state``. An eigenvalue <= 0 (or a failed decomposition): pycma adds the smallest previous eigenvalue to the
    diagonal and tries again, without limit; we give up after :data:`_MAX_EIGEN_REPAIRS` repairs and return False."""
    C = state.C
    d = C.shape[0]
    previous = state.eigenvalues_sqrt.copy()
    for _ in range(_MAX_EIGEN_REPAIRS):
        sym = np.empty((d, d))
        for i in range(d):
            for j in range(d):
                sym[i, j] = (C[i, j] + C[j, i]) / 2
        C[:, :] = sym
        if np.all(np.isfinite(C)):
            values, vectors_t, ok = lk.eigh_kernel(C)
            if ok and np.all(values > 0):  # ascending (the kernel sorts them), as pycma's
                for i in range(d):
                    for j in range(d):
                        state.eigenvectors[i, j] = vectors_t[j, i]
                for i in range(d):
                    state.eigenvalues_sqrt[i] = math.sqrt(values[i])
                return True
        # pycma: "covariance matrix eigen decomposition failed"; add the smallest previous eigenvalue to the diagonal
        shift = el.pow(np.min(previous), 2.0)
        for i in range(d):
            C[i, i] += shift
        for i in range(d):
            previous[i] = math.sqrt(previous[i] * previous[i] + shift)
    return False


@njit(cache=True)
def _alleviate_conditioning_kernel(state, constants):
    """pycma's ``conditioncov_alleviate``, in place of ``state``; returns (C was decomposed or reset here, no
    decomposition failed).

    * Coordinate condition max(diag C) / min(diag C) >= ``constants.coordinate_limit``
      (``alleviate_conditioning_in_coordinates``): C becomes its correlation matrix, the standard deviations move into
      ``scaling`` (pycma's ``sigma_vec``).
    * Condition of C >= ``constants.condition_limit``, judged from the previous decomposition as pycma does
      (``alleviate_conditioning``, once per run): the coordinates become g = T^-1 x with T = S C^1/2 (from that
      decomposition) and C is reset, p_c mapped along. The sampling distribution stays the same up to the C update of
      this generation, which pycma discards here.
    """
    C = state.C
    d = C.shape[0]
    decomposed = False
    if constants.coordinate_limit:
        diag = np.diag(C).copy()
        if np.max(diag) / np.min(diag) >= constants.coordinate_limit:
            if not _decompose_kernel(state):  # pycma's to_correlation_matrix decomposes first (and symmetrises)
                return True, False
            factors = np.sqrt(np.diag(C).copy())
            corr = np.empty((d, d))
            for i in range(d):
                for j in range(d):
                    corr[i, j] = C[i, j] / factors[j] / factors[i]
            for i in range(d):
                for j in range(d):
                    C[i, j] = (corr[i, j] + corr[j, i]) / 2.0
            if not _decompose_kernel(state):
                return True, False
            for i in range(d):
                state.scaling[i] = state.scaling[i] * factors[i]
                state.p_c[i] = state.p_c[i] / factors[i]
            decomposed = True
    D = state.eigenvalues_sqrt
    if not state.transformed[0] and constants.condition_limit and el.pow(D[d - 1] / D[0], 2.0) >= constants.condition_limit:
        B = state.eigenvectors
        b_over_d = np.empty((d, d))
        b_times_d = np.empty((d, d))
        for i in range(d):
            for j in range(d):
                b_over_d[i, j] = B[i, j] / D[j]
                b_times_d[i, j] = B[i, j] * D[j]
        bt = np.ascontiguousarray(B.T)
        tf_inv = lk.mat_mat_kernel(b_over_d, bt)
        tf = lk.mat_mat_kernel(b_times_d, bt)
        for i in range(d):  # the sampler reset (not decomposed again)
            for j in range(d):
                C[i, j] = 0.0
                B[i, j] = 0.0
            C[i, i] = el.exp((1e-4 / d) * i)
            B[i, i] = 1.0
        for i in range(d):
            D[i] = math.sqrt(C[i, i])
        p_c = lk.mat_vec_kernel(tf_inv, state.p_c)
        state.p_c[:] = p_c
        for i in range(d):
            for j in range(d):
                state.transform[i, j] = state.scaling[i] * tf[i, j]
                state.transform_inverse[i, j] = tf_inv[i, j] / state.scaling[j]
        state.transformed[0] = True
        state.scaling[:] = 1.0
        mean = lk.mat_vec_kernel(state.transform_inverse, state.mean_geno)
        state.mean_geno[:] = mean
        decomposed = True
    return decomposed, True


@njit(cache=True)
def _tpa_log_step(state, constants, probe_fitness, fitness):
    """log sigma's change from TPA's two points (pycma's ``CMAAdaptSigmaTPA.update2``, maximising), ``state.tpa_s``
    moved: z = (#{f > f_behind} - #{f > f_ahead}) / (n - 1) over the two points and the generation; 0 without points."""
    if probe_fitness.shape[0] == 0:
        return 0.0
    n = probe_fitness.shape[0] + fitness.shape[0]
    f = np.empty(n)
    f[: probe_fitness.shape[0]] = probe_fitness
    f[probe_fitness.shape[0] :] = fitness
    for i in range(n):
        if not math.isfinite(f[i]):
            f[i] = -np.inf
    above_behind = 0
    above_ahead = 0
    for i in range(n):
        if f[i] > f[1]:
            above_behind += 1
        if f[i] > f[0]:
            above_ahead += 1
    z = (above_behind - above_ahead) / (n - 1)
    state.tpa_s[0] = (1 - 0.3) * state.tpa_s[0] + 0.3 * math.copysign(el.pow(abs(z), 0.5), z)
    return state.tpa_s[0] / constants.tpa_damp


@njit(cache=True)
def cmaes_update(samples, utilities, fitness, probe_fitness, state, constants, mean_weights):
    """One CMA-ES update (module docstring; [T] = Hansen's tutorial), in place of ``state`` (:class:`CMAESState`):
    the one copy of the maths, which :meth:`CMAES._update` runs. ``fitness``/``probe_fitness``: the generation's raw
    fitness and TPA's two points' (size 0: none); ``mean_weights`` receives each member's positive weight. Returns
    False when C stays indefinite after pycma's repairs (the caller raises)."""
    n, d = samples.shape
    sigma, cs, cc = state.step_size[0], constants.cs, constants.cc
    # read before anything below writes them (the redistribution, the alleviation and the decomposition come last)
    B, D, scaling = state.eigenvectors, state.eigenvalues_sqrt, state.scaling
    x = samples if not state.transformed[0] else lk.mat_mat_kernel(samples, np.ascontiguousarray(state.transform_inverse.T))
    state.countiter[0] += 1

    # Selection: best first. Tied utilities share their positions' weights, separately for the positive and the
    # negative parts (module docstring).
    order = np.argsort(-utilities, kind="mergesort")  # stable, as numpy's kind="stable"
    xs = np.empty((n, d))
    sorted_u = np.empty(n)
    for r in range(n):
        xs[r] = x[order[r]]
        sorted_u[r] = utilities[order[r]]
    w_pos, w_neg = _shared_among_ties_kernel(constants.weights, sorted_u)
    for r in range(n):
        mean_weights[order[r]] = w_pos[r]  # m' - m = sum_i w_i (x_i - m): the mean weights, by member

    # [T] (9): m' = sum_i w_i x_{i:lambda} over the positive weights (pycma: cmean = 1)
    mean_old = state.mean_geno.copy()
    k = 0
    for r in range(n):
        if w_pos[r] != 0.0:
            k = r + 1  # without ties: mu
    mean_new = lk.vec_mat_kernel(w_pos[:k], xs[:k])
    state.mean_geno[:] = mean_new
    dm = np.empty(d)
    for j in range(d):
        dm[j] = mean_new[j] - mean_old[j]

    # [T] (43): p_sigma <- (1 - cs) p_sigma + sqrt(cs (2 - cs) mueff) C^-1/2 (m' - m) / sigma, C^-1/2 = B D^-1 B^T
    scaled = np.empty(d)
    for j in range(d):
        scaled[j] = dm[j] / scaling[j]
    half = lk.vec_mat_kernel(scaled, B)
    for j in range(d):
        half[j] = half[j] / D[j]
    z = lk.mat_vec_kernel(B, half)
    factor = el.pow(constants.mueff, 0.5) / sigma / 1.0
    path = math.sqrt(cs * (2 - cs))
    p_sigma = state.p_sigma
    for j in range(d):
        p_sigma[j] *= 1 - cs
        p_sigma[j] += path * (z[j] * factor)
    # hsig ([T] p. 29; pycma's bias-corrected form): stall p_c when ||p_sigma|| is large
    squares = np.empty(d)
    for j in range(d):
        squares[j] = p_sigma[j] * p_sigma[j]
    squared_sum = lk.numpy_sum(squares) / (1 - el.pow(1 - cs, float(2 * state.countiter[0])))
    hsig = 1 if squared_sum / d - 1 < 1 + 4.0 / (d + 1) else 0
    # [T] (45): p_c <- (1 - cc) p_c + hsig sqrt(cc (2 - cc) mueff) (m' - m) / sigma
    pc_factor = hsig * (el.pow(cc * (2 - cc) * constants.mueff, 0.5) / sigma / 1.0)
    for j in range(d):
        state.p_c[j] = (1 - cc) * state.p_c[j] + pc_factor * dm[j] / scaling[j]

    # [T] (47), (46): C <- (1 + c1 delta(hsig) - c1 - cmu sum w) C + c1 p_c p_c^T + cmu sum_i w_i° y_i y_i^T,
    # y_i = (x_i - m) / sigma, w_i° = w_i for w_i >= 0 and w_i d / ||C^-1/2 y_i||^2 otherwise (active CMA). pycma folds
    # delta(hsig) into c1a and gives p_c the weight c1a with length rescaled so that c1a ||v||^2 = c1 ||p_c||^2; so do we.
    c1, cmu = constants.c1, constants.cmu
    c1a = c1 * (1 - (1 - hsig * hsig) * cc * (2 - cc))
    vectors = np.empty((n + 1, d))
    for r in range(n):
        for j in range(d):
            vectors[r + 1, j] = (xs[r, j] - mean_old[j]) / (sigma * scaling[j])
    total = c1a  # sampler.update's decay, summed in Python's order
    for r in range(constants.weights.shape[0]):
        total += cmu * constants.weights[r]
    decay = 1 - total
    coef = np.empty(n + 1)
    coef[0] = c1a
    n_negative = 0
    for r in range(n):
        coef[r + 1] = cmu * w_pos[r]
        if w_neg[r] != 0.0:
            n_negative += 1
    if n_negative:
        negative = np.empty(n_negative, np.int64)
        m = 0
        for r in range(n):
            if w_neg[r] != 0.0:
                negative[m] = r
                m += 1
        whitened = lk.mat_mat_kernel(vectors[negative + 1], B)
        for m in range(n_negative):
            acc = 0.0
            for j in range(d):
                v = whitened[m, j] / D[j]
                acc += v * v
            norm = math.sqrt(acc) + 1e-9
            r = negative[m]
            coef[r + 1] += (cmu * w_neg[r]) * (d / (norm * norm))
    pc_length = el.pow(c1 / (c1a + 1e-23), 0.5)
    for j in range(d):
        vectors[0, j] = pc_length * state.p_c[j]
    gram = lk.weighted_gram_kernel(coef, vectors)
    C = state.C
    for i in range(d):
        for j in range(d):
            C[i, j] *= decay
            C[i, j] += gram[i, j]

    # [T] (44): sigma <- sigma exp(cs / damps (||p_sigma|| / E||N(0, I)|| - 1)), the change of log sigma clipped to
    # +-1 (pycma's max_delta_log_sigma); with TPA, from the two points instead (module docstring)
    if constants.tpa:
        s = _tpa_log_step(state, constants, probe_fitness, fitness)
        for j in range(d):
            state.tpa_move[j] = mean_new[j] - mean_old[j]
    else:
        s = math.sqrt(lk.numpy_sum(squares)) / constants.chi_d - 1
        s *= cs / constants.damps
    if -1.0 > s:
        s = -1.0
    if 1.0 < s:
        s = 1.0
    state.step_size[0] *= el.exp(s)
    # pycma moves a huge sigma into C (_redistribute_sigma_above = 1e9), same distribution
    if state.step_size[0] > 1e9 * constants.sigma0:
        alpha = state.step_size[0] / el.pow(np.max(np.diag(C).copy()), 0.5)
        if alpha > 1:
            root = el.pow(alpha, 0.5)
            for i in range(d):
                for j in range(d):
                    C[i, j] *= alpha
                state.eigenvalues_sqrt[i] = state.eigenvalues_sqrt[i] * root
            state.step_size[0] /= root

    # what pycma's ask does before it samples: alleviate conditioning, then decompose C
    decomposed, ok = _alleviate_conditioning_kernel(state, constants)
    if not ok:
        return False
    if not decomposed:
        return _decompose_kernel(state)
    return True


@njit(cache=True)
def cmaes_distribution(state):
    """The search distribution of ``state``: x = T (mean + sigma * scaling * B D z), i.e. N(T mean, sigma^2 T S C S T^T)
    with S = diag(scaling), as :class:`~imix_cli.core.distributions.FullGaussian` holds it -- ``(mean, cov, low,
    log_norm, ok)``: the covariance symmetrised (0.5 (cov + cov^T)), its Cholesky factor and the log-normaliser; ``ok``
    False when the covariance is not positive definite. The one copy: :meth:`CMAES._set_distribution` and the compiled
    generation loop both run it."""
    d = state.mean_geno.shape[0]
    s2 = el.pow(state.step_size[0], 2.0)
    scaling = state.scaling
    cov = np.empty((d, d))
    for i in range(d):
        for j in range(d):
            cov[i, j] = state.C[i, j] * (s2 * (scaling[i] * scaling[j]))
    mean = state.mean_geno.copy()
    if state.transformed[0]:
        mean = lk.mat_vec_kernel(state.transform, mean)
        cov = lk.mat_mat_kernel(lk.mat_mat_kernel(state.transform, cov), np.ascontiguousarray(state.transform.T))
    sym = np.empty((d, d))
    for i in range(d):
        for j in range(d):
            sym[i, j] = 0.5 * (cov[i, j] + cov[j, i])
    low, ok = lk.cholesky_kernel(sym)
    if not ok:
        return mean, sym, low, 0.0, False
    logs = lk.log_kernel(np.diag(low).copy())
    return mean, sym, low, -0.5 * d * xp.LOG_2PI - lk.numpy_sum(logs), True


@njit(cache=True)
def cmaes_probes(rng, state, constants, out):
    """TPA's two test points m +- sigma r u into ``out`` (2, d), from ``rng`` (u the last move of the mean, of unit
    length in sigma^2 C's metric; r the length of a fresh N(0, I) draw); returns how many: 2, or 0 with CSA and before
    the mean has moved. The one copy: :meth:`CMAES.probes` and the compiled generation loop both run it."""
    if not constants.tpa:
        return 0
    move = state.tpa_move
    d = move.shape[0]
    moved = False
    for j in range(d):
        if move[j] != 0.0:
            moved = True
    if not moved:
        return 0
    scaled = np.empty(d)
    for j in range(d):
        scaled[j] = move[j] / state.scaling[j]
    whitened = lk.vec_mat_kernel(scaled, state.eigenvectors)
    for j in range(d):
        whitened[j] = whitened[j] / state.eigenvalues_sqrt[j] / state.step_size[0]
    draw = np.empty(d)
    for j in range(d):
        draw[j] = rng.standard_normal()
    # lengths by the fixed-order loop, not numpy's BLAS dot: the same bits under every CPU kernel
    dd = 0.0
    ww = 0.0
    for j in range(d):
        dd += draw[j] * draw[j]
    for j in range(d):
        ww += whitened[j] * whitened[j]
    length = math.sqrt(dd / ww)
    points = np.empty((2, d))
    for j in range(d):
        y = move[j] * length
        points[0, j] = state.mean_geno[j] + y
        points[1, j] = state.mean_geno[j] - y
    if state.transformed[0]:
        points = lk.mat_mat_kernel(points, np.ascontiguousarray(state.transform.T))
    out[:2] = points
    return 2


def _field(name: str, scalar=None):
    """An attribute of :class:`CMAES` that is field ``name`` of its state record (``scalar``: float or int, a
    (1,)-array field read as a number and written in place)."""
    if scalar is None:

        def fget(self):
            return getattr(self.state, name)

        def fset(self, value):
            self.state = self.state._replace(**{name: value})

    else:

        def fget(self):
            return scalar(getattr(self.state, name)[0])

        def fset(self, value):
            getattr(self.state, name)[0] = value

    return property(fget, fset, doc=f"Field ``{name}`` of :attr:`CMAES.state` (:class:`CMAESState`).")


class CMAES(EvolutionStrategy):
    """CMA-ES: N(mean, sigma^2 C) with full C, pycma's update (see the module docstring).

    ``CMAES(dim, params=None, *, mean=None, **fields)``: see
    :class:`~imix_cli.core.algorithms.base.EvolutionStrategy` and :class:`CMAESParams`; ``mean``
    is x0 and ``dim`` must be <= :data:`MAX_DIM`.

    Populations whose size n differs from ``popsize`` (the base class allows it): for
    n >= mu, pycma's handling -- the same mu, mueff, learning rates and positive weights,
    the most negative weights kept for the worst members, zeros padded in the middle if
    n > lambda. For 3 <= n < mu (pycma refuses), that one update uses the strategy
    parameters of lambda = n (weights, mueff, c1, cmu, cc; cs and damps stay). n >= 3.
    """

    name = "cmaes"
    Params = CMAESParams

    def _setup(self) -> None:
        cma_options = self.params.cma_options
        if self.popsize < MIN_POPSIZE:
            raise ValueError(f"CMAES needs popsize >= {MIN_POPSIZE}, got {self.popsize}")
        check_dimension(self.dim)
        unknown = sorted(set(cma_options or {}) - set(SUPPORTED_OPTIONS))
        if unknown:
            raise ValueError(f"cma_options: unsupported {unknown}; CMAES implements {sorted(SUPPORTED_OPTIONS)}")
        opts = {**SUPPORTED_OPTIONS, **(cma_options or {})}
        self.active = bool(opts["CMA_active"])
        alleviate = opts["conditioncov_alleviate"]
        self.alleviate_limits = (float(alleviate[0]), float(alleviate[-1])) if alleviate else (0.0, 0.0)

        d = self.dim
        self._params = {self.popsize: _Parameters(d, self.popsize, self.active)}
        self._constants_by_n = {}
        p = self._params[self.popsize]
        # CSA constants (CMAAdaptSigmaCSA.compute_cs / compute_damps; [T] (55)) with no
        # mirrors: cs = min(1/2, (mueff + 2) / (d + mueff + 3)),
        # damps = 1 + 2 max(0, a sqrt((mueff - 1) / (d + 1)) - 1) + cs, a = max(1, 3 (1 - 2^(-d/9)))
        self.cs = min((0.5, _pow(p.mueff + 2, 1.0) / (_pow(d, 1.0) + _pow(p.mueff + 3, 1.0))))
        damp_in = max((1, 3 * (1 - _pow(0.5, d / 9))))
        self.damps = (
            0.5 + _pow(min((1, _pow(0 / (0.159 * self.popsize) - 1, 2))), 1) / 2 + 2 * max((0, damp_in * _pow((p.mueff - 1) / (d + 1), 0.5) - 1)) + self.cs
        )
        self.chi_d = expected_norm(d)

        if self.params.step_size_control not in ("csa", "tpa"):
            raise ValueError(f"step_size_control={self.params.step_size_control!r}: must be 'csa' or 'tpa'")
        # the state (CMAESState): pycma's genotype coordinates, x = T g; T = I until the 1e12 condition alleviation sets it
        C = np.diag(xp.exp((1e-4 / d) * np.arange(d)))  # pycma's initial C (see module doc)
        tpa = self.params.step_size_control == "tpa"
        state = CMAESState(
            mean_geno=self.initial_mean.copy(), C=C, eigenvalues_sqrt=np.sqrt(np.diag(C)).copy(), eigenvectors=np.eye(d),
            scaling=np.ones(d), p_sigma=np.zeros(d), p_c=np.zeros(d), step_size=np.array([self.sigma]), countiter=np.zeros(1, dtype=np.int64),
            transform=np.eye(d), transform_inverse=np.eye(d), transformed=np.zeros(1, dtype=np.bool_),
            tpa_move=np.zeros(d if tpa else 0), tpa_s=np.zeros(1 if tpa else 0),
        )  # fmt: skip
        # TPA (pycma's CMAAdaptSigmaTPA constants): the damping; its state s and the last move of the mean (genotype),
        # from which the next two test points are made, are in the record
        self.tpa_damp = 0.7 + 2 * _log(d) + 2 * _log(max(1, self.popsize - d))
        self._probe_fitness = None
        self.set_state(state)

    # ------------------------------------------------------------ the state record's fields, as attributes
    mean_geno, C, eigenvalues_sqrt, eigenvectors = _field("mean_geno"), _field("C"), _field("eigenvalues_sqrt"), _field("eigenvectors")
    scaling, p_sigma, p_c, tpa_move = _field("scaling"), _field("p_sigma"), _field("p_c"), _field("tpa_move")
    step_size, countiter, tpa_s = _field("step_size", float), _field("countiter", int), _field("tpa_s", float)
    transform_inverse = _field("transform_inverse")

    @property
    def transform(self) -> np.ndarray | None:
        """T, once pycma's alleviate_conditioning has fired; None before (x = g)."""
        return self.state.transform if self.state.transformed[0] else None

    @transform.setter
    def transform(self, value) -> None:
        self.state = self.state._replace(transform=value, transformed=np.array([True]))

    def _state_changed(self) -> None:
        self._set_distribution()  # a full Gaussian of the genotype state (:meth:`_set_distribution`)

    # ------------------------------------------------------------ distribution
    @property
    def distribution(self) -> FullGaussian:
        return self._dist

    def _set_distribution(self) -> None:
        """x = T (mean + sigma * scaling * B D z): N(T mean, sigma^2 T S C S T^T), S = diag(scaling)
        (:func:`cmaes_distribution`)."""
        mean, cov, low, log_norm, ok = cmaes_distribution(self.state)
        if not ok:
            raise ValueError("FullGaussian: cov is not positive definite")
        self._dist = FullGaussian.from_cholesky(mean, low, checked=False, log_norm=log_norm)
        self._dist._cov = cov  # the covariance itself, as FullGaussian(mean, cov) keeps it (its checkpoint saves it)

    # ------------------------------------------------------------------ TPA
    @property
    def probe_count(self) -> int:
        """TPA's two points per generation (once the mean has moved); none with CSA."""
        return 2 if self.params.step_size_control == "tpa" else 0

    def probes(self, rng: np.random.Generator) -> np.ndarray | None:
        """With ``step_size_control="tpa"``: the two test points m +- sigma r u (u the last move of
        the mean, of unit length in sigma^2 C's metric; r the length of a fresh N(0, I) draw) to
        evaluate afresh with this generation and pass to :meth:`tell` as ``probe_fitness``. None
        with CSA, and before the mean has moved."""
        out = np.empty((2, self.dim))
        return out if cmaes_probes(rng, self.state, self._constants(self.popsize), out) else None

    def tell(self, samples, fitness, probe_fitness=None) -> None:
        """:meth:`EvolutionStrategy.tell`; with TPA, ``probe_fitness`` holds the returns of the two
        points :meth:`probes` gave for this generation (ahead, behind); without it sigma stays."""
        if probe_fitness is not None:
            probe_fitness = np.asarray(probe_fitness, dtype=np.float64).reshape(-1)
            if not self.probe_count or probe_fitness.size != self.probe_count:
                raise ValueError("probe_fitness: the 2 returns of the points probes() gave (step_size_control='tpa' only)")
            self._probe_fitness = (probe_fitness, np.asarray(fitness, dtype=np.float64).reshape(-1))
        try:
            super().tell(samples, fitness)
        finally:
            self._probe_fitness = None

    # ------------------------------------------------------------------ update
    def _parameters(self, n: int) -> tuple[_Parameters, list]:
        """Strategy parameters and the n position weights for a population of n."""
        base = self._params[self.popsize]
        if n >= base.mu:
            return base, base.resized(n)
        if n not in self._params:
            self._params[n] = _Parameters(self.dim, n, self.active)
        return self._params[n], self._params[n].weights

    def _constants(self, n: int) -> CMAESConstants:
        """:func:`cmaes_update`'s constants for a population of n (one record per n, kept)."""
        if n not in self._constants_by_n:
            p, weights = self._parameters(n)
            self._constants_by_n[n] = CMAESConstants(
                np.array(weights, dtype=np.float64), float(p.mueff), float(p.cc), float(p.c1), float(p.cmu), float(self.cs),
                float(self.damps), float(self.chi_d), self.params.step_size_control == "tpa", float(self.tpa_damp), float(self.sigma),
                *self.alleviate_limits,
            )  # fmt: skip
        return self._constants_by_n[n]

    def _update(self, samples: np.ndarray, utilities: np.ndarray) -> None:
        n = samples.shape[0]
        if n < 3:
            raise ValueError(f"CMAES.tell needs at least 3 samples, got {n}")
        probe_fitness, fitness = self._probe_fitness if self._probe_fitness is not None else (_NO_FITNESS, _NO_FITNESS)
        self._told_mean_weights = np.empty(n)
        samples = np.ascontiguousarray(samples, dtype=np.float64)
        utilities = np.ascontiguousarray(utilities, dtype=np.float64)
        if not cmaes_update(samples, utilities, fitness, probe_fitness, self.state, self._constants(n), self._told_mean_weights):
            raise FloatingPointError("CMAES: covariance matrix stays indefinite after repairs")
        self._set_distribution()

    def compiled_step(self) -> CompiledStep:
        """:func:`cmaes_update` over :class:`CMAESState`, a full Gaussian (:func:`cmaes_distribution`) with TPA's points
        (:func:`cmaes_probes`): the compiled generation loop runs it (:class:`~imix_cli.core.algorithms.base.CompiledStep`)."""
        return CompiledStep(cmaes_update, self._constants(self.popsize), full=(cmaes_distribution, cmaes_probes, self.probe_count))

    def _decompose(self) -> None:
        """C = B D^2 B^T, in place of the state (:func:`_decompose_kernel`); FloatingPointError if C stays indefinite."""
        if not _decompose_kernel(self.state):
            raise FloatingPointError("CMAES: covariance matrix stays indefinite after repairs")

    def _mean_weights(self, utilities: np.ndarray) -> np.ndarray:
        """Each member's positive recombination weight (ties sharing theirs): m' - m = sum_i w_i (x_i - m)."""
        return self._told_mean_weights

    # ------------------------------------------------------------ checkpoints
    # The base class's: the counters and :attr:`state` field by field (continuing is then bit-identical).
