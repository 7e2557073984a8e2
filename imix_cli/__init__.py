"""imix: evolution strategies with importance mixing (Pourchot, Perrin & Sigaud, 2018).

Library entry points::

    from imix_cli.mixing import DiagonalGaussian, FullGaussian, mix
    from imix_cli.algorithms import OpenES, SNES, CEM, CMAES, make_es

Importing ``imix_cli`` loads nothing heavy (no numpy, no gymnasium): every subcommand imports
what it uses. imix's gymnasium environments (``imix/ContinuousCartPole-v0``,
``imix/ContinuousCartPoleHard-v0``) are registered by ``import imix_cli.envs`` (or
``gym.make("imix_cli.envs:imix/ContinuousCartPole-v0")``); imix's own modules that make them do so.

The one place that sets imix's one-BLAS-thread default (only where the variable is unset),
before any module of the package loads numpy, and inherited by every worker process: imix's
matrices are tiny, its seeds already run one process per core, and two BLAS threads fighting
over two cores made CMA-ES's eigendecomposition 10x slower.
"""

import os as _os
import signal as _signal
import sys as _sys

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")


def _stop_before_anything_is_written(signum, frame):
    how = "terminated" if signum == _signal.SIGTERM else "interrupted"
    print(f"imix: {how} (nothing was written); re-run the same command to start again", file=_sys.stderr, flush=True)
    _os._exit(128 + signum)


# The `imix` console script: a Ctrl-C during the imports of a run (numpy, gymnasium, Hydra) or the
# validation that follows can be swallowed by C code that clears errors (measured: with a cold
# bytecode cache, SIGINT 0.2 s after start let a whole sweep run). Nothing is written before the
# run starts, so until then a Ctrl-C ends the process at once; imix_cli.cli hands SIGINT back to
# Python's handler before anything runs. Library imports are unaffected.
if _os.path.basename(_sys.argv[0] if _sys.argv else "") == "imix":
    _signal.signal(_signal.SIGINT, _stop_before_anything_is_written)

__version__ = "0.1.0"
