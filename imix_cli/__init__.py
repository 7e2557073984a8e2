"""imix: evolution strategies with importance mixing (Pourchot, Perrin & Sigaud, 2018).

The public API (:data:`__all__`), loaded on first use::

    import imix_cli
    es = imix_cli.MixingES(imix_cli.make_es("cem", dim=10, popsize=20), "exact", rng=0)  # ask/tell with mixing
    df = imix_cli.run(algo="snes", env="cartpole", eim=True, seeds=3, generations=50)    # imix run -> DataFrame

Importing ``imix_cli`` loads nothing heavy (no numpy, no gymnasium) and changes nothing in the
importing process: each name of :data:`__all__` imports its module when first read, and every
subcommand imports what it uses. imix's gymnasium environments (``imix/ContinuousCartPole-v0``,
``imix/ContinuousCartPoleHard-v0``) are registered by ``import imix_cli.core.envs`` (or
``gym.make("imix_cli.core.envs:imix/ContinuousCartPole-v0")``); imix's own modules that make them do so.

One BLAS thread per process is imix's default only in its own processes -- the ``imix`` command
and the worker processes it spawns (:func:`imix_cli.core.processes.one_blas_thread`) -- never in a
user's Python that imports the library.
"""

import os as _os
import signal as _signal
import sys as _sys


def _stop_before_anything_is_written(signum, frame):
    how = "terminated" if signum == _signal.SIGTERM else "interrupted"
    print(f"imix: {how} (nothing was written); re-run the same command to start again", file=_sys.stderr, flush=True)
    _os._exit(128 + signum)


# The `imix` console script: a Ctrl-C (or SIGTERM) during the imports of a run (numpy, gymnasium, Hydra) or the
# validation that follows can be swallowed by C code that clears errors (measured: with a cold
# bytecode cache, SIGINT 0.2 s after start let a whole sweep run). Nothing is written before the
# run starts, so until then a Ctrl-C ends the process at once; imix_cli.commands.cli hands SIGINT back to
# Python's handler before anything runs. The same process gets imix's one-BLAS-thread default here,
# before any module loads numpy (imix_cli.core.processes says why). Library imports are unaffected.
if _os.path.basename(_sys.argv[0] if _sys.argv else "") == "imix":
    _signal.signal(_signal.SIGINT, _stop_before_anything_is_written)
    # SIGTERM too: `imix run`'s handlers are set only once its imports (numba: seconds on a loaded
    # machine) are done, and a SIGTERM before that ended the process without a word (exit -15).
    _signal.signal(_signal.SIGTERM, _stop_before_anything_is_written)
    from imix_cli.core.processes import set_one_blas_thread as _set_one_blas_thread

    _set_one_blas_thread()

__version__ = "0.1.0"

#: name -> module of the public API; ``imix_cli.<name>`` imports the module when first read.
_API = {
    "MixingES": "imix_cli.core.mixing.ask_tell",
    "fmin2": "imix_cli.core.adapters.pycma_fmin",
    "run": "imix_cli.experiment",
    "Experiment": "imix_cli.experiment",
    "make_es": "imix_cli.core.algorithms",
    "OpenES": "imix_cli.core.algorithms",
    "SNES": "imix_cli.core.algorithms",
    "CEM": "imix_cli.core.algorithms",
    "CMAES": "imix_cli.core.algorithms",
    "mix": "imix_cli.core.mixing",
    "Generation": "imix_cli.core.mixing",
    "DiagonalGaussian": "imix_cli.core.mixing",
    "FullGaussian": "imix_cli.core.mixing",
    "make_evaluator": "imix_cli.core.evaluation",
    "policy_action": "imix_cli.core.evaluation.policies",
    "policy_output": "imix_cli.core.evaluation.policies",
    "ConfigError": "imix_cli.running.config.checks",
    "RunError": "imix_cli.messages",
}

__all__ = [*_API, "__version__"]


def __getattr__(name: str):
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'imix_cli' has no attribute {name!r}")
    from importlib import import_module

    value = getattr(import_module(module), name)
    globals()[name] = value  # later reads skip this function
    return value


def __dir__():
    return sorted([*globals(), *_API])
