"""Adapters that let :class:`~imix_cli.MixingES` mix for other libraries' evolution strategies.

:class:`~imix_cli.MixingES` needs of an ES what imix's own give: ``ask(rng)``, ``tell(samples,
fitness)``, ``distribution`` (the density the next generation is drawn from) and ``popsize``
(:mod:`imix_cli.core.mixing.ask_tell`). An adapter gives those for a library's ES, leaving its update alone:

* :mod:`imix_cli.core.adapters.pycma`: ``cma.CMAEvolutionStrategy``, wrapped by MixingES itself
  (``MixingES(cma.CMAEvolutionStrategy(...), "exact")``), or as :class:`~imix_cli.core.adapters.pycma.PycmaES`
  for its options;
* :mod:`imix_cli.core.adapters.evosax`: evosax 0.3's SNES, Open_ES, CMA_ES, Sep_CMA_ES, through
  :func:`~imix_cli.core.adapters.evosax.from_evosax` (``MixingES(from_evosax(algorithm, params, key), "exact")``).

Neither library is imported here: an adapter's module imports its library when used.
"""

from __future__ import annotations

__all__ = ["adapt"]


def adapt(es):
    """``es`` itself if it has the ES protocol MixingES uses; a pycma ``CMAEvolutionStrategy`` wrapped
    in :class:`~imix_cli.core.adapters.pycma.PycmaES`; TypeError (one line) for anything else."""
    if all(hasattr(es, name) for name in ("ask", "tell", "distribution", "popsize")):
        return es
    from imix_cli.core.adapters.pycma import PycmaES, is_pycma

    if is_pycma(es):
        return PycmaES(es)
    if type(es).__module__.startswith("evosax"):
        raise TypeError(
            f"an evosax {type(es).__name__} needs its params and key: MixingES(imix_cli.core.adapters.evosax.from_evosax(algorithm, params, key), ...)"
        )
    raise TypeError(f"MixingES takes an imix ES, a cma.CMAEvolutionStrategy or an adapter (imix_cli.core.adapters), got {type(es).__name__}")
