"""Numerical divergence of a search: a result to record, not a crash.

Legal settings can make a search diverge: ``lr=100`` with SNES drives log sigma to overflow
within a few generations, and then the ES cannot even build its next distribution (the
distributions refuse non-finite parameters). Whether a setting diverges depends on the run,
so it cannot be refused up front; instead the seed ends at the generation where its search
distribution stopped being finite, and that is recorded (the CSV's ``diverged`` column, the
run's summary).

:class:`GuardedES` wraps an ES so that a ``tell`` which leaves (or would leave: the
distributions refuse non-finite parameters, so the update raises) non-finite distribution
parameters marks the ES as diverged instead of raising; the distribution stays
the last finite one, so the generation just told keeps its valid row. An exception that does
not come before the update (samples or fitness of the wrong shape) is a bug, and is raised as usual. Floating-point warnings
(overflow, invalid) are silenced inside ``tell``: with ``weight_decay=1e308`` every penalty
overflows each generation, which is the documented ranking of non-finite fitness, not news.
"""

from __future__ import annotations

import numpy as np

#: Exceptions an ES update may raise when its numbers overflow (the distributions' ValueError,
#: Python's OverflowError on float ** 2, numpy's LinAlgError on a non-finite covariance).
_NUMERICAL_ERRORS = (ValueError, OverflowError, FloatingPointError, ZeroDivisionError, np.linalg.LinAlgError, AssertionError)


class GuardedES:
    """An ES whose ``tell`` records divergence in :attr:`diverged` (a reason, or None) instead of raising.

    Every other attribute is read from the wrapped ES (attributes set on the wrapper stay on it,
    e.g. a benchmark's timing wrapper around ``tell``); once diverged, ``tell`` does nothing.
    """

    def __init__(self, es):
        self.__dict__["es"] = es
        self.__dict__["diverged"] = None

    def tell(self, samples, fitness, **probes) -> None:
        """``probes``: CMA-ES's ``probe_fitness`` (two-point step-size adaptation), passed on."""
        if self.diverged is not None:
            return
        samples, fitness = np.asarray(samples), np.asarray(fitness)
        if samples.ndim != 2 or samples.shape[1] != self.es.dim or samples.shape[0] != fitness.reshape(-1).shape[0]:
            self.es.tell(samples, fitness, **probes)  # the ES's own one-line ValueError: a caller's bug, not divergence
        with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
            try:
                self.es.tell(samples, fitness, **probes)
            except _NUMERICAL_ERRORS as err:
                # The inputs were well-formed, so the update itself overflowed.
                reason = nonfinite_parameters(self.es) or "overflow in the update"
                text = str(err).strip().splitlines()[0] if str(err).strip() else ""
                self.__dict__["diverged"] = f"{reason}: {type(err).__name__}{': ' + text if text else ''}"
                return
        # A tell that went through but left an infinite mean (a distribution accepts huge
        # finite numbers, whose next samples overflow) also ends the search.
        reason = nonfinite_parameters(self.es, distribution_only=True)
        if reason is not None:
            self.__dict__["diverged"] = reason

    def state_dict(self) -> dict:
        return {**self.es.state_dict(), "diverged": self.diverged}

    def load_state_dict(self, state: dict) -> None:
        state = dict(state)
        self.__dict__["diverged"] = state.pop("diverged", None)
        self.es.load_state_dict(state)

    def __getattr__(self, name):
        if "es" not in self.__dict__:  # during unpickling or copying, before __init__'s fields exist
            raise AttributeError(name)
        return getattr(self.__dict__["es"], name)


def nonfinite_parameters(es, distribution_only: bool = False) -> str | None:
    """Which parameters of ``es`` are non-finite ("mean", "std", or a state-dict entry), or None."""
    dist = es.distribution
    for name in ("mean", "std"):
        if not np.all(np.isfinite(getattr(dist, name))):
            return f"non-finite distribution {name}"
    if distribution_only:
        return None
    try:
        state = es.state_dict()
    except NotImplementedError:
        return None
    for name, value in state.items():
        if isinstance(value, np.ndarray) and value.dtype.kind == "f" and not np.all(np.isfinite(value)):
            return f"non-finite {name}"
        if isinstance(value, float) and not np.isfinite(value):
            return f"non-finite {name}"
    return None
