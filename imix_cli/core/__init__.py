"""The numerical library: distributions, mixing and its compiled kernels, the evolution strategies, the
environments and policies, their evaluation, the elementary functions, statistics. No files, no Hydra: it
imports nothing of :mod:`imix_cli.running`, :mod:`imix_cli.commands` or :mod:`imix_cli.plotting`
(tests/test_layering.py).
"""
