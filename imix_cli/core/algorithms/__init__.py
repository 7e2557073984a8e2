"""The four evolution strategies of the paper (section 2.1), one module each.

=========  ======================  =========================================
name       class                   search distribution
=========  ======================  =========================================
openes     :class:`OpenES`         N(mu, sigma^2 I), sigma fixed
snes       :class:`SNES`           N(mu, diag(sigma^2)), sigma adapted
cem        :class:`CEM`            N(mu, diag(sigma^2)), refitted to elites
cmaes      :class:`CMAES`          N(mu, sigma^2 C), full C (pycma)
ars        :class:`ARS`            N(mu, nu^2 I) in mirrored pairs (Mania et al. 2018)
=========  ======================  =========================================

``make_es("snes", dim=130, popsize=50)`` builds one by name, its class's ``name`` (the same names as
:data:`imix_cli.core.registry.ALGORITHM_SPECS`, where a new ES is registered too: tests/test_registry.py). This
package does not import the registry: the registry's loaders import the ES modules, and importing one runs this
``__init__`` first, so the two would import each other (tests/test_layering.py). Each class takes
its parameter record, ``SNES(130, SNES.Params(popsize=50))``, or the record's fields as
keywords (:class:`~imix_cli.core.algorithms.base.Params`).
"""

from __future__ import annotations

from imix_cli.core.algorithms.ars import ARS
from imix_cli.core.algorithms.base import EvolutionStrategy, Params
from imix_cli.core.algorithms.cem import CEM
from imix_cli.core.algorithms.cmaes import CMAES
from imix_cli.core.algorithms.openes import OpenES
from imix_cli.core.algorithms.snes import SNES

#: Every evolution strategy of the package, in the registry's order.
_CLASSES = (OpenES, SNES, CEM, CMAES, ARS)
#: ES name -> class, for every evolution strategy whose ``tell`` takes any population
#: (any rows, in any order); ARS's members come in mirrored pairs (:data:`MIRRORED_ALGORITHMS`).
ALGORITHMS = {cls.name: cls for cls in _CLASSES if cls.generation_scheme is None}
#: ES name -> class, for the ES whose ``tell`` takes N mirrored pairs ``[plus; minus]`` (imix_cli.core.mixing.mirrored).
MIRRORED_ALGORITHMS = {cls.name: cls for cls in _CLASSES if cls.generation_scheme is not None}


def make_es(name: str, dim: int, **kwargs) -> EvolutionStrategy:
    """Build the evolution strategy called ``name`` (a key of :data:`ALGORITHMS`) in dimension ``dim``.

    ``kwargs``: ``mean`` and the fields of the class's ``Params`` (popsize, sigma, lr, ...).
    """
    try:
        cls = {**ALGORITHMS, **MIRRORED_ALGORITHMS}[name]
    except KeyError:
        raise ValueError(f"unknown algorithm {name!r}; valid names: {', '.join(sorted([*ALGORITHMS, *MIRRORED_ALGORITHMS]))}") from None
    return cls(dim, **kwargs)


__all__ = ["EvolutionStrategy", "Params", "OpenES", "SNES", "CEM", "CMAES", "ARS", "ALGORITHMS", "MIRRORED_ALGORITHMS", "make_es"]
