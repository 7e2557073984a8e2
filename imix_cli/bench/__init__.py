"""``imix bench``: speed benchmarks, each next to its baseline measured in the same run.

Sections (give any of them; default ``rollouts mixing memory``; ``all`` runs every one)::

    rollouts   env-steps/s of imix's evaluator (imix_cli.evaluation.make_evaluator: compiled
               episodes, policy included) for CartPole and Acrobot at several batch sizes (2: what
               importance mixing leaves fresh per seed; 50: one population), next to a naive loop
               (gymnasium.make + numpy MLP per step, one episode at a time) and gymnasium's
               SyncVectorEnv stepping the same batched numpy policy; ratios of the three.
    mixing     one importance-mixing step (paper, exact, sun2009) against plain sampling of the
               same population (N = 50, K = 3), d = 130 (the paper's CartPole) to 10^6.
    memory     wall time, CPU time and peak RSS (VmHWM) of `imix run algo=snes env=cartpole
               eim=true seeds=25` in a subprocess: its main process and its worker processes.
    breakdown  where a run's time goes: evaluation, mixing (or plain sampling) and ES update
               of a lockstep run in this process (seeds of one worker, paper dimensions).
    loop       the compiled generation loop (imix_cli.running.compiled_loop) against the Python loop it
               reproduces: the same seeds of SNES + EIM, OpenES + EIM and SNES without mixing on
               CartPole, in this process; time per seed-generation, ratio, and whether the rows
               are the same (13 seeds x 300 generations unless seeds=/generations=).
    grid       wall time and total env steps of the paper's main grid (4 ES x CartPole,
               Acrobot x 25 seeds at the paper's generation counts), with EIM and without
               mixing, through imix_cli.running.runner.run into a temporary folder. Takes minutes.
    peers      the same task in a peer library, in this run: evosax SNES and OpenES + gymnax
               CartPole-v1 / Acrobot-v1 (both capped at 200 steps), the same 8-8 tanh MLP, pop 50,
               no mixing, the whole loop jitted with the seeds vmapped (JAX on CPU); next to
               `imix run algo=snes env=<env> eim=true` and `eim=false` (in this process, all
               cores, a temporary results folder), and on the first env `imix run ... eim=true`
               as a user's first run (a new process with an empty numba cache: every kernel is
               compiled). Wall times (compile included: JAX's shown, and imix's first run's
               extra over the warm run), env steps, final scores and ratios. Default 25 seeds x
               1000 generations (minutes); quick=true: 3 x 100. Needs the `peers` extra (pip
               install 'imix-cli[peers]'); without it the section says so and exits 0.
    mujoco     imix's cost per env step on HalfCheetah-v5 and Hopper-v5 (linear policy, no mixing,
               pool evaluator with one worker: the evaluator on fixed policies, and a short
               `imix run`) against a plain gymnasium loop over the same policies and seeds, and
               the share of that loop spent in MuJoCo's mj_step (the floor of any path that
               reproduces gymnasium's episodes). Pairwise ratios. Needs the `mujoco` extra.

Policies of the rollout benchmark (fixed, so episodes have realistic lengths): CartPole, a
hand-built balancing controller written as an MLP (action = sign of 2 theta + 0.5 theta_dot
+ 0.3 x_dot + 0.1 x through one tanh unit per layer) plus N(0, 0.1^2) noise on every parameter
(numpy seed 0): a late-training population, mean episode ~190 steps. Acrobot, random
N(0, 0.5^2) parameters (seed 0): an early-training population, mean episode ~195 steps of
the 200-step cap. Episode seeds 0..B-1.

Timings are medians of repeats; the machine may be shared, so compare the ratios (measured
in the same run) rather than absolute numbers across runs. Exit status 2 on bad arguments.
"""

# The docstring above is the body of `imix bench --help` (imix_cli.bench.cli.help_text). One module per
# section (rollouts, mixing, memory and its child process memory_child, breakdown, grid, peers), shared
# helpers in common, the command line in cli; the scripts of benchmarks/ build on these modules.
from imix_cli.bench.cli import SECTIONS, main
from imix_cli.bench.common import median_time
from imix_cli.bench.mixing import format_mixing, mixing_rows, mixing_times
from imix_cli.bench.peers import peer_rows
from imix_cli.bench.rollouts import bench_policies, rollout_rows

__all__ = ["SECTIONS", "bench_policies", "format_mixing", "main", "median_time", "mixing_rows", "mixing_times", "peer_rows", "rollout_rows"]
