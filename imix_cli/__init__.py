"""imix: evolution strategies with importance mixing (Pourchot, Perrin & Sigaud, 2018).

Library entry points::

    from imix_cli.mixing import DiagonalGaussian, FullGaussian, mix
    from imix_cli.algorithms import OpenES, SNES, CEM, CMAES, make_es

Importing ``imix_cli`` registers imix's gymnasium environments (``imix/ContinuousCartPole-v0``,
``imix/ContinuousCartPoleHard-v0``; see :mod:`imix_cli.envs`). That import loads numpy, so the
one-BLAS-thread default of ``imix_cli.cli`` is set here first (only where the variable is
unset): imix's matrices are tiny and its seeds already use one process per core.
"""

import os as _os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

from imix_cli import envs as _envs  # noqa: E402,F401  (registers the imix/ gymnasium ids)

__version__ = "0.1.0"
