"""CMA-ES's step size under importance mixing: three step-size controls, with and without mixing.

Why this script. With mixing, a third of CMA-ES's members are reused, and given the loop they
are not fresh draws of the current distribution (docs/research/bias.md, constant fitness: E[z^2]
0.977, members +0.05 spreads ahead along the last move). CSA compares the mean's step with the
step of *fresh* randomly ranked members, E||N(0, I)||, so under constant fitness it reads the
reused members' short steps as "converging" and shrinks sigma (0.55x the run without mixing in
200 generations). This script measures two remedies against pycma's CSA, each with and without
mixing, under constant fitness (where any drift of sigma is the loop's own) and on the sphere
(where sigma must shrink as fast as the search converges):

``csa``          imix's CMAES as it is (pycma's CSA).
``permutation``  CSA whose increment is the mean's step taken relative to the generation's own
                 mean, divided by its expected length had the ranks been a uniformly random
                 permutation of these very members (:func:`permutation_increment`). Under random
                 ranks each increment then has conditional mean 0 and E||.||^2 = d whatever the
                 members, so the path is unbiased under constant fitness by construction.
``tpa``          CMAES with ``step_size_control="tpa"``: two-point step-size adaptation (Hansen
                 2008; pycma 4.5's constants), two extra fresh episodes per generation along the
                 last move of the mean; its signal comes from those two evaluations only
                 (imix_cli/core/algorithms/cmaes.py). ``imix run`` uses it when it mixes.

What it showed (docs/research/bias.md, "CMA-ES's step size"): ``permutation`` removes the
constant-fitness drift but fails the sphere even without mixing (centring on the generation's
mean dilutes CSA's main signal for shrinking sigma: that the selected members are the short
ones), so it is not offered as an option; ``tpa`` neither drifts under constant fitness nor
collapses under neutral selection, and on the paper's tasks keeps CMA-ES + EIM's sigma near the
run without mixing -- it is the default with mixing. On the sphere no rule makes mixing free:
the mean's own moves change with reuse (the elites that pulled the mean are kept, ahead of it).

    python benchmarks/cma_step_size.py [--seeds-constant 10] [--seeds-sphere 4] [--generations 200] [--workers 2]
    python benchmarks/cma_step_size.py --tasks cartpole,acrobot [--task-seeds 10]   # the paper's tasks and settings

d = 130, N = 50, sigma0 0.25 (benchmarks/reuse_bias.py's settings); mixing = EIM's ``exact`` rule;
``--tasks``: CartPole/Acrobot with the paper's settings (``imix run``'s), the loop written out.
"""

from __future__ import annotations

import argparse
import itertools
import math
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from imix_cli.core.algorithms.cmaes import CMAES
from imix_cli.core.mixing.generation import Archive, MixingSettings, finish_generation, plan_generation
from imix_cli.core.numerics import linalg_kernels as lk

DIM, POPSIZE, SIGMA0 = 130, 50, 0.25
CONTROLS = ("csa", "permutation", "tpa")
MIXING = {"none": MixingSettings(None), "exact": MixingSettings("exact")}


def permutation_increment(x, mean, dm, scale, B, D, weights) -> np.ndarray:
    """CSA's increment: C^-1/2 (dm - (xbar - m)) / sigma, scaled so that under uniformly random ranks of
    these members its expected squared length is d.

    With position weights w (sum 1) and v = w - 1/n (sum 0), sum_i w_pi(i) (z_i - zbar) = sum_i v_pi(i) c_i,
    c_i = z_i - zbar; for a random permutation pi, E[v_pi(i)^2] = V / n and E[v_pi(i) v_pi(j)] =
    -V / (n (n - 1)) (i != j), V = sum v^2 = sum w^2 - 1/n, and sum_{i != j} <c_i, c_j> = -sum ||c_i||^2,
    so E ||.||^2 = V sum_i ||c_i||^2 / (n - 1). ``scale``: sigma times pycma's coordinate scaling.
    """
    n, d = x.shape
    w = np.maximum(np.asarray(weights, dtype=np.float64)[:n], 0.0)
    w = w / w.sum()
    spread = float(np.sum(w * w)) - 1.0 / n
    xbar = lk.vec_mat(np.full(n, 1.0 / n), x)
    centred = lk.mat_mat((x - xbar) / scale, B) / D  # rows B^T c_i / D: the norms of C^-1/2 c_i
    expected = spread * float(np.sum(lk.row_sq_norms(centred))) / (n - 1)
    step = lk.mat_vec(B, lk.vec_mat((dm - (xbar - mean)) / scale, B) / D)
    return step * math.sqrt(d / expected) if expected > 0 else step


