"""The numerical library: distributions, mixing and its compiled kernels, the evolution strategies, the
environments and policies, their evaluation, the elementary functions, statistics. No files, no Hydra: it
imports nothing of :mod:`imix_cli.running`, :mod:`imix_cli.commands` or :mod:`imix_cli.plotting`
(tests/test_layering.py).

A folder per concern: ``numerics/`` (the same bits on every CPU), ``mixing/`` (importance mixing, one generation,
``MixingES``), ``evaluation/`` (episodes of policies, here or on many cores), ``envs/``, ``algorithms/`` (one file per
ES), ``adapters/`` (pycma, evosax), ``ddpg/``; at the top the modules every folder reads (``registry``,
``distributions``, ``bounds``, ``divergence``, ``processes``, ``stats``).
"""
