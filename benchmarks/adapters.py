"""Importance mixing for pycma and evosax (imix_cli.core.adapters): the measurements of docs/adapters.md.

    python benchmarks/adapters.py all                    # every section, the docs' tables (full seeds)
    python benchmarks/adapters.py cma --seeds 15 --dims 10,40
    python benchmarks/adapters.py stepsize | noisy | evosax [--seeds N]
    python benchmarks/adapters.py evosax --seed 0 > s0.jsonl   # one seed's runs (JSON lines), e.g. one process per seed,
    python benchmarks/adapters.py table s0.jsonl s1.jsonl      # then their table (noisy likewise)

``make adapters`` runs every section in turn into results/adapters/.

Sections (each prints a markdown table):

``stepsize``  pycma's step-size control under mixing (d = 10, default popsize, x0 = 1 (rosen: 0),
              sigma0 = 0.5): evaluations and generations to f(mean) <= 1e-8 for pycma alone (CSA;
              its TPA), and with mixing under pycma's CSA, pycma's TPA and imix's TPA
              (``PycmaES(step_size=...)``). The winner is the adapter's default.
``cma``       pycma on cma.ff.sphere, elli, rosen, d = 10 and 40, default popsize: evaluations to
              f(mean) <= 1e-8 with and without mixing (the adapter's defaults, ``"exact"``), and f(mean)
              of both at equal evaluations (the median evaluations mixing needed).
``noisy``     the noisy sphere of pycma issue 262 (``cma.ff.noisysphere(x, cond=1e4, noise=1,
              noise_offset=0)``, d = 33, x0 = 1, sigma0 = 1): noise-free f(mean) (``cma.ff.elli(mean,
              cond=1e4)``) at equal evaluations for pycma alone, pycma + TPA + ``cma.NoiseHandler``
              (the issue's setting, ``NoiseHandler(33)`` as ``cma.fmin2(..., noise_handler=cma.NoiseHandler)``
              makes it, in pycma's documented ask/tell loop; and with up to 30 re-evaluations,
              ``maxevals=[1, 1, 30]``), and mixing with and without the stored-return remedy ``reeval_count``.
``evosax``    evosax SNES and Open_ES on gymnax CartPole-v1 (``imix bench peers``' task and settings:
              popsize 50, sigma 0.25, Adam lr 0.01 for Open_ES, the 2 x 8 tanh policy, 200 steps; SNES at
              evosax's defaults, which move the mean by a full natural-gradient step per generation, and
              SNES from ``imix_cli.core.adapters.evosax.snes_for_mixing``, Adam 0.03 on the mean and lr_std 0.01):
              episodes and wall time until the generation's mean return (stored returns for reused
              members) reaches 195, with and without mixing. Every arm runs the same host loop (evosax's
              jitted ask/tell, compiled before the clock starts, and one jitted batched rollout of the
              points asked; batch sizes padded to a power of two so each compiles once), the arms of a
              seed back to back: the wall-time ratios against SNES at evosax's defaults are paired by seed.
``evosax-lr`` ``snes_for_mixing``'s two learning rates searched (``--lrs``, ``--lr-stds``: every pair) with mixing on the
              same task: episodes to 195 per seed, their median, and evosax's SNES alone on the same seeds. Choose
              on some seeds (``--seed 0 ... --seed 4``), check the choice on others (``--seed 5 ... --seed 14``).
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import numpy as np

FUNCTIONS = ("sphere", "elli", "rosen")
TARGET = 1e-8


def _quiet():
    warnings.simplefilter("ignore")


def _pycma(fname, d, seed, **options):
    import cma

    x0 = d * [0.0 if fname == "rosen" else 1.0]
    return cma.CMAEvolutionStrategy(x0, 0.5, {"seed": seed, "verbose": -9, **options})


def pycma_run(fname, d, seed, arm, max_generations=100_000):
    """One run to f(mean) <= 1e-8; returns evaluations per generation and f(mean) per generation (arrays)."""
    import cma

    import imix_cli
    from imix_cli.core.adapters.pycma import PycmaES

    _quiet()
    f = getattr(cma.ff, fname)
    tpa = {"AdaptSigma": cma.sigma_adaptation.CMAAdaptSigmaTPA} if arm in ("pycma-tpa", "mix-pycma-tpa") else {}
    es = _pycma(fname, d, seed, **tpa)
    evals, values = [], []
    if not arm.startswith("mix"):
        while f(es.mean) > TARGET and len(evals) < max_generations:
            x = es.ask()
            es.tell(x, [f(xi) for xi in x])
            evals.append(es.countevals)
            values.append(f(es.mean))
        return np.array(evals), np.array(values)
    step = {"mix": None, "mix-pycma-tpa": "pycma", "mix-tpa": "tpa", "mix-csa": "pycma"}[arm]
    m = imix_cli.MixingES(es if step is None else PycmaES(es, step_size=step), "exact", rng=seed)
    while f(m.distribution.mean) > TARGET and len(evals) < max_generations:
        x = m.ask()
        m.tell(x, [f(xi) for xi in x])
        evals.append(m.evaluations)
        values.append(f(m.distribution.mean))
    return np.array(evals), np.array(values)


def _safe_run(*args, **kw):
    """:func:`pycma_run`, or the run up to an error as one that did not reach the target (said on stderr)."""
    import sys

    try:
        return pycma_run(*args, **kw)
    except (ValueError, np.linalg.LinAlgError) as err:
        print(f"run {args} stopped: {err}", file=sys.stderr)
        return np.array([0]), np.array([np.inf])


def _f_at(evals, values, budget):
    """f(mean) after the last generation whose evaluations fit in ``budget`` (the start's if none)."""
    k = np.searchsorted(evals, budget, side="right") - 1
    return values[k] if k >= 0 else np.inf


def stepsize(seeds=5, dims=(10,)):
    arms = ("pycma", "pycma-tpa", "mix-csa", "mix-pycma-tpa", "mix-tpa")
    names = {"pycma": "pycma alone (CSA)", "pycma-tpa": "pycma alone (its TPA)", "mix-csa": "mixing, pycma's CSA (default)",
             "mix-pycma-tpa": "mixing, pycma's TPA", "mix-tpa": "mixing, imix's TPA"}  # fmt: skip
    print("| function | d | step size | evaluations to 1e-8, median [min, max] | generations, median | runs that reached it |")
    print("|---|---:|---|---:|---:|---:|")
    for fname in FUNCTIONS:
        for d in dims:
            for arm in arms:
                runs = [_safe_run(fname, d, s, arm, max_generations=20_000) for s in range(1, seeds + 1)]
                ok = [r for r in runs if r[1][-1] <= TARGET]
                e = np.array([r[0][-1] for r in ok]) if ok else np.array([np.nan])
                g = np.array([len(r[0]) for r in ok]) if ok else np.array([np.nan])
                spread = f"{np.median(e):,.0f} [{e.min():,.0f}, {e.max():,.0f}]"
                print(f"| {fname} | {d} | {names[arm]} | {spread} | {np.median(g):,.0f} | {len(ok)}/{seeds} |", flush=True)


def cma_table(seeds=15, dims=(10, 40), functions=FUNCTIONS):
    print("| function | d | evaluations to 1e-8, pycma alone | with mixing | ratio | generations ratio "
          "| f(mean) at equal evaluations (budget): pycma alone | with mixing | reuse |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---|---:|---:|")
    for fname in functions:
        for d in dims:
            plain = [_safe_run(fname, d, s, "pycma") for s in range(1, seeds + 1)]
            mixed = [_safe_run(fname, d, s, "mix") for s in range(1, seeds + 1)]
            ep, em = (np.array([r[0][-1] for r in runs]) for runs in (plain, mixed))
            gp, gm = (np.array([len(r[0]) for r in runs]) for runs in (plain, mixed))
            budget = float(np.median(em))
            fp = np.median([_f_at(*r, budget) for r in plain])
            fm = np.median([_f_at(*r, budget) for r in mixed])
            reuse = 1 - np.sum(em) / np.sum(gm * _popsize(d))
            print(f"| {fname} | {d} | {np.median(ep):,.0f} [{ep.min():,.0f}, {ep.max():,.0f}] | {np.median(em):,.0f} [{em.min():,.0f}, {em.max():,.0f}] | "
                  f"{np.median(em) / np.median(ep):.2f} | {np.median(gm) / np.median(gp):.2f} | ({budget:,.0f}) {fp:.2g} | {fm:.2g} "
                  f"| {100 * reuse:.0f} % |", flush=True)  # fmt: skip


def _popsize(d):
    return 4 + int(3 * np.log(d))


def noisy_run(seed, arm, budget, checkpoints):
    """Noise-free f(mean) at each checkpoint (evaluations) for one arm on issue 262's noisy sphere."""
    import cma

    import imix_cli

    _quiet()
    np.random.seed(10_000 + seed)  # the noise's stream (noisysphere draws from numpy's global generator)
    count = [0]

    def f(x):
        count[0] += 1
        return cma.ff.noisysphere(x, cond=1e4, noise=1, noise_offset=0.0)

    def truth(mean):
        return cma.ff.elli(np.asarray(mean), cond=1e4)

    d = 33
    options = {"seed": seed, "verbose": -9}
    if "NoiseHandler" in arm:
        options["AdaptSigma"] = cma.sigma_adaptation.CMAAdaptSigmaTPA
    es = cma.CMAEvolutionStrategy(d * [1.0], 1.0, options)
    out, todo = [], list(checkpoints)
    m = None
    if arm.startswith("mixing"):
        remedy = {"reeval_count": 2} if "reeval_count" in arm else {}
        m = imix_cli.MixingES(es, "exact", rng=seed, **remedy)
    nh = None
    if "NoiseHandler" in arm:  # the issue's: fmin2(..., noise_handler=cma.NoiseHandler) makes NoiseHandler(N), no re-evaluations
        nh = cma.NoiseHandler(d, maxevals=[1, 1, 30]) if "maxevals" in arm else cma.NoiseHandler(d)
    last = truth(es.mean)
    while todo and count[0] < budget:
        if m is not None:
            x = m.ask()
            m.tell(x, [f(xi) for xi in x])
            mean = m.distribution.mean
        elif nh is not None:
            x, values = es.ask_and_eval(f, evaluations=nh.evaluations)
            es.tell(x, values)
            es.sigma *= nh(x, values, f, es.ask)
            mean = es.mean
        else:
            x = es.ask()
            es.tell(x, [f(xi) for xi in x])
            mean = es.mean
        while todo and count[0] > todo[0]:
            out.append(last)
            todo.pop(0)
        last = truth(mean)
    out += [last] * len(todo)
    return out


NOISY_ARMS = ("pycma", "pycma + TPA + NoiseHandler", "pycma + TPA + NoiseHandler(maxevals=[1, 1, 30])", "mixing", "mixing + reeval_count=2")


def _checkpoints(budget):
    return [budget // 6, budget // 3, budget]


def noisy_runs(seeds, budget=30_000, arms=NOISY_ARMS):
    """One record per arm and seed (of the list ``seeds``): f(mean) at the checkpoints."""
    return [{"section": "noisy", "arm": arm, "seed": s, "budget": budget, "values": [float(v) for v in noisy_run(s, arm, budget, _checkpoints(budget))]}
            for arm in arms for s in seeds]  # fmt: skip


def noisy_table(records):
    budget = records[0]["budget"]
    print("| arm | seeds | " + " | ".join(f"f(mean) at {c:,} evaluations, median [IQR]" for c in _checkpoints(budget)) + " |")
    print("|---|---:|" + "---:|" * len(_checkpoints(budget)))
    for arm in dict.fromkeys(r["arm"] for r in records):
        values = np.array([r["values"] for r in records if r["arm"] == arm])
        cells = [f"{np.median(v):.3g} [{np.percentile(v, 25):.3g}, {np.percentile(v, 75):.3g}]" for v in values.T]
        print(f"| {arm} | {values.shape[0]} | " + " | ".join(cells) + " |", flush=True)


def _evosax_algorithm(algo, dim):
    """evosax ``algo`` (a key of :data:`EVOSAX_NAMES`) for ``dim`` parameters: (algorithm, params)."""
    import jax.numpy as jnp
    import optax
    from evosax.algorithms import SNES, Open_ES

    from imix_cli.bench.peers import PEER_LR, PEER_POPSIZE, PEER_SIGMA

    solution = jnp.zeros(dim)
    if algo == "snes":  # imix bench peers' setting: evosax's defaults but the initial std
        algorithm = SNES(population_size=PEER_POPSIZE, solution=solution)
        return algorithm, algorithm.default_params.replace(std_init=jnp.asarray(PEER_SIGMA))
    if algo == "snes-mixing":  # the adapter's SNES for mixing (imix_cli.core.adapters.evosax.snes_for_mixing)
        from imix_cli.core.adapters.evosax import snes_for_mixing

        return snes_for_mixing(PEER_POPSIZE, solution, std_init=PEER_SIGMA)
    if algo == "snes-small":  # imix's SNES step sizes: Adam (lr 0.01, beta1 0.99) on the mean, ~0.01 per generation on log sigma
        algorithm = SNES(population_size=PEER_POPSIZE, solution=solution, optimizer=optax.adam(PEER_LR, b1=0.99))
        return algorithm, algorithm.default_params.replace(std_init=jnp.asarray(PEER_SIGMA), lr_std_init=jnp.asarray(0.01))
    algorithm = Open_ES(population_size=PEER_POPSIZE, solution=solution, optimizer=optax.adam(PEER_LR),
                        std_schedule=optax.constant_schedule(PEER_SIGMA))  # fmt: skip
    return algorithm, algorithm.default_params


_CACHE = {}


def _cartpole_rollouts():
    """One jitted batched rollout of imix bench peers' CartPole (imix's policy, 200 steps) per process, and the
    parameter count: compiled once per batch size for all runs."""
    if "rollouts" not in _CACHE:
        import jax

        from imix_cli.bench.peers import gymnax_episode

        episode, dim = gymnax_episode("cartpole")
        _CACHE["rollouts"] = jax.jit(jax.vmap(lambda flat, key: episode(flat, key)[0])), dim
    return _CACHE["rollouts"]


def evosax_cartpole(algo, mixing, seed, max_generations=1000, target=195.0, algorithm=None, **mixing_options):
    """Episodes and wall seconds until the population mean return reaches ``target`` (None if never),
    generations and reuse. ``algorithm``: an (algorithm, params) pair in place of ``algo``'s."""
    import jax
    import jax.numpy as jnp

    import imix_cli
    from imix_cli.core.adapters.evosax import from_evosax

    rollouts, dim = _cartpole_rollouts()
    if algorithm is None:
        if algo not in _CACHE:  # one object per algorithm: evosax's jitted ask and tell compile once
            _CACHE[algo] = _evosax_algorithm(algo, dim)
        algorithm = _CACHE[algo]
    algorithm, params = algorithm
    solution = jnp.zeros(dim)
    key = jax.random.key(seed)
    eval_key = jax.random.key(1_000_000 + seed)
    # evosax jits ask and tell per algorithm object: compile them before the clock starts (both arms)
    warm = algorithm.init(jax.random.key(0), solution, params)
    population, warm = algorithm.ask(jax.random.key(0), warm, params)
    jax.block_until_ready(algorithm.tell(jax.random.key(0), population, jnp.zeros(population.shape[0]), warm, params))

    def evaluate(points):
        nonlocal eval_key
        n = points.shape[0]
        if n == 0:
            return np.zeros(0)
        size = 1 << (n - 1).bit_length()  # padded to a power of two: one compilation per size
        padded = np.zeros((size, dim), np.float32)
        padded[:n] = points
        eval_key, k = jax.random.split(eval_key)
        return np.asarray(rollouts(jnp.asarray(padded), jax.random.split(k, size)))[:n]

    for n in (1, 2, 4, 8, 16, 32, 64):  # compile before the clock starts (both arms)
        evaluate(np.zeros((n, dim)))
    started, episodes = time.perf_counter(), 0
    if mixing:
        m = imix_cli.MixingES(from_evosax(algorithm, params, key), "exact", rng=seed, **mixing_options)
        for generation in range(max_generations):
            x = m.ask()
            returns = evaluate(x)
            episodes += x.shape[0]
            fitness = m.tell(x, -returns)  # evosax minimises
            if -np.mean(fitness) >= target:
                return episodes, time.perf_counter() - started, generation + 1, m.reuse
        return None, time.perf_counter() - started, max_generations, m.reuse
    key, k_init = jax.random.split(key)
    state = algorithm.init(k_init, solution, params)
    for generation in range(max_generations):
        key, k_ask, k_tell = jax.random.split(key, 3)
        population, state = algorithm.ask(k_ask, state, params)
        returns = evaluate(np.asarray(population))
        episodes += population.shape[0]
        state, _ = algorithm.tell(k_tell, population, -jnp.asarray(returns), state, params)
        if np.mean(returns) >= target:
            return episodes, time.perf_counter() - started, generation + 1, 0.0
    return None, time.perf_counter() - started, max_generations, 0.0


EVOSAX_NAMES = {"snes": "SNES (evosax's defaults)", "snes-mixing": "SNES (snes_for_mixing)", "openes": "Open_ES (antithetic)",
                "snes-small": "SNES (imix's step sizes)"}  # fmt: skip


def evosax_runs(seeds, algos=("snes", "snes-mixing", "openes")):
    """One record per arm and seed (of the list ``seeds``). Every arm of a seed runs back to back (the
    machine's speed drifts), so that wall-time ratios can be paired seed by seed."""
    records = []
    for seed in seeds:
        for algo in algos:
            for mixing in (False, True):
                episodes, wall, generations, reuse = evosax_cartpole(algo, mixing, seed)
                records.append({"section": "evosax", "algo": algo, "mixing": mixing, "seed": seed, "episodes": episodes, "wall": wall,
                                "generations": generations, "reuse": reuse})  # fmt: skip
    return records


def evosax_table(records):
    """Episodes and wall-time ratios are per seed, paired with the first arm (evosax SNES at its defaults, no mixing)."""
    arms = list(dict.fromkeys((r["algo"], r["mixing"]) for r in records))
    seeds = sorted({r["seed"] for r in records})
    run = {(r["algo"], r["mixing"], r["seed"]): r for r in records}
    first = EVOSAX_NAMES[arms[0][0]]
    print(f"| algorithm | mixing | seeds reaching 195 | episodes to 195, median [min, max] | generations, median | reuse "
          f"| episodes: {first} alone / this, median | wall time to 195: this / {first} alone, median [min, max] |")  # fmt: skip
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for algo, mixing in arms:
        rs = [run[algo, mixing, s] for s in seeds]
        ok = [r for r in rs if r["episodes"] is not None]
        e = np.array([r["episodes"] for r in ok]) if ok else np.array([np.nan])
        g = np.median([r["generations"] for r in ok]) if ok else np.nan
        reuse = np.mean([r["reuse"] for r in rs])
        pairs = [(run[(*arms[0], s)], run[algo, mixing, s]) for s in seeds]
        pairs = [(b, r) for b, r in pairs if b["episodes"] is not None and r["episodes"] is not None]
        fewer = np.median([b["episodes"] / r["episodes"] for b, r in pairs]) if pairs else np.nan
        wall = np.array([r["wall"] / b["wall"] for b, r in pairs]) if pairs else np.array([np.nan])
        print(f"| {EVOSAX_NAMES[algo]} | {'exact' if mixing else 'none'} | {len(ok)}/{len(rs)} | {np.median(e):,.0f} [{e.min():,.0f}, {e.max():,.0f}] | "
              f"{g:.0f} | {100 * reuse:.0f} % | {fewer:.2f} | {np.median(wall):.2f} [{wall.min():.2f}, {wall.max():.2f}] |", flush=True)  # fmt: skip


def evosax_lr_table(seeds, lrs, lr_stds):
    """Episodes to 195 of evosax SNES + mixing for each (lr, lr_std) of ``snes_for_mixing``, and of evosax's SNES alone."""
    import jax.numpy as jnp

    from imix_cli.bench.peers import PEER_POPSIZE, PEER_SIGMA
    from imix_cli.core.adapters.evosax import snes_for_mixing

    _, dim = _cartpole_rollouts()
    alone = {s: evosax_cartpole("snes", False, s)[0] for s in seeds}
    print(f"seeds {', '.join(map(str, seeds))}; evosax's SNES alone: {np.median([e or np.inf for e in alone.values()]):,.0f} episodes (median)\n")
    print("| lr (mean, Adam) | lr_std | episodes to 195, median | per seed | alone / this, paired median | generations, median | reuse |")
    print("|---:|---:|---:|---|---:|---:|---:|")
    for lr in lrs:
        for lr_std in lr_stds:
            algorithm = snes_for_mixing(PEER_POPSIZE, jnp.zeros(dim), std_init=PEER_SIGMA, lr=lr, lr_std=lr_std)
            runs = {s: evosax_cartpole("snes-mixing", True, s, algorithm=algorithm) for s in seeds}
            episodes = [r[0] or np.inf for r in runs.values()]
            paired = np.median([(alone[s] or np.inf) / (runs[s][0] or np.inf) for s in seeds])
            print(f"| {lr:g} | {lr_std:g} | {np.median(episodes):,.0f} | {', '.join(f'{e:,.0f}' for e in episodes)} | {paired:.2f} "
                  f"| {np.median([r[2] for r in runs.values()]):.0f} | {100 * np.mean([r[3] for r in runs.values()]):.0f} % |", flush=True)  # fmt: skip


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("section", choices=["all", "stepsize", "cma", "noisy", "evosax", "evosax-lr", "table"])
    parser.add_argument("--seeds", type=int, default=None, help="seeds per cell (default: stepsize 5, cma 15, noisy 15, evosax 5)")
    parser.add_argument("--seed", type=int, action="append", help="noisy, evosax: run only this seed (repeatable) and print its runs as JSON lines")
    parser.add_argument("--dims", default="10,40", help="cma: dimensions")
    parser.add_argument("--functions", default=",".join(FUNCTIONS), help="cma: which of " + ", ".join(FUNCTIONS))
    parser.add_argument("--budget", type=int, default=30_000, help="noisy: evaluations")
    parser.add_argument("--algos", default="snes,snes-mixing,openes", help="evosax: " + ", ".join(EVOSAX_NAMES))
    parser.add_argument("--lrs", default="0.03,0.05,0.1", help="evosax-lr: learning rates of the mean (Adam)")
    parser.add_argument("--lr-stds", default="0.01,0.03", help="evosax-lr: learning rates of log std")
    parser.add_argument("files", nargs="*", help="table: files of JSON lines (--seed's output, e.g. of several processes) to tabulate")
    args = parser.parse_args(argv)
    dims = tuple(int(d) for d in args.dims.split(","))
    if args.section == "table":  # --seed's runs, from several processes, as one table per section
        records = [json.loads(line) for name in args.files for line in open(name) if line.startswith("{")]
        for section, table in (("noisy", noisy_table), ("evosax", evosax_table)):
            if any(r["section"] == section for r in records):
                table([r for r in records if r["section"] == section])
        return 0
    if args.section == "evosax-lr":
        floats = lambda text: [float(v) for v in text.split(",")]  # noqa: E731
        evosax_lr_table(args.seed or list(range(args.seeds or 5)), floats(args.lrs), floats(args.lr_stds))
        return 0
    if args.seed and args.section in ("noisy", "evosax"):
        runs = noisy_runs(args.seed, args.budget) if args.section == "noisy" else evosax_runs(args.seed, tuple(args.algos.split(",")))
        for record in runs:
            print(json.dumps(record), flush=True)
        return 0
    if args.section in ("all", "stepsize"):
        stepsize(args.seeds or 5)
    if args.section in ("all", "cma"):
        cma_table(args.seeds or 15, dims, tuple(args.functions.split(",")))
    if args.section in ("all", "noisy"):
        noisy_table(noisy_runs(range(1, (args.seeds or 15) + 1), args.budget))
    if args.section in ("all", "evosax"):
        evosax_table(evosax_runs(range(args.seeds or 5), tuple(args.algos.split(","))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
