"""The policy forward of a MuJoCo batch: numpy (imix's BatchPolicy) against a numba loop, per call and per member.

    python benchmarks/mujoco_policy_forward.py [--sizes 1 12 50]

Why: the direct MuJoCo path (docs/mujoco-episodes.md) computes each env step's actions for the
whole batch with :class:`imix_cli.core.evaluation.policies.BatchPolicy` (one einsum per layer, numpy's tanh).
A numba loop calls less numpy per step; this measures what that would save per member-step
(HalfCheetah's linear policy: 17 observations, 6 actions, bounds [-1, 1]) and whether its
actions are the same bits. They are not: numba's tanh is libm's, numpy's is its own SIMD one,
an ulp apart on some inputs (imix_cli/core/envs/kernels.py says the same), and one ulp in an action
makes the episode differ from gymnasium's. Compare the per-member cost with a MuJoCo step
(`imix bench mujoco`: tens of microseconds).
"""

from __future__ import annotations

import argparse
import functools
import math
import timeit

import numba
import numpy as np

from imix_cli.core.evaluation.policies import BatchPolicy

OBS, ACT = 17, 6


@numba.njit(cache=True)
def linear_tanh(W, b, obs, out):
    """out[m] = tanh(obs[m] @ W[m] + b[m]), summed in the order of BatchPolicy's einsum."""
    n, d = obs.shape
    k = b.shape[1]
    for m in range(n):
        for j in range(k):
            acc = 0.0
            for i in range(d):
                acc += W[m, i, j] * obs[m, i]
            out[m, j] = math.tanh(acc + b[m, j])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 12, 50])
    args = parser.parse_args()
    print("| batch | numpy BatchPolicy (µs/call) | per member | numba loop (µs/call) | per member | same bits |")
    print("|---:|---:|---:|---:|---:|---|")
    for n in args.sizes:
        rng = np.random.default_rng(0)
        params, obs = rng.normal(size=(n, OBS * ACT + ACT)), rng.normal(size=(n, OBS))
        policy = BatchPolicy(params, OBS, ACT, discrete=False, hidden=(), low=-1.0, high=1.0)
        W, b, out = np.ascontiguousarray(params[:, : OBS * ACT].reshape(n, OBS, ACT)), np.ascontiguousarray(params[:, OBS * ACT :]), np.empty((n, ACT))
        linear_tanh(W, b, obs, out)  # compiles
        numpy_call = min(timeit.repeat(functools.partial(policy, obs), number=2000, repeat=5)) / 2000
        numba_call = min(timeit.repeat(functools.partial(linear_tanh, W, b, obs, out), number=2000, repeat=5)) / 2000
        same = np.array_equal(policy(obs), out)
        print(f"| {n} | {numpy_call * 1e6:.1f} | {numpy_call / n * 1e6:.2f} | {numba_call * 1e6:.1f} | {numba_call / n * 1e6:.2f} | {same} |")


if __name__ == "__main__":
    main()
