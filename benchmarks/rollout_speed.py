"""Steps per second (CPU time, policy included) of `make_evaluator(env).evaluate` at batch 2, 50
and 1250, for CartPole and Acrobot, with the rollout benchmark's fixed policies.

Measures whichever imix is on the path, so the same script gives before/after figures on a
loaded machine (CPU time, not wall time: other processes' load does not count)::

    PYTHONPATH=/path/to/old/checkout python benchmarks/rollout_speed.py
    PYTHONPATH=. python benchmarks/rollout_speed.py

`imix bench rollouts` prints the same kind of figure next to gymnasium baselines.
"""

import sys
import time

import numpy as np

from imix_cli.bench import bench_policies
from imix_cli.core.evaluation import make_evaluator


def rate(ev, params, seeds, min_seconds=1.5, min_repeats=3):
    ev.evaluate(params[:1], seeds[:1])  # compiles or loads the kernels: not timed
    rates, started = [], time.process_time()
    while time.process_time() - started < min_seconds or len(rates) < min_repeats:
        t = time.process_time()
        _, steps = ev.evaluate(params, seeds)
        rates.append(steps.sum() / max(time.process_time() - t, 1e-9))
    return float(np.median(rates)), float(steps.mean())


def main(sizes=(2, 50, 1250)):
    for env in ("cartpole", "acrobot"):
        ev = make_evaluator(env)
        for b in sizes:
            r, mean_episode = rate(ev, bench_policies(env, b), np.arange(b))
            print(f"{env} B={b}: {r / 1e6:.3f}M steps/s per core (mean episode {mean_episode:.0f})", flush=True)


if __name__ == "__main__":
    main(tuple(int(a) for a in sys.argv[1:]) or (2, 50, 1250))
