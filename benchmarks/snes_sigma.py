"""What shrinks SNES's sigma under EIM: controlled runs that switch one suspect off at a time.

Why (issue 35; docs/research/bias.md, "Sigma of the gradient ES"): on held-out tasks SNES + EIM ended
with a smaller sigma than SNES alone (InvertedDoublePendulum 0.75-0.95x). The suspects: the stored
returns (a reused member is told the return it drew once), Adam's momentum on log sigma, and the
sample itself -- inside the loop a reused member is not a fresh draw (it helped move the mean). Each
row changes one thing against the default (``exact``, ``min_fresh`` 1):

* ``exact fresh-returns``: every reused member is evaluated again (``reeval_prob`` 1 - 1e-6) and told the
  new return -- the sample is the default's, the stored returns are gone;
* ``momentum-0``: Adam's beta1 = 0 for log sigma, with and without mixing;
* ``min_fresh=k``: k random slots per generation drawn fresh -- members live shorter, reuse drops;
* ``conditional``: each reused member taken for what it is given the move it took part in (exact
  for the loop under neutral ranks; :mod:`imix_cli.core.mixing`, "Reuse inside the loop");
* ``weighted``: the archive weighted into the update instead of mixed (``eim_variant=weighted``,
  :mod:`imix_cli.core.mixing.weighted_reuse`); the told gradient is the weighted one SNES takes.

Next to the final sigma, each generation's sigma gradient (SNES's grad log sigma, averaged over the
coordinates) is compared with the gradient of a *shadow* generation: ``popsize`` fresh draws from the
same distribution, evaluated on their own episodes and never told. Their difference is the bias of
the told generation at the same (mu, sigma), whatever the path; its standard error is taken over
blocks of 25 generations (the told gradients are correlated from one generation to the next: the
same members). The shadow changes nothing in the runs (its own random streams); ``--no-shadow`` leaves
it out (final sigma only, half the episodes on a gymnasium task).

    python benchmarks/snes_sigma.py [--tasks hash,idp] [--seeds 5] [--rules "none,exact,..."] [--no-shadow]

Tasks: ``hash`` -- f(x) = sin(10^4 w.x), 20-d: noise-free (a member evaluated again returns the
same number) but uninformative, so nothing but the loop can move sigma; ``sphere`` -- f = -|x|^2,
20-d, started at the optimum; ``idp`` (InvertedDoublePendulum-v5, 200-step cap), ``pendulum``
(Pendulum-v1), ``reacher`` (Reacher-v5) -- tasks of ``benchmarks/untuned_tasks.py`` with imix's default
policy (MuJoCo ones need the mujoco extra). SNES at imix's defaults, popsize 20.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from imix_cli import MixingES
from imix_cli.core.algorithms.snes import SNES

POPSIZE = 20
#: task -> (generations, what it is)
TASKS = {"hash": (300, "20-d sin(1e4 w.x), noise-free, uninformative"), "sphere": (300, "20-d -|x|^2 from its optimum"),
         "idp": (150, "InvertedDoublePendulum-v5, cap 200"), "pendulum": (150, "Pendulum-v1"), "reacher": (150, "Reacher-v5")}  # fmt: skip
#: the gymnasium tasks: name -> (id, env.max_steps or None for the env's own limit), as benchmarks/untuned_tasks.py runs them
GYM = {"idp": ("InvertedDoublePendulum-v5", 200), "pendulum": ("Pendulum-v1", None), "reacher": ("Reacher-v5", None)}
#: rule -> (variant, min_fresh, fresh returns, Adam beta1 on log sigma)
RULES = {
    "none": (None, 0, False, None),
    "exact": ("exact", 1, False, None),
    "exact fresh-returns": ("exact", 1, True, None),
    "none momentum-0": (None, 0, False, 0.0),
    "exact momentum-0": ("exact", 1, False, 0.0),
    "exact min_fresh=2": ("exact", 2, False, None),
    "exact min_fresh=3": ("exact", 3, False, None),
    "exact min_fresh=5": ("exact", 5, False, None),
    "conditional": ("conditional", 1, False, None),
    "weighted": ("weighted", 1, False, None),
}


class RecordingSNES(SNES):
    """SNES that records, at each tell, its sigma gradient and what the reused members look like."""

    def _update(self, samples, utilities):
        s = (samples - self.state.mean) / self.state.std
        q = s * s - 1.0
        reused = self.told_source > 0
        self.record["told"].append(float(np.mean(utilities @ q)) / 2.0)
        self.record["ez2_reused"].append(float(np.mean(q[reused])) + 1.0 if reused.any() else np.nan)
        self.record["u_reused"].append(float(np.mean(utilities[reused])) if reused.any() else np.nan)
        super()._update(samples, utilities)


def objective(task: str, stream: int):
    """(dim, f) with f(x) -> returns (maximised); ``stream`` seeds the episodes' resets."""
    if task in GYM:
        from imix_cli.core.evaluation import GymEvaluator

        env = GymEvaluator(*GYM[task])
        rng = np.random.default_rng(stream)

        def episodes(x):
            if not len(x):
                return np.zeros(0)
            returns, _ = env.evaluate(x, rng.integers(0, 2**62, len(x)))
            return np.asarray(returns, dtype=np.float64)

        return env.num_params, episodes
    if task == "hash":
        w = np.random.default_rng(7).standard_normal(20)
        return 20, lambda x: np.sin(1e4 * (x @ w))
    if task == "sphere":
        return 20, lambda x: -np.sum(x * x, axis=1)
    raise ValueError(f"unknown task {task!r}; valid: {', '.join(TASKS)}")


