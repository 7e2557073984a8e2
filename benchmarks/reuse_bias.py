"""Does reuse bend the search? One table: every ES, without mixing and with each rule, from no signal to real tasks.

Importance mixing draws a generation exactly from its distribution along a *fixed* path of
distributions; inside an ES the path is made from the members, and the search with mixing can
become a different search. Three things can bend it (README, "Reused returns and the search"):
tie ranks that follow a member from generation to generation (fixed by per-generation tie
keys), the members' own pull on the move they are then reused after (the ``conditional``
rule), and stored noisy returns told again (``reeval_count``). Each section isolates one:

``constant``  every return equal: each move is neutral, so any deviation is the loop's own.
              E[z^2] of the generation in the coordinates whitened by its distribution
              (1 without bias), the members' mean offset along the last move of the mean
              (0 without bias; in units of the distribution's spread), sigma/sigma0 and the
              mean's displacement ||m - m0|| / (sigma0 sqrt(d)) at the end.
``neutral``   every episode's return an independent N(0, 1) draw: stored returns carry luck
              and nothing else.
``noisy``     a sphere whose evaluations carry noise the size of the population's spread of
              true values: the true f(mean) at the end (lower is better).
``sphere``    the same sphere without noise: what reuse does to a search whose returns are exact.
``echo``      neutral returns again, for the mechanism of OpenES/SNES + EIM on noisy tasks: the
              cosine between consecutive rank-utility gradient estimates g_t = mean_i(u_i z_i)
              (u centred ranks of the told returns, z the members whitened by their generation's
              distribution: OpenES's and SNES's estimate of the mean's gradient), 0 when every
              return is a fresh draw; and the displacement. ``--beta1`` sets OpenES/SNES's Adam
              first-moment decay (OpenES's default 0.99), to separate the echo from the momentum.
``tasks``     reads an experiment of ``imix run`` CSVs (CartPole, Acrobot, MuJoCo: see
              ``make reuse-bias``) and prints, per run: the population's mean return at the
              end (reused returns included), the mean policy theta on fresh episodes at the end
              and averaged over the run (per generation, next to the same ES without mixing),
              episodes per seed, reuse, the lowest seed, the median final sigma.

Usage::

    python benchmarks/reuse_bias.py constant|neutral|noisy|sphere|echo [--seeds 5] [--generations 400] [--workers 2] [--beta1 B]
    python benchmarks/reuse_bias.py tasks [--experiment results/paper --experiment results/reuse_rules]

d = 130 (the CartPole policy's size), N = 50, sigma0 0.25, lr 0.01, no weight decay in the
synthetic sections. Rows: ``none`` (no mixing), ``exact`` (``eim=true eim_variant=exact``),
``conditional`` (``eim=true eim_variant=conditional``), ``weighted`` (``eim=true eim_variant=weighted``: the
archive weighted into the update, OpenES and SNES only; E[z^2], the offset and the echo's gradient weighted as
the update weights them), ``exact + reeval 2`` (``eim=true
reeval_count=2``); CMA-ES with mixing uses two-point step-size adaptation and ``exact + CSA`` is
CMA-ES with mixing and pycma's CSA; CMA-ES's ``none`` row is pycma's CSA, as the published tables
were made (``imix run`` now runs TPA without mixing too, so that ``eim=false,true`` changes the
mixing alone).
"""

from __future__ import annotations

import argparse
import glob
import itertools
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from imix_cli.core.algorithms import make_es
from imix_cli.core.mixing import _whitened
from imix_cli.core.mixing.generation import Archive, MixingSettings, finish_generation, plan_generation
from imix_cli.core.mixing.weighted_reuse import weighted_centered_ranks

ALGOS = ("openes", "snes", "cem", "cmaes")
RULES = {
    "none": MixingSettings(None),
    "exact": MixingSettings("exact"),  # min_fresh=1, the default: one slot drawn at random holds a fresh draw
    "exact, min_fresh 0": MixingSettings("exact", min_fresh=0),  # the rules alone (no minimal refresh)
    "conditional": MixingSettings("conditional"),
    "exact + reeval 2": MixingSettings("exact", reeval_count=2),
    "exact + CSA": MixingSettings("exact"),  # CMA-ES only: mixing with pycma's step-size control
    "weighted": MixingSettings("weighted"),  # OpenES, SNES only: the archive weighted into the update (imix_cli.core.mixing.weighted_reuse)
}
#: Rows that only apply to CMA-ES.
CMAES_ONLY = ("exact + CSA",)


def es_options(algo: str, rule: str) -> dict:
    """CMA-ES's step-size control as ``imix run``'s ``auto`` picks it (TPA when mixing), except on the
    row that asks for pycma's CSA with mixing."""
    if algo != "cmaes":
        return {}
    return {"step_size_control": "csa" if rule in ("none", *CMAES_ONLY) else "tpa"}


