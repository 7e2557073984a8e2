"""Every ES keeps its search state in one record (:class:`imix_cli.core.algorithms.base.CompiledStep`): what ``tell``
moves, what the compiled loop runs on and what the checkpoint saves.

Why a test: an ES that kept part of its state elsewhere (an optimiser object, a step-size attribute) would checkpoint
and resume without it, or run differently in the compiled loop, which moves a copy of the record and hands it back.
Here an ES built afresh and given a copy of another's record (and its generation count) must then continue *bit for
bit* as the original does, over many generations, and its checkpoint must be exactly the record's fields.
"""

from __future__ import annotations

import numpy as np
import pytest

from imix_cli.core.algorithms import _CLASSES
from imix_cli.core.algorithms.base import copy_record, flatten_record

DIM, POPSIZE = 6, 12
OPTIONS = {"cmaes": [{"step_size_control": "csa"}, {"step_size_control": "tpa"}], "ars": [{"top": 3}]}


def _cases():
    for cls in _CLASSES:
        for options in OPTIONS.get(cls.name, [{}]):
            yield pytest.param(cls, options, id=f"{cls.name} {options}" if options else cls.name)


def _generation(es, rng):
    """One generation of ``es`` on a noisy sphere (its probes told too: CMA-ES's TPA)."""
    x = es.ask(rng)
    probes = es.probes(rng)

    def f(points):
        return -np.sum((points - 1.0) ** 2, axis=1) + 0.1 * rng.standard_normal(points.shape[0])

    if probes is None:
        es.tell(x, f(x))
    else:
        es.tell(x, f(x), probe_fitness=f(probes))


@pytest.mark.parametrize("cls,options", list(_cases()))
def test_an_es_given_anothers_state_record_continues_bit_for_bit(cls, options):
    es = cls(DIM, popsize=POPSIZE, sigma=0.5, **options)
    rng = np.random.default_rng(0)
    for _ in range(40):
        _generation(es, rng)
    clone = cls(DIM, popsize=POPSIZE, sigma=0.5, **options)
    clone.set_state(copy_record(es.state))
    clone.generation = es.generation
    a, b = np.random.default_rng(1), np.random.default_rng(1)
    for _ in range(60):
        _generation(es, a)
        _generation(clone, b)
    for name, value in flatten_record(es.state).items():
        np.testing.assert_array_equal(flatten_record(clone.state)[name], value, err_msg=name, strict=True)
    np.testing.assert_array_equal(clone.distribution.mean, es.distribution.mean, strict=True)
    assert es.generation == clone.generation == 100


@pytest.mark.parametrize("cls,options", list(_cases()))
def test_the_checkpoint_is_the_state_record(cls, options):
    es = cls(DIM, popsize=POPSIZE, **options)
    state = es.state_dict()
    assert set(state) == {"generation", "nonfinite_fitness_count", *flatten_record(es.state)}
    state["generation"] = 0
    fresh = cls(DIM, popsize=POPSIZE, **options)
    fresh.load_state_dict(state)
    assert type(fresh.state) is type(es.state)


def test_the_compiled_loop_moves_a_copy_of_the_record():
    """The compiled loop drops a chunk it cannot finish (the Python path takes it): the ES's own record must be
    untouched until the chunk is done, so it moves a copy (:func:`copy_record`)."""
    cls = next(c for c in _CLASSES if c.name == "snes")
    es = cls(DIM, popsize=POPSIZE)
    copy = copy_record(es.state)
    copy.mean[:] = 7.0
    copy.mu_adam.t[0] = 5
    assert not np.any(es.state.mean == 7.0) and es.state.mu_adam.t[0] == 0