class PermutationCMAES(CMAES):
    """CMAES whose CSA path takes :func:`permutation_increment` (hsig still reads pycma's path)."""

    def _update(self, samples, utilities):
        n = samples.shape[0]
        _, weights = self._parameters(n)
        B, D, scale, cs = self.eigenvectors, self.eigenvalues_sqrt, self.step_size * self.scaling, self.cs
        mean_old, path_old, sigma_old = self.mean_geno.copy(), self.p_sigma.copy(), self.step_size
        super()._update(samples, utilities)
        x = samples if self.transform is None else lk.mat_mat(samples, self.transform_inverse.T)
        increment = permutation_increment(x, mean_old, self.mean_geno - mean_old, scale, B, D, weights)
        self.p_sigma = (1 - cs) * path_old + math.sqrt(cs * (2 - cs)) * increment
        s = (np.sqrt(np.sum(self.p_sigma**2)) / self.chi_d - 1) * cs / self.damps
        self.step_size = sigma_old * math.exp(min(max(float(s), -1), 1))
        self._set_distribution()


def make_cmaes(control: str, dim: int, popsize: int, **options) -> CMAES:
    if control == "permutation":
        return PermutationCMAES(dim, popsize=popsize, **options)
    return CMAES(dim, popsize=popsize, step_size_control=control, **options)


def generation_step(es, archive, settings, rng, f) -> tuple[np.ndarray, int]:
    """One generation as imix runs it: mix, evaluate the members to evaluate and TPA's two points, tell."""
    plan = plan_generation(es, archive, settings, rng)
    points = plan.points
    return finish_generation(es, archive, settings, plan, f(points)), len(points)


def run(objective: str, control: str, mixing: str, seed: int, generations: int, dim: int = DIM, popsize: int = POPSIZE) -> dict:
    rng = np.random.default_rng(seed)
    mean0 = np.full(dim, 0.5) if objective == "sphere" else None
    es = make_cmaes(control, dim, popsize, sigma=SIGMA0, weight_decay=0.0, mean=mean0)
    archive, sigma0, episodes = Archive(), es.distribution.sigma_mean, 0

    def f(x):
        return np.zeros(len(x)) if objective == "constant" else -np.sum(x * x, axis=1)

    for _ in range(generations):
        episodes += generation_step(es, archive, MIXING[mixing], rng, f)[1]
    return {"log sigma/sigma0": math.log(es.distribution.sigma_mean / sigma0), "f(mean)": float(np.sum(es.mean**2)), "episodes": episodes}


def _one(job):
    return job, run(*job)


def run_task(env: str, control: str, mixing: str, seed: int, generations: int | None = None) -> dict:
    """One seed of ``imix run algo=cmaes env=<env> [eim=true]`` with the run's own settings (the paper's), the
    loop written out here so that TPA's two points can be evaluated; theta: the mean on 5 fresh episodes."""
    from imix_cli.core.evaluation import make_evaluator
    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.loop.lockstep import loop_settings

    spec = validate_overrides(["algo=cmaes", f"env={env}", f"eim={mixing != 'none'}"])[0]
    evaluator = make_evaluator(spec.env_name, spec.env_max_steps)
    settings = loop_settings(spec, evaluator)
    options = {k: v for k, v in settings.es_options.items() if k not in ("popsize", "step_size_control")}
    es = make_cmaes(control, settings.dim, spec.popsize, **options)
    sample_rng, episode_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    archive, episodes = Archive(), 0

    def f(x):
        return evaluator.evaluate(x, episode_rng.integers(0, 2**62, size=len(x)))[0]

    for _ in range(generations or spec.generations):
        fitness, n = generation_step(es, archive, settings.mixing, sample_rng, f)
        episodes += n
    theta = float(np.mean(f(np.repeat(es.mean[None, :], 5, axis=0))))
    return {"population": float(np.mean(fitness)), "theta": theta, "sigma": es.distribution.sigma_mean, "episodes": episodes}


