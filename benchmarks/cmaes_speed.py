"""Time one CMA-ES update (``tell``) per generation: imix's numpy CMAES vs the pycma wrapper it replaced.

Both run in the same process, interleaved generation by generation on the same samples
(a sphere, lambda = 50 by default), so the ratio is meaningful on a loaded machine. The
baseline is what the former wrapper (imix_cli/core/algorithms/cmaes.py before the rewrite) did
per generation: pycma's ``tell(check_points=False)`` after its ask bookkeeping, the
pre-sampling steps of pycma's ``ask`` (condition alleviation, eigendecomposition), and the
FullGaussian of the new distribution. Ours: ``CMAES.tell`` (the same steps, FullGaussian
included). Times: median over generations, after a few warm-up ones.

``--big`` adds our CMAES alone at larger d (the dimension guard's numbers) and
``--profile`` prints where our update's time goes.

    python benchmarks/cmaes_speed.py [--dims 30 130] [--popsize 50] [--generations 100]
    python benchmarks/cmaes_speed.py --dims --big 500 1000 2000 --generations 5
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import numpy as np

from imix_cli.core.algorithms.cmaes import CMAES
from imix_cli.core.distributions import FullGaussian


class PycmaWrapperUpdate:
    """The former pycma wrapper's update path (trimmed: no option checks)."""

    def __init__(self, dim, popsize, sigma=0.25):
        import cma
        import cma.utilities.utils

        def must_not_sample(*args):
            raise RuntimeError("pycma sampled")

        opts = dict(popsize=popsize, verbose=-9, verb_disp=0, verb_log=0, seed=np.nan, randn=must_not_sample,
                    CMA_mirrors=0, bounds=[None, None], AdaptSigma=True, updatecovwait=0)  # fmt: skip
        self.es = cma.CMAEvolutionStrategy(np.zeros(dim), sigma, opts)
        self._timer = cma.utilities.utils.ElapsedWCTime
        self.prepare()

    def prepare(self):
        es = self.es
        es.alleviate_conditioning_in_coordinates(es.opts["conditioncov_alleviate"][0])
        es.alleviate_conditioning(es.opts["conditioncov_alleviate"][-1])
        es.sm.update_now()
        es._updateBDfromSM(es.sm)
        a = es.sigma * (es.sm.B * es.sm.D)
        self.distribution = FullGaussian(np.array(es.mean), a @ a.T)

    def tell(self, samples, utilities):
        es = self.es
        if es.countiter == 0:
            es.timer = self._timer()
        else:
            es.timer.tic  # noqa: B018  (a property with a side effect, as in the old wrapper)
        es._flgtelldone = False
        es.ary = []
        es.number_of_injections = 0
        es.number_of_solutions_asked = len(samples)
        es._is_independent_sample = len(samples) * [True]
        es.evaluations_per_f_value = 1
        es.tell(samples.copy(), (-utilities).tolist(), check_points=False)
        self.prepare()


def time_updates(dim, popsize, generations, with_pycma=True, warmup=3, seed=0):
    """Median seconds per ``tell``: ``{"imix": t, "pycma": t}`` (pycma only if asked)."""
    rng = np.random.default_rng(seed)
    ours = CMAES(dim, popsize=popsize, weight_decay=0.0)
    ref = PycmaWrapperUpdate(dim, popsize) if with_pycma else None
    times = {"imix": [], "pycma": []}
    for g in range(warmup + generations):
        samples = ours.ask(rng)
        utilities = -np.einsum("ij,ij->i", samples, samples)  # sphere, maximised
        t0 = time.perf_counter()
        ours._update(samples, utilities)
        t1 = time.perf_counter()
        if ref is not None:
            ref.tell(samples, utilities)
        t2 = time.perf_counter()
        if g >= warmup:
            times["imix"].append(t1 - t0)
            times["pycma"].append(t2 - t1)
    return {k: float(np.median(v)) for k, v in times.items() if v}


def profile_updates(dim, popsize, generations, seed=0, top=12):
    rng = np.random.default_rng(seed)
    es = CMAES(dim, popsize=popsize, weight_decay=0.0)
    batches = [es.ask(rng) for _ in range(generations)]
    profiler = cProfile.Profile()
    profiler.enable()
    for samples in batches:
        es._update(samples, -np.einsum("ij,ij->i", samples, samples))
    profiler.disable()
    pstats.Stats(profiler).sort_stats("tottime").print_stats(top)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dims", type=int, nargs="*", default=[30, 130])
    parser.add_argument("--big", type=int, nargs="*", default=[], help="our CMAES alone at these d")
    parser.add_argument("--popsize", type=int, default=50)
    parser.add_argument("--generations", type=int, default=100)
    parser.add_argument("--profile", type=int, default=0, metavar="D", help="profile our update at this d")
    args = parser.parse_args()
    if args.dims:
        print("| d | lambda | pycma wrapper tell (ms) | imix CMAES tell (ms) | speed-up |\n|---:|---:|---:|---:|---:|")
        for dim in args.dims:
            t = time_updates(dim, args.popsize, args.generations)
            print(f"| {dim} | {args.popsize} | {t['pycma'] * 1e3:.2f} | {t['imix'] * 1e3:.2f} | {t['pycma'] / t['imix']:.1f}x |")
    if args.big:
        print("\n| d | lambda | imix CMAES tell (s) | 400 generations (min) |\n|---:|---:|---:|---:|")
        for dim in args.big:
            t = time_updates(dim, args.popsize, args.generations, with_pycma=False, warmup=1)["imix"]
            print(f"| {dim} | {args.popsize} | {t:.3f} | {400 * t / 60:.1f} |")
    if args.profile:
        profile_updates(args.profile, args.popsize, args.generations)


if __name__ == "__main__":
    main()
