"""``imix bench``: speed benchmarks, each next to its baseline measured in the same run.

The sections, their settings and what each measures: ``imix bench --help`` (:data:`imix_cli.bench.cli.HELP`).
"""

# One module per
# section (rollouts, mixing, memory (its child process: imix_cli.commands.bench_memory_child), breakdown, grid, peers), shared
# helpers in common, the command line in cli; the scripts of benchmarks/ build on these modules.
from imix_cli.bench.cli import SECTIONS, main
from imix_cli.bench.common import median_time
from imix_cli.bench.mixing import format_mixing, mixing_rows, mixing_times
from imix_cli.bench.peers import peer_rows
from imix_cli.bench.rollouts import bench_policies, rollout_rows

__all__ = ["SECTIONS", "bench_policies", "format_mixing", "main", "median_time", "mixing_rows", "mixing_times", "peer_rows", "rollout_rows"]