def tasks_table(envs, seeds: int, workers: int, generations: int | None) -> None:
    jobs = [(e, c, m, s, generations) for e, c, m, s in itertools.product(envs, CONTROLS[::2], MIXING, range(seeds))]  # csa, tpa
    results = {}
    with ProcessPoolExecutor(workers) as pool:
        for job, out in pool.map(_task, jobs):
            results.setdefault(job[:3], []).append(out)
    print(f"CMA-ES, paper settings, {seeds} seeds; mixing: EIM exact; mean over seeds (± s.e.); theta: the mean on 5 fresh episodes at the end")
    print("| env | step size | mixing | population mean | theta | lowest seed (population) | median final sigma | episodes/seed |")
    print("|---|---|---|---:|---:|---:|---:|---:|")
    for key, outs in results.items():
        pop, theta = np.array([o["population"] for o in outs]), np.array([o["theta"] for o in outs])
        se = pop.std(ddof=1) / np.sqrt(pop.size)
        cells = [*key, f"{pop.mean():.2f} ± {se:.2f}", f"{theta.mean():.2f}", f"{pop.min():.1f}", f"{np.median([o['sigma'] for o in outs]):.3g}"]
        print("| " + " | ".join(cells) + f" | {np.mean([o['episodes'] for o in outs]):,.0f} |", flush=True)


def _task(job):
    return job, run_task(*job)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds-constant", type=int, default=10)
    parser.add_argument("--seeds-sphere", type=int, default=4)
    parser.add_argument("--generations", type=int, default=200)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--tasks", help="instead: CSA and TPA, with and without EIM, on these envs (e.g. cartpole,acrobot)")
    parser.add_argument("--task-seeds", type=int, default=10)
    args = parser.parse_args(argv)
    if args.tasks:
        tasks_table(args.tasks.split(","), args.task_seeds, args.workers, None)
        return 0
    seeds = {"constant": args.seeds_constant, "sphere": args.seeds_sphere}
    jobs = [(o, c, m, s, args.generations) for o in seeds for c, m in itertools.product(CONTROLS, MIXING) for s in range(seeds[o])]
    results = {}
    with ProcessPoolExecutor(args.workers) as pool:
        for job, out in pool.map(_one, jobs):
            results.setdefault(job[:3], []).append(out)
    print(f"CMA-ES, d={DIM}, N={POPSIZE}, {args.generations} generations; mixing: EIM exact; mean over seeds (± s.e.)")
    print("| objective | seeds | step size | mixing | log(sigma/sigma0) | sigma vs no mixing | f(mean), median | episodes |")
    print("|---|---:|---|---|---:|---:|---:|---:|")
    for objective, control, mixing in itertools.product(seeds, CONTROLS, MIXING):
        outs = results[(objective, control, mixing)]
        logs = np.array([o["log sigma/sigma0"] for o in outs])
        base = np.mean([o["log sigma/sigma0"] for o in results[(objective, control, "none")]])
        se = logs.std(ddof=1) / np.sqrt(logs.size) if logs.size > 1 else 0.0
        f_median = np.median([o["f(mean)"] for o in outs])
        episodes = np.mean([o["episodes"] for o in outs])
        ratio = math.exp(logs.mean() - base)
        cells = [objective, len(outs), control, mixing, f"{logs.mean():+.3f} ± {se:.3f}", f"{ratio:.3g}×", f"{f_median:.3g}", f"{episodes:,.0f}"]
        print("| " + " | ".join(map(str, cells)) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
