"""The range of every numeric hyper-parameter, written once: the library's constructors and ``imix run`` check the same numbers.

Why one record: the bounds used to be written twice -- ``imix run``'s config checks refused ``eim_generations=0`` or
``sigma=1e300`` while ``MixingES`` and ``make_es`` accepted them and failed later, deep inside, or truncated
``popsize=2.5`` to 2. Now :class:`~imix_cli.core.algorithms.base.Params` (:data:`~imix_cli.core.algorithms.base.PARAM_BOUNDS`)
and :class:`~imix_cli.core.mixing.generation.MixingSettings` (:data:`~imix_cli.core.mixing.generation.MIXING_BOUNDS`) check their fields with a
:class:`Bound` at construction, and ``imix run``'s key declarations (:data:`imix_cli.running.config.keys.KEYS`) check
the config keys with the very same ones (:func:`imix_cli.running.config.checks.as_bounded`).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass


@dataclass(frozen=True)
class Bound:
    """A numeric range: ``low`` (inclusive or not) to ``high`` (inclusive or not), integers only if ``integer``."""

    low: float
    low_inclusive: bool = True
    high: float = math.inf
    high_inclusive: bool = False
    integer: bool = False

    def rule(self) -> str:
        """The range in words: ``">= 2"``, ``"> 0 and < 1e+154"``, ``">= 0.0 and < 1.0"``."""
        low = f"{'>=' if self.low_inclusive else '>'} {self.low}"
        return low if self.high == math.inf else f"{low} and {'<=' if self.high_inclusive else '<'} {self.high:g}"

    def contains(self, value: float) -> bool:
        above = value >= self.low if self.low_inclusive else value > self.low
        below = value <= self.high if self.high_inclusive else value < self.high
        return bool(above and below)

    def check(self, name: str, value):
        """``value`` if it is in range; TypeError for a value of the wrong kind (``2.5`` for an integer, a string, a bool),
        ValueError out of range or not finite -- each naming ``name`` and the range."""
        kind = "an integer" if self.integer else "a number"
        wrong_type = isinstance(value, bool) or not isinstance(value, numbers.Integral if self.integer else numbers.Real)
        if wrong_type:
            raise TypeError(f"{name} must be {kind} {self.rule()}, got {value!r}")
        if not math.isfinite(value) or not self.contains(value):
            raise ValueError(f"{name} must be {self.rule()}, got {value!r}")
        return value
