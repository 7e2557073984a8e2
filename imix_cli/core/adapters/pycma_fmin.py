"""pycma's ``cma.fmin2`` -- IPOP and BIPOP restarts included -- with importance mixing in every run.

Why not a restart loop of our own: pycma's IPOP/BIPOP logic (which population next, how BIPOP splits its budget
between large and small populations, the seeds, ``es.result``, ``all_stoppings``, the logger) is what users run
and compare against; a copy would drift from it. pycma's ``fmin`` makes every run's ES by the name
``CMAEvolutionStrategy`` of its module and drives it through ``stop()``, ``ask_and_eval()`` and ``tell()``. So
:func:`fmin2` calls pycma's own ``fmin2`` with that name bound, for the duration of the call, to
:class:`MixingCMAEvolutionStrategy`: a pycma ES whose ``ask_and_eval`` evaluates only the points importance
mixing asks for, whose ``tell`` takes their values and tells pycma the whole mixed generation, and whose ``stop``
judges pycma's criteria on fresh evaluations (all through :class:`~imix_cli.core.mixing.ask_tell.MixingES` and
:class:`~imix_cli.core.adapters.pycma.PycmaES`). Every other line of the restart loop is pycma's::

    import cma, imix_cli
    x, es = imix_cli.fmin2(cma.ff.rastrigin, 10 * [3.0], 2.0, {"verbose": -9, "seed": 1}, restarts=5, bipop=True)
    es.result.evaluations        # evaluations made, all runs (pycma's countevals: fresh ones only)

Assumptions (each checked where named): BIPOP's budget split reads ``es.countevals``, which the adapter keeps to
the evaluations made (tests/test_adapters_pycma.py, ``test_fmin2_...``); pycma's noise handler re-evaluates
members and changes sigma outside ``tell`` -- it is refused (one line), as are ``gradf`` and options under which
pycma's samples are not an independent Gaussian sample (:data:`~imix_cli.core.adapters.pycma.REFUSED_OPTIONS`,
e.g. ``CMA_mirrors``, which pycma sets by default for popsize < 6: :func:`fmin2` sets ``CMA_mirrors=0`` unless
given). While :func:`fmin2` runs, ``cma.evolution_strategy.CMAEvolutionStrategy`` is the subclass: do not run two
:func:`fmin2` calls in threads of one process at once.
"""

from __future__ import annotations

import contextlib
import functools
import threading

import numpy as np

__all__ = ["fmin2"]  # and MixingCMAEvolutionStrategy, made on first use (module __getattr__)

_LOCK = threading.Lock()


@functools.cache
def _subclass():
    """The pycma subclass, made once, on first use (cma is imported only here)."""
    import cma

    base = cma.CMAEvolutionStrategy

    class MixingCMAEvolutionStrategy(base):
        """A pycma ES that mixes: ``ask_and_eval``, ``tell`` and ``stop`` through :class:`~imix_cli.core.mixing.ask_tell.MixingES`."""

        _mixing_options: dict = {}  # MixingES's keywords (fmin2's mixing=); those left out: its defaults

        def _mixing(self):
            m = self.__dict__.get("_mixing_es")
            if m is None:
                from imix_cli.core.adapters.pycma import PycmaES
                from imix_cli.core.mixing.ask_tell import MixingES

                options = dict(self._mixing_options)
                step_size = options.pop("step_size", "pycma")
                seed = self.opts["seed"]  # pycma's seed of this run (fmin adds 1 per restart): the mixing stream's too
                rng = int(seed) if isinstance(seed, (int, np.integer)) and seed > 0 else None
                m = self._mixing_es = MixingES(PycmaES(self, step_size=step_size), rng=rng, **options)
            return m

        def ask_and_eval(self, func, args=(), gradf=None, number=None, xmean=None, sigma_fac=1, evaluations=1,
                         aggregation=np.median, kappa=1, parallel_mode=False):  # fmt: skip
            """The points mixing asks for, and their values (pycma's signature; only ``func``, ``args`` and
            ``parallel_mode`` apply)."""
            if gradf is not None or number is not None or xmean is not None or sigma_fac != 1 or evaluations != 1 or kappa != 1:
                raise ValueError("imix_cli.fmin2: gradf, number, xmean, sigma_fac, evaluations and kappa are not supported with mixing")
            x = self._mixing().ask()
            points = list(x)
            values = list(func(points, *args)) if parallel_mode else [func(p, *args) for p in points]
            return points, values

        def tell(self, solutions, function_values, check_points=None, copy=False):
            """The values of the points :meth:`ask_and_eval` returned; pycma is told the whole mixed generation."""
            self._mixing().tell(np.asarray(solutions, dtype=np.float64), np.asarray(function_values, dtype=np.float64))

        def stop(self, check=True, ignore_list=(), check_in_same_iteration=False, get_value=None):
            """pycma's criteria, those that read f-values on fresh evaluations (:class:`~imix_cli.core.adapters.pycma.FreshRecord`)."""
            if not check or get_value or check_in_same_iteration or ignore_list or self.countiter == 0:
                return base.stop(self, check, ignore_list, check_in_same_iteration, get_value)
            return self._mixing().stop()

    return MixingCMAEvolutionStrategy


def __getattr__(name):
    if name == "MixingCMAEvolutionStrategy":
        return _subclass()
    raise AttributeError(name)


@contextlib.contextmanager
def _pycma_makes(cls):
    import cma.evolution_strategy as module

    with _LOCK:
        own = module.CMAEvolutionStrategy
        module.CMAEvolutionStrategy = cls
        try:
            yield
        finally:
            module.CMAEvolutionStrategy = own


def fmin2(objective_function, x0, sigma0, options=None, *, mixing=None, **kwargs):
    """``cma.fmin2(objective_function, x0, sigma0, options, **kwargs)`` with importance mixing in every run.

    Parameters
    ----------
    objective_function, x0, sigma0, options, **kwargs
        pycma's (``restarts=``, ``bipop=``, ``incpopsize=``, ``parallel_objective=``, ``callback=``, ...); x0 may
        be a callable, as in pycma. Refused with one line (ValueError): ``noise_handler``, ``gradf``, an ES as x0.
    mixing : dict or None
        :class:`~imix_cli.core.mixing.ask_tell.MixingES`'s keywords for every run (``variant``, ``eim_generations``,
        ``min_fresh``, ...) and the adapter's ``step_size``; each left out takes MixingES's default
        (:data:`imix_cli.core.mixing.MIXING_DEFAULTS`: ``"exact"``, as ``imix run eim=true``).

    Returns
    -------
    pycma's ``(xbest, es)``: ``es`` the last run's ES (``es.result``, ``es.stop()``, ``es.all_stoppings``, ...).
    """
    import cma

    for key in ("noise_handler", "gradf"):
        if kwargs.get(key) is not None:
            raise ValueError(f"imix_cli.fmin2: {key}= is not supported with mixing ({key} evaluates or moves outside tell)")
    if isinstance(x0, cma.CMAEvolutionStrategy):
        raise ValueError("imix_cli.fmin2: x0 must be a point or a callable, not an ES (wrap an ES in imix_cli.MixingES instead)")
    options = dict(options or {})
    options.setdefault("CMA_mirrors", 0)  # pycma mirrors by default below popsize 6: not independent samples
    base = _subclass()
    cls = type("MixingCMAEvolutionStrategy", (base,), {"_mixing_options": dict(mixing or {})})
    with _pycma_makes(cls):
        return cma.fmin2(objective_function, x0, sigma0, options, **kwargs)