DIM, POPSIZE, SIGMA0 = 130, 50, 0.25
WARMUP = 20  # generations before E[z^2] and the offset are averaged


def synthetic(objective: str, algo: str, rule: str, seed: int, generations: int, dim: int = DIM, popsize: int = POPSIZE, beta1=None) -> dict:
    """One run of ``algo`` with ``rule`` on a synthetic objective; the statistics of the module docstring."""
    rng = np.random.default_rng(seed)
    noise_rng = np.random.default_rng(seed + 10_000)
    mean0 = np.full(dim, 0.5) if objective in ("noisy", "sphere") else None
    momentum = {"beta1": beta1} if beta1 is not None and algo in ("openes", "snes") else {}
    es = make_es(algo, dim, popsize=popsize, sigma=SIGMA0, lr=0.01, weight_decay=0.0, mean=mean0, **es_options(algo, rule), **momentum)
    settings, archive = RULES[rule], Archive()
    start, sigma0 = es.mean.copy(), es.distribution.sigma_mean
    z2, offset, previous_mean = [], [], None
    echo, previous_gradient = [], None
    reused = evaluated = 0
    for g in range(generations):
        dist = es.distribution
        plan = plan_generation(es, archive, settings, rng)
        x = plan.generation.samples
        # each member's weight in the update: equal, or eim_variant=weighted's importance weights
        weights = getattr(plan.generation, "weights", None)
        weights = np.full(x.shape[0], 1.0 / x.shape[0]) if weights is None else weights
        if g >= WARMUP:
            z = _whitened(dist, x)
            z2.append(float(weights @ np.mean(z * z, axis=1)))
            move = -_whitened(dist, previous_mean[None, :])[0]  # m_t - m_t-1, whitened by p_t
            norm = float(np.linalg.norm(move))
            if norm > 0:
                offset.append(float(weights @ (z @ (move / norm))))
        previous_mean = dist.mean.copy()
        todo = plan.points  # the members to evaluate, then CMA-ES's two TPA points
        if objective == "constant":
            returns = np.zeros(todo.shape[0])
        elif objective in ("neutral", "echo"):
            returns = noise_rng.standard_normal(todo.shape[0])
        elif objective == "sphere":
            returns = -np.sum(todo * todo, axis=1)
        else:  # true f spread across a population ~ sigma^2 sqrt(2d); noise of that size
            returns = -np.sum(todo * todo, axis=1) + SIGMA0**2 * np.sqrt(2 * dim) * noise_rng.standard_normal(todo.shape[0])
        fitness = finish_generation(es, archive, settings, plan, returns)
        # the rank-utility gradient estimate of this generation, and its cosine with the previous one's
        if getattr(plan.generation, "weights", None) is None:
            utilities = np.argsort(np.argsort(fitness, kind="stable"), kind="stable") / (x.shape[0] - 1) - 0.5
        else:
            utilities = weighted_centered_ranks(fitness, weights, np.arange(x.shape[0], dtype=np.uint64))
        gradient = (weights * utilities) @ _whitened(dist, x)
        if g >= WARMUP and previous_gradient is not None:
            echo.append(float(gradient @ previous_gradient / (np.linalg.norm(gradient) * np.linalg.norm(previous_gradient))))
        previous_gradient = gradient
        reused += plan.generation.reused
        evaluated += todo.shape[0]
    return {
        "E[z^2]": np.mean(z2),
        "offset": np.mean(offset),
        "sigma/sigma0": es.distribution.sigma_mean / sigma0,
        "displacement": float(np.linalg.norm(es.mean - start) / (sigma0 * np.sqrt(dim))),
        "reuse": reused / (generations * popsize),
        "episodes": evaluated,
        "true f(mean)": float(np.sum(es.mean**2)),
        "echo": float(np.mean(echo)) if echo else float("nan"),  # none before the warm-up ends
    }


def _one(job):
    return job, synthetic(*job)