def run(task: str, rule: str, seed: int, generations: int, shadow: bool = True) -> dict:
    variant, min_fresh, fresh_returns, beta1 = RULES[rule]
    dim, f = objective(task, 1000 + seed)
    f_shadow = objective(task, 5000 + seed)[1] if shadow else None
    es0 = RecordingSNES(dim, popsize=POPSIZE)
    es0.record = {"told": [], "shadow": [], "ez2_reused": [], "u_reused": []}
    if beta1 is not None:
        es0.sigma_optimizer.beta1 = beta1
    es = MixingES(es0, variant, rng=seed, min_fresh=min_fresh, reeval_prob=1 - 1e-6 if fresh_returns else 0.0)
    shadow_rng = np.random.default_rng(3000 + seed)
    for _ in range(generations):
        x = es.ask()
        es0.told_source = es.plan.generation.source
        if shadow:
            xs = es0.distribution.sample(POPSIZE, shadow_rng)
            s = (xs - es0.distribution.mean) / es0.distribution.std
            es0.record["shadow"].append(float(np.mean(es0.utilities(xs, f_shadow(xs)) @ (s * s - 1.0))) / 2.0)
        es.tell(x, f(x))
    return {"sigma": float(np.median(es0.distribution.std)), "log_sigma": float(np.mean(np.log(es0.distribution.std))),
            "reuse": es.reuse, "episodes": es.evaluations, **{k: np.array(v) for k, v in es0.record.items()}}  # fmt: skip


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default="hash,idp")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--rules", default=",".join(RULES))
    parser.add_argument("--no-shadow", action="store_true", help="no shadow generation (half the episodes of a gymnasium task): no bias columns")
    args = parser.parse_args(argv)
    rules = args.rules.split(",")
    for rule in rules:
        if rule not in RULES:
            parser.error(f"unknown rule {rule!r}; valid: {', '.join(RULES)}")
    tasks = args.tasks.split(",")
    for task in tasks:  # every name checked before anything runs
        if task not in TASKS:
            parser.error(f"unknown task {task!r}; valid: {', '.join(TASKS)}")
    for task in tasks:
        generations = TASKS[task][0]
        print(f"\nSNES, {TASKS[task][1]}, popsize {POPSIZE}, {generations} generations, {args.seeds} seeds\n")
        print(
            "| rule | reuse | episodes/seed | median final sigma | vs none | mean log sigma vs none | sigma-gradient bias (told - shadow) "
            "| told | shadow | E[z^2], reused | utility, reused |"
        )
        print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
        base = {}
        for rule in rules:
            start = time.time()
            runs = [run(task, rule, seed, generations, shadow=not args.no_shadow) for seed in range(args.seeds)]
            sigma = float(np.median([r["sigma"] for r in runs]))
            log_sigma = float(np.mean([r["log_sigma"] for r in runs]))
            if rule in ("none", "none momentum-0"):
                base[rule] = (sigma, log_sigma)
            ref = base.get("none momentum-0" if rule == "exact momentum-0" else "none")
            told = np.concatenate([r["told"] for r in runs])
            bias = shadow = ""
            if not args.no_shadow:
                blocks = np.concatenate([(r["told"] - r["shadow"])[: generations // 25 * 25].reshape(-1, 25).mean(axis=1) for r in runs])
                bias = f"{blocks.mean():+.4f} ± {blocks.std(ddof=1) / np.sqrt(blocks.size):.4f}"
                shadow = f"{np.concatenate([r['shadow'] for r in runs]).mean():+.4f}"
            versus = f"{sigma / ref[0]:.2f}×" if ref else ""
            shift = f"{log_sigma - ref[1]:+.3f}" if ref else ""
            ez2, u = (np.concatenate([r[k] for r in runs]) for k in ("ez2_reused", "u_reused"))
            ez2, u = (f"{np.nanmean(ez2):.4f}", f"{np.nanmean(u):+.4f}") if np.isfinite(ez2).any() else ("", "")  # none: nothing reused
            print(
                f"| {rule} | {np.mean([r['reuse'] for r in runs]):.1%} | {np.mean([r['episodes'] for r in runs]):,.0f} | {sigma:.4g} | {versus} "
                f"| {shift} | {bias} | {told.mean():+.4f} | {shadow} | {ez2} | {u} |",
                flush=True,
            )
            print(f"<!-- {rule}: {time.time() - start:.0f} s -->", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
