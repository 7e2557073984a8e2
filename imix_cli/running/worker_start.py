"""What the seed workers' fork server runs before it forks them (:data:`imix_cli.running.pool.SEED_WORKER_MODULES`):
numba's CPU target set up, by loading one small cached kernel.

Why: the first compiled kernel a process loads sets up numba's compiler target (its typing and lowering registries),
~0.25 s, whichever kernel it is. A spawned worker paid it before its first generation, on each core; the fork server
pays it once, while the main process validates the run, and the workers forked from it have it. (Loading the run's
own kernels there too was tried: the server then finished after the validation, and the workers waited for it.)
"""

from imix_cli.core import numerics as xp

xp.log(0.5)  # a cached kernel's load sets up the target; its value is not used
