"""What the seed workers' fork server runs before it forks them (:data:`imix_cli.running.pool.SEED_WORKER_MODULES`):
numba's CPU target set up, by loading one small cached kernel; and the server's own end without the interpreter's
teardown.

Why the kernel: the first compiled kernel a process loads sets up numba's compiler target (its typing and lowering
registries), ~0.25 s, whichever kernel it is. A spawned worker paid it before its first generation, on each core; the
fork server pays it once, while the main process validates the run, and the workers forked from it have it. (Loading
the run's own kernels there too was tried: the server then finished after the validation, and the workers waited for it.)

Why the end: the server ends when the main process does (its pipe from there closes), and then tore down numba,
gymnasium and the rest, ~0.2 s, holding the ``imix run`` process's stdout and stderr open all the while -- which it
shares, to pass them on to the workers. A caller that reads them to their end (``subprocess.run(capture_output=True)``,
``imix bench peers``'s whole-process row, a pipe into ``tee``) waited those 0.2 s after the run had ended. The
workers forked from the server never run its exit hooks (multiprocessing ends them with ``os._exit``).
"""

import atexit

from imix_cli.core import numerics as xp
from imix_cli.core.processes import exit_without_teardown

xp.log(0.5)  # a cached kernel's load sets up the target; its value is not used
atexit.register(exit_without_teardown, 0)  # the server's end: SystemExit once the main process has gone
