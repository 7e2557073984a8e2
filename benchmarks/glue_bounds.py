"""What bounds imix's CartPole main job against a fused, jitted peer: the measurements behind
the README's "three ways to cut that glue" and "bound by libm calls" paragraphs.

1. ``update``: a SNES update batched over a worker's 13 lockstep seeds with numpy (exact: the
   stacked ``matmul`` gives each seed's ``u @ s`` bit for bit) against 13 per-seed updates. The
   batched figure depends on the process: its (13, 50, 130) temporaries are above glibc's mmap
   threshold, and whether ``free`` returns them to the kernel (so that every call page-faults
   them in again) depends on what the process allocated before; ``MALLOC_MMAP_THRESHOLD_=16777216``
   removes that (11 against 50-80 us per seed on the 2-core AMD EPYC VM).
2. ``mixing``: the fixed cost of one compiled mixing step (calling the kernel, and ``mix``'s own
   Python), measured on a step with almost no work (d = 1, N = 2, K = 1), against a paper-sized
   one (d = 130, N = 50, K = 3): what one call for all seeds could save at most.
3. ``tanh``: the compiled CartPole episode kernel as it is, and a copy whose hidden units are the
   identity instead of libm's ``tanh`` (a measurement, not a policy): ns per env step.

    python benchmarks/glue_bounds.py [update] [mixing] [tanh]
"""

from __future__ import annotations

import copy
import importlib.util
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _per_call(fn, calls: int) -> float:
    fn()
    started = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - started) / calls


def bench_update(seeds: int = 13, dim: int = 130, popsize: int = 50) -> None:
    from imix_cli.core.algorithms import make_es

    rng = np.random.default_rng(0)
    ess = [make_es("snes", dim, popsize=popsize, sigma=0.1, lr=0.01) for _ in range(seeds)]
    xs = [es.ask(rng) for es in ess]
    us = [es.utilities(x, np.round(rng.normal(size=popsize))) for es, x in zip(ess, xs)]
    frozen = copy.deepcopy(ess)  # batched gradients at the same state every call

    def per_seed():
        for es, x, u in zip(ess, xs, us):
            es._update(x, u)

    def batched():
        mu = np.stack([es._mu for es in frozen])
        sigma = np.stack([es._dist.std for es in frozen])
        s = (np.stack(xs) - mu[:, None, :]) / sigma[:, None, :]
        u = np.stack(us)[:, None, :]
        return sigma * np.matmul(u, s)[:, 0], np.matmul(u, s * s - 1.0)[:, 0] / 2.0

    es = frozen[0]
    s = (xs[0] - es._mu) / es._dist.std
    grad_mu, grad_log_sigma = batched()
    exact = np.array_equal(es._dist.std * (us[0] @ s), grad_mu[0]) and np.array_equal(us[0] @ (s * s - 1.0) / 2.0, grad_log_sigma[0])
    print(f"## SNES update, {seeds} seeds, d = {dim}, N = {popsize}")
    print(f"batched gradients equal a seed's own, bit for bit: {exact}")
    print(f"per-seed SNES._update (the whole update): {_per_call(per_seed, 500) / seeds * 1e6:.1f} us per seed")
    print(f"batched gradients only:                   {_per_call(batched, 500) / seeds * 1e6:.1f} us per seed")
    stacked, single = np.stack(xs), np.stack(us)[:, None, :]
    print(f"  of which the stacked matmul:            {_per_call(lambda: np.matmul(single, stacked), 2000) / seeds * 1e6:.1f} us per seed")


def bench_mixing() -> None:
    from imix_cli.core.distributions import DiagonalGaussian
    from imix_cli.core.mixing import Generation, mix
    from imix_cli.core.mixing import kernels as mixing_kernels

    rng = np.random.default_rng(0)

    def archive(dist, n, k):
        return [Generation(dist.sample(n, rng), np.zeros(n, np.int64), np.full(n, -1, np.int64), dist) for _ in range(k)]

    z, o = np.zeros(1), np.ones(1)
    raw = (rng, (z, o, 0.0), (np.zeros((1, 1)), np.ones((1, 1)), np.zeros(1), np.zeros((1, 2, 1)), np.full((1, 2), -50.0), np.array([2])), 2, 0.0, 0.0, 0)
    tiny = DiagonalGaussian(z, o)
    tiny_archive = archive(tiny, 2, 1)
    big, big_new = DiagonalGaussian(np.zeros(130), np.ones(130)), DiagonalGaussian(np.full(130, 0.01), np.ones(130))
    big_archive = archive(big, 50, 3)
    print("## One compiled exact step")
    print(f"the kernel's call alone (d = 1, N = 2, K = 1): {_per_call(lambda: mixing_kernels._mix_exact(*raw), 20000) * 1e6:.1f} us")
    print(f"mix() on that step:                            {_per_call(lambda: mix(tiny, tiny_archive, 2, rng, variant='exact'), 20000) * 1e6:.1f} us")
    print(f"mix() at d = 130, N = 50, K = 3:               {_per_call(lambda: mix(big_new, big_archive, 50, rng, variant='exact'), 3000) * 1e6:.1f} us")


def _kernels_copy(identity_hidden: bool):
    """A fresh, uncached copy of imix_cli/core/envs/kernels.py (hidden units tanh or identity)."""
    import imix_cli.core.envs.kernels as kernels

    source = Path(kernels.__file__).read_text().replace("cache=True", "cache=False")
    if identity_hidden:
        line = "y[j] = math.tanh(acc) if layer < last else acc"
        assert line in source, "mlp_forward changed: update this benchmark"
        source = source.replace(line, "y[j] = acc")
    path = Path(tempfile.mkdtemp(prefix="imix-glue-")) / ("kernels_identity.py" if identity_hidden else "kernels_tanh.py")
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def bench_tanh(batch: int = 50) -> None:
    from imix_cli.bench.rollouts import bench_policies

    params = bench_policies("cartpole", batch)
    sizes = np.array([4, 8, 8, 2], dtype=np.int64)
    seeds = np.arange(batch, dtype=np.uint64)
    print(f"## CartPole episodes, compiled, batch {batch} (the rollout benchmark's policies)")
    for name, identity in (("libm tanh (as imix runs)", False), ("identity hidden units", True)):
        episodes = _kernels_copy(identity).cartpole_episodes
        returns, steps = np.empty(batch), np.empty(batch, dtype=np.int64)
        args = (params, seeds, sizes, False, False, 200, returns, steps, np.empty((0, 201, 4)))
        per_call = min(_per_call(lambda f=episodes, a=args: f(*a), 20) for _ in range(5))
        print(f"{name}: {per_call / steps.sum() * 1e9:.0f} ns per env step ({steps.sum()} steps per call)")


if __name__ == "__main__":
    chosen = sys.argv[1:] or ["update", "mixing", "tanh"]
    for section in chosen:
        {"update": bench_update, "mixing": bench_mixing, "tanh": bench_tanh}[section]()
        print()