def synthetic_table(objective: str, seeds: int, generations: int, workers: int, algos, rules, beta1=None) -> None:
    jobs = [
        (objective, a, r, s, generations, DIM, POPSIZE, beta1)
        for a, r, s in itertools.product(algos, rules, range(seeds))
        if (a == "cmaes" or r not in CMAES_ONLY) and (a in ("openes", "snes") or not RULES[r].weighted)
    ]
    results = {}
    with ProcessPoolExecutor(workers) as pool:
        for job, out in pool.map(_one, jobs):
            results.setdefault(job[1:3], []).append(out)
    columns = {
        "constant": ("E[z^2]", "offset", "sigma/sigma0", "displacement", "reuse"),
        "neutral": ("sigma/sigma0", "displacement", "reuse", "episodes"),
        "noisy": ("true f(mean)", "sigma/sigma0", "reuse", "episodes"),
        "sphere": ("true f(mean)", "sigma/sigma0", "reuse", "episodes"),
        "echo": ("echo", "displacement", "reuse"),
    }[objective]
    momentum = f", Adam beta1={beta1} (OpenES, SNES)" if beta1 is not None else ""
    print(f"objective={objective}, d={DIM}, N={POPSIZE}, {generations} generations, {seeds} seeds{momentum}: mean over seeds (± s.e.)")
    print("| ES | rule | " + " | ".join(columns) + " | vs none: " + ", ".join(c for c in columns if c in ("sigma/sigma0", "displacement")) + " |")
    print("|---|---|" + "---:|" * len(columns) + "---:|")
    for algo in algos:
        base = {c: np.mean([o[c] for o in results.get((algo, "none"), [])] or [np.nan]) for c in columns}
        for rule in rules:
            if (algo, rule) not in results:
                continue
            outs = results[(algo, rule)]
            cells = []
            for c in columns:
                v = np.array([o[c] for o in outs], dtype=float)
                se = v.std(ddof=1) / np.sqrt(v.size) if v.size > 1 else 0.0
                cells.append(f"{100 * v.mean():.1f} %" if c == "reuse" else (f"{v.mean():,.0f}" if c == "episodes" else f"{v.mean():.4g} ± {se:.2g}"))
            ratios = [f"{np.mean([o[c] for o in outs]) / base[c]:.2f}×" for c in columns if c in ("sigma/sigma0", "displacement") and base[c]]
            print(f"| {algo} | {rule} | " + " | ".join(cells) + " | " + ", ".join(ratios) + " |", flush=True)


def tasks_table(experiments: list[str]) -> None:
    import pandas as pd

    rows = []
    for folder in sorted(f for e in experiments for f in glob.glob(os.path.join(e, "*"))):
        csvs = sorted(f for f in glob.glob(os.path.join(folder, "seed_*.csv")) if os.path.basename(f)[5:-4].isdigit())  # not .partial
        if not csvs:
            continue
        frames = [pd.read_csv(f) for f in csvs]
        last = [f.iloc[-1] for f in frames]
        theta = [f["mean_policy_score"].dropna() for f in frames]
        rows.append(
            {
                "run": os.path.basename(folder),
                "seeds": len(frames),
                "population mean": np.mean([r["mean_score"] for r in last]),
                "population s.e.": np.std([r["mean_score"] for r in last], ddof=1) / np.sqrt(len(last)) if len(last) > 1 else 0.0,
                "theta fresh": np.mean([t.iloc[-1] for t in theta if len(t)]) if any(len(t) for t in theta) else np.nan,
                "theta over run": np.mean([t.mean() for t in theta if len(t)]) if any(len(t) for t in theta) else np.nan,
                "episodes/seed": np.mean([r["evaluations"] for r in last]),
                "reuse": np.mean([f["reused"].sum() / (f["popsize"].sum()) for f in frames]),
                "lowest seed": np.min([r["mean_score"] for r in last]),
                "median sigma": np.median([r["sigma_mean"] for r in last]),
            }
        )
    if not rows:
        raise SystemExit(f"no seed CSVs under {', '.join(experiments)}/*/")
    by_name = {r["run"]: r for r in rows}
    print(
        "| run | seeds | population mean (± s.e.) | theta, fresh episodes, end | theta over the run (vs none) "
        "| episodes/seed | reuse | lowest seed | median final sigma |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        algo_env = "-".join(r["run"].split("-")[:2])
        none = by_name.get(f"{algo_env}-none")
        versus = f" ({r['theta over run'] - none['theta over run']:+.1f})" if none and none is not r else ""
        print(
            f"| {r['run']} | {r['seeds']} | {r['population mean']:.2f} ± {r['population s.e.']:.2f} | {r['theta fresh']:.2f} | "
            f"{r['theta over run']:.2f}{versus} | {r['episodes/seed']:,.0f} | {100 * r['reuse']:.1f} % | {r['lowest seed']:.1f} | {r['median sigma']:.3g} |"
        )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("section", choices=("constant", "neutral", "noisy", "sphere", "echo", "tasks"))
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--generations", type=int, default=400)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--algos", default=",".join(ALGOS))
    parser.add_argument("--rules", default=",".join(RULES))
    parser.add_argument("--beta1", type=float, default=None, help="OpenES/SNES's Adam first-moment decay (default: each ES's own)")
    parser.add_argument("--experiment", action="append", help="an experiment folder of seed CSVs (repeatable)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    if args.section == "tasks":
        tasks_table(args.experiment or ["results/paper", "results/reuse_rules"])
    else:
        synthetic_table(args.section, args.seeds, args.generations, args.workers, args.algos.split(","), args.rules.split(","), args.beta1)
    print(f"({time.perf_counter() - started:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
