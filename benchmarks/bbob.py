"""pycma alone and wrapped in importance mixing on COCO's bbob and bbob-noisy suites: the benchmark of docs/adapters.md.

    make bbob                                              # run + table + cocopp figure (the docs' numbers)
    make bbob-noisy                                        # the same on the noisy suite (f101-130) into results/bbob-noisy
    python benchmarks/bbob.py run --out results/bbob       # both arms, every problem, COCO's observer output
    python benchmarks/bbob.py table --out results/bbob     # the markdown table of docs/adapters.md
    python benchmarks/bbob.py cocopp --out results/bbob    # cocopp's runtime ECDFs per function group
    python benchmarks/bbob.py run --functions 7,13 --dims 5 --instances 1 --arms pycma,mixing  # a few problems
    python benchmarks/bbob.py overhead --dims 2,5,10,40   # ask + tell time per generation, wrapped against pycma alone

The protocol is a pycma user's (issue 45): bbob functions 1-24, dimensions 2, 5, 10, instances 1-3 (216
problems); per problem, x0 uniform in [-4, 4]^d, sigma0 = 2, a budget of 2000 d evaluations, a restart from a
new x0 (and a new seed) whenever ``stop()`` fires; the x0s and seeds of a problem are the same for every arm.
A problem is hit when f - f_opt <= 1e-8 (COCO's final target); its runtime is the evaluations until then.

``--suite bbob-noisy``: COCO's noisy suite (``cocoex.Suite("bbob-noisy", "", "")``, its observer "bbob-noisy"),
functions 101-130 -- moderate noise f101-106, severe noise f107-121, severe noise multimodal f122-130 (cocopp's groups
nzmod, nzsev, nzsmm) -- at the same dimensions, instances, protocol and budget; output under ``results/bbob-noisy``.
Which value is compared with 1e-8: the ES is told the noisy value, but cocoex returns (f - f_opt) * noise + 1.01e-8 +
f_opt (multiplicative noise; Cauchy noise is added on top of f + 1.01e-8), so the noisy value never comes within 1e-8
of f_opt and ``problem.final_target_hit``, which reads the best noisy value returned, never fires on this suite.
COCO's bbob-noisy observer records for each evaluation that reaches a new target the best *noise-free* f - f_opt so
far (column 3 of its ``.dat`` files, "best noise-free fitness - Fopt"), and cocopp measures runtimes on it: a noisy
problem is hit when that recorded noise-free value is <= 1e-8 (:class:`NoiseFreeTarget` reads the observer's file
after every generation), its runtime the evaluation the observer logged. Hits at 1e-8 are rare under severe noise, so
the noisy table adds hits at 1e-2 and the median best noise-free f - f_opt within the budget (each run's
``best_delta``), the progress a noisy-suite user reads where the final target is out of reach.

Arms (``--arms``): ``pycma`` (``cma.CMAEvolutionStrategy(x0, 2, {"seed": s, "verbose": -9})``, pycma's
ask/tell loop) and ``mixing`` (the same ES wrapped in ``imix_cli.MixingES(es, "exact", rng=s)``, the adapter's
defaults). ``mixing-K1``: ``eim_generations=1``; ``mixing-fresh3``: ``min_fresh=3`` -- settings the docs
measure. ``mixing-reeval2``: ``reeval_count=2``, 2 reused members re-evaluated per generation and the others'
stored values calibrated on them (the remedy docs/adapters.md measures on pycma's noisy sphere). Every arm of a
problem runs in the same process one after the other, so its overhead per generation (time in ask and tell, the
objective excluded) is measured next to pycma's under the same load.

``run`` writes one JSON line per (problem, arm) to ``OUT/runs.jsonl`` (finished pairs are skipped, so an
interrupted run resumes) and COCO's observer data to ``OUT/exdata/<arm>/``; it needs the ``bbob`` extra
(coco-experiment, cocopp).
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import os
import shutil
import sys
import time
import warnings
from pathlib import Path

import numpy as np

#: arm -> None (pycma alone) or (MixingES keywords, PycmaES keywords)
ARMS = {
    "pycma": None,
    "mixing": ({}, {}),
    "mixing-K1": ({"eim_generations": 1}, {}),
    "mixing-fresh3": ({"min_fresh": 3}, {}),
    "mixing-tpa": ({}, {"step_size": "tpa"}),
    "mixing-fresh-half": ({"min_fresh": "half"}, {}),
    "mixing-cond": ({"variant": "conditional"}, {}),
    "mixing-cond-pop2": ({"variant": "conditional"}, {}),
    "mixing-pop2": ({}, {}),  # pycma's default popsize doubled (POPSIZE_FACTOR)
    "mixing-pop3": ({}, {}),  # tripled: about as many fresh members per generation as pycma at its default
    "pycma-pop2": None,
    "pycma-pop3": None,
    "mixing-reeval2": ({"reeval_count": 2}, {}),  # 2 reused members re-evaluated per generation (the noisy suite's remedy)
}
#: arms that run pycma's IPOP restarts (cma.fmin2(..., restarts=9, incpopsize=2)), alone or with mixing (imix_cli.fmin2)
IPOP_ARMS = {"pycma-ipop": None, "mixing-ipop": {}, "pycma-bipop": None, "mixing-bipop": {}, "mixing-ipop-tpa": {"step_size": "tpa"},
             "mixing-ipop-fresh-half": {"min_fresh": "half"}}  # fmt: skip
ARMS.update(IPOP_ARMS)
#: arms whose pycma popsize is POPSIZE_FACTOR x pycma's default (4 + 3 ln d)
POPSIZE_FACTOR = {"mixing-pop2": 2, "pycma-pop2": 2, "mixing-cond-pop2": 2, "mixing-pop3": 3, "pycma-pop3": 3}
GROUPS = (
    ("separable f1-5", range(1, 6)),
    ("low/moderate conditioning f6-9", range(6, 10)),
    ("high conditioning f10-14", range(10, 15)),
    ("multimodal f15-19", range(15, 20)),
    ("weak structure f20-24", range(20, 25)),
)
#: bbob-noisy's groups, as cocopp groups them (nzmod, nzsev, nzsmm)
NOISY_GROUPS = (
    ("moderate noise f101-106", range(101, 107)),
    ("severe noise f107-121", range(107, 122)),
    ("severe noise multimodal f122-130", range(122, 131)),
)
#: suite -> its functions, table groups and output folder (``--suite``)
SUITES = {
    "bbob": {"functions": "1-24", "groups": GROUPS, "out": "results/bbob"},
    "bbob-noisy": {"functions": "101-130", "groups": NOISY_GROUPS, "out": "results/bbob-noisy"},
}
#: the noisy suite's second measure: hits at this looser target (the noise-free best f - f_opt)
LOOSE_TARGET = 1e-2
SIGMA0 = 2.0
BUDGET_PER_DIM = 2000


def _problem_seed(fid: int, dim: int, instance: int) -> int:
    return 1_000_003 * fid + 1009 * dim + instance


class NoiseFreeTarget:
    """The best noise-free f - f_opt of one bbob-noisy problem as COCO's observer records it (its ``.dat`` file).

    On bbob-noisy, cocoex returns (f - f_opt) * noise + 1.01e-8 + f_opt: the value the ES sees never comes within
    1e-8 of f_opt, so ``problem.final_target_hit`` (which reads the best value returned) never fires. The observer
    logs, at every evaluation that reaches a new target, the best *noise-free* f - f_opt so far (column 3 of
    ``data_f<fid>/bbobexp_f<fid>_DIM<d>.dat``, the value cocopp's runtimes are measured on). ``update()`` reads the
    lines written since the last call; ``runtime`` is the evaluation that first reached ``target``, ``best`` the
    best value read.
    """

    def __init__(self, observer, problem, target: float = 1e-8):
        fid, dim = problem.id_function, problem.dimension
        folder = Path(observer.result_folder)
        self.dat = folder / f"data_f{fid}" / f"bbobexp_f{fid}_DIM{dim}.dat"
        self.tdat = self.dat.with_suffix(".tdat")
        self.offset = self.dat.stat().st_size if self.dat.exists() else 0  # this problem's lines follow
        self.tdat_offset = self.tdat.stat().st_size if self.tdat.exists() else 0
        self.target = target
        self.runtime: int | None = None
        self.best = math.inf

    @property
    def hit(self) -> bool:
        return self.runtime is not None

    def _lines(self, path: Path, offset: int) -> tuple[list[list[str]], int]:
        if not path.exists():
            return [], offset
        with path.open("rb") as fh:
            fh.seek(offset)
            data = fh.read()
        end = data.rfind(b"\n") + 1  # whole lines only
        rows = [line.split() for line in data[:end].decode().splitlines() if line.strip() and not line.startswith("%")]
        return rows, offset + end

    def update(self) -> None:
        rows, self.offset = self._lines(self.dat, self.offset)
        for row in rows:
            evaluations, best = int(row[0]), float(row[2])
            self.best = min(self.best, best)
            if self.runtime is None and best <= self.target:
                self.runtime = evaluations

    def final_best(self) -> float:
        """After ``problem.free()``: the best noise-free f - f_opt of the whole run (the ``.tdat`` file's last
        line, which the observer writes with the final best), else the best of the ``.dat`` lines."""
        self.update()
        rows, self.tdat_offset = self._lines(self.tdat, self.tdat_offset)
        return min([self.best] + [float(row[2]) for row in rows[-1:]])


def run_problem(problem, arm: str, *, budget_per_dim: int = BUDGET_PER_DIM, noise_free: NoiseFreeTarget | None = None) -> dict:
    """One arm on one (observed) COCO problem under the protocol; returns its record. ``noise_free``: the problem
    is a bbob-noisy one, hit when its observer records a noise-free f - f_opt <= 1e-8 (:class:`NoiseFreeTarget`)."""
    import cma

    import imix_cli
    from imix_cli.core.adapters.pycma import PycmaES

    dim = problem.dimension
    budget = budget_per_dim * dim
    starts = np.random.default_rng(_problem_seed(problem.id_function, dim, problem.id_instance))
    record = {"problem": problem.id, "function": problem.id_function, "dim": dim, "instance": problem.id_instance, "arm": arm,
              "hit": False, "runtime": None, "evaluations": 0, "restarts": -1, "generations": 0, "stops": {}, "exception": None,
              "overhead_s": 0.0, "evaluation_s": 0.0}  # fmt: skip
    stops = collections.Counter()

    def hit() -> bool:
        return problem.final_target_hit if noise_free is None else noise_free.hit

    if arm in IPOP_ARMS:
        return _run_ipop(problem, arm, budget, starts, record, stops, noise_free)
    try:
        while problem.evaluations < budget and not hit():
            record["restarts"] += 1
            x0 = starts.uniform(-4, 4, dim)
            seed = int(starts.integers(1, 2**31 - 1))
            options = {"seed": seed, "verbose": -9, "maxfevals": budget - problem.evaluations}
            if arm in POPSIZE_FACTOR:
                options["popsize"] = POPSIZE_FACTOR[arm] * (4 + int(3 * math.log(dim)))
            es = cma.CMAEvolutionStrategy(x0, SIGMA0, options)
            if ARMS[arm] is not None:
                mixing_options, adapter_options = ARMS[arm]
                if mixing_options.get("min_fresh") == "half":
                    mixing_options = {**mixing_options, "min_fresh": es.popsize // 2}
                mixing_options = dict(mixing_options)
                variant = mixing_options.pop("variant", "exact")
                es = imix_cli.MixingES(PycmaES(es, **adapter_options), variant, rng=seed, **mixing_options)
            while True:
                t0 = time.perf_counter()
                stop = es.stop()
                if stop:
                    break
                x = es.ask()
                t1 = time.perf_counter()
                f = []
                for xi in x:
                    f.append(problem(xi))
                    if noise_free is None and problem.final_target_hit and record["runtime"] is None:
                        record["runtime"] = int(problem.evaluations)
                if noise_free is not None:  # the observer's lines of this generation (counted as evaluation time)
                    noise_free.update()
                    if noise_free.hit and record["runtime"] is None:
                        record["runtime"] = noise_free.runtime
                t2 = time.perf_counter()
                es.tell(x, f)
                t3 = time.perf_counter()
                record["overhead_s"] += (t1 - t0) + (t3 - t2)
                record["evaluation_s"] += t2 - t1
                record["generations"] += 1
                if hit() or problem.evaluations >= budget:
                    break
            for key in stop:
                stops[key] += 1
    except Exception as err:  # noqa: BLE001 (the benchmark counts exceptions; it must go on to the next problem)
        record["exception"] = f"{type(err).__name__}: {err}"
    record["hit"] = bool(hit())
    record["evaluations"] = int(problem.evaluations)
    record["stops"] = dict(stops)
    return record


def _run_ipop(problem, arm, budget, starts, record, stops, noise_free=None) -> dict:
    """pycma's IPOP or BIPOP (``cma.fmin2``, or ``imix_cli.fmin2`` with mixing) under the protocol: x0 drawn anew
    at every restart, the budget and the target enforced by pycma's ``termination_callback`` (which ends fmin's
    restart loop too)."""
    import cma

    import imix_cli

    dim = problem.dimension
    seed = int(starts.integers(1, 2**31 - 1))

    def hit() -> bool:
        return problem.final_target_hit if noise_free is None else noise_free.hit

    def objective(x):
        f = problem(x)
        if noise_free is None and problem.final_target_hit and record["runtime"] is None:
            record["runtime"] = int(problem.evaluations)
        return f

    def done(es):
        if noise_free is not None:  # once per iteration: the observer's lines of this generation
            noise_free.update()
            if noise_free.hit and record["runtime"] is None:
                record["runtime"] = noise_free.runtime
        return bool(hit() or problem.evaluations >= budget)

    options = {"seed": seed, "verbose": -9, "CMA_mirrors": 0, "termination_callback": done}
    fmin2 = cma.fmin2 if ARMS[arm] is None else imix_cli.fmin2
    mixing = dict(ARMS[arm] or {})
    if mixing.get("min_fresh") == "half":  # half of the default popsize (IPOP's later runs: a smaller share)
        mixing["min_fresh"] = (4 + int(3 * math.log(dim))) // 2
    kwargs = {} if ARMS[arm] is None else {"mixing": mixing}
    t0 = time.perf_counter()
    try:
        _, es = fmin2(objective, lambda: starts.uniform(-4, 4, dim), SIGMA0, options, restarts=9, incpopsize=2, bipop="bipop" in arm, **kwargs)
        for stop in es.all_stoppings[1:]:
            for key in stop or {}:
                stops[key] += 1
        record["restarts"] = len(es.all_stoppings) - 2
    except Exception as err:  # noqa: BLE001 (counted, as in run_problem)
        record["exception"] = f"{type(err).__name__}: {err}"
    record["evaluation_s"] = time.perf_counter() - t0
    if noise_free is not None:
        done(None)
    record["hit"] = bool(hit())
    record["evaluations"] = int(problem.evaluations)
    record["stops"] = dict(stops)
    return record


def _todo(functions, dims, instances):
    return [(f, d, i) for d in dims for f in functions for i in instances]


def _worker(args):
    """Run every arm on the problems of one worker, observed into OUT/exdata/<arm>/w<k>; yield records."""
    worker, problems, arms, out, budget_per_dim, *rest = args
    suite_name = rest[0] if rest else "bbob"
    import cocoex

    warnings.simplefilter("ignore")
    cocoex.log_level("warning")
    out = Path(out)
    records = []
    for arm in arms:
        os.chdir(out / "exdata" / arm)
        observer = cocoex.Observer(suite_name, f"result_folder: w{worker} algorithm_name: {arm}")  # the observer of the suite's name
        suite = cocoex.Suite(suite_name, *suite_options(problems))
        for fid, dim, inst in problems:
            problem = suite.get_problem_by_function_dimension_instance(fid, dim, inst)
            problem.observe_with(observer)
            noise_free = NoiseFreeTarget(observer, problem) if suite_name == "bbob-noisy" else None
            record = run_problem(problem, arm, budget_per_dim=budget_per_dim, noise_free=noise_free)
            problem.free()
            if noise_free is not None:
                record["best_delta"] = noise_free.final_best()  # the noise-free best f - f_opt within the budget
            records.append(record)
        del observer
    return records


def suite_options(problems) -> tuple[str, str]:
    """``cocoex.Suite``'s instance and option strings holding ``problems`` ((function, dim, instance) triples): COCO's
    default suite holds only that year's instances (bbob: no instance 6), so the instances are named."""
    instances = ",".join(str(i) for i in sorted({p[2] for p in problems}))
    dims = ",".join(str(d) for d in sorted({p[1] for p in problems}))
    return f"instances: {instances}", f"dimensions: {dims}"


def missing_problem(suite: str, problems) -> str | None:
    """The first of ``problems`` that COCO's ``suite`` does not have, in words; None if it has them all."""
    import cocoex

    cocoex.log_level("error")
    try:
        coco = cocoex.Suite(suite, *suite_options(problems))
    except Exception:  # noqa: BLE001 (cocoex calls a suite with no problem "unknown")
        coco = None
    for fid, dim, inst in problems:
        try:
            coco.get_problem_by_function_dimension_instance(fid, dim, inst).free()
        except Exception:  # noqa: BLE001 (cocoex raises its own exception types)
            return f"{suite} has no problem f{fid} d={dim} instance {inst} (its dimensions are 2, 3, 5, 10, 20, 40; instances >= 1)"
    return None


def run(out: Path, functions, dims, instances, arms, workers: int, budget_per_dim: int, suite: str = "bbob") -> None:
    import multiprocessing

    out.mkdir(parents=True, exist_ok=True)
    runs = out / "runs.jsonl"
    done = set()
    if runs.exists():
        for line in runs.read_text().splitlines():
            r = json.loads(line)
            done.add((r["function"], r["dim"], r["instance"], r["arm"]))
    todo = [p for p in _todo(functions, dims, instances) if any((*p, a) not in done for a in arms)]
    if not todo:
        print(f"{suite}: every problem of {runs} is done", file=sys.stderr)
        return
    for arm in arms:  # observer folders: a resumed run starts them anew (COCO appends -001 to an existing folder)
        folder = out / "exdata" / arm
        folder.mkdir(parents=True, exist_ok=True)
    # problems dealt round-robin by cost (d), one chunk per task, so both workers stay busy to the end
    chunks = [todo[k :: workers * 8] for k in range(workers * 8)]
    tasks = [(f"{k:02d}_{int(time.time())}", chunk, arms, str(out), budget_per_dim, suite) for k, chunk in enumerate(chunks) if chunk]
    t0 = time.time()
    with multiprocessing.get_context("spawn").Pool(workers) as pool, runs.open("a") as sink:
        for n, records in enumerate(pool.imap_unordered(_worker, tasks), start=1):
            for r in records:
                if (r["function"], r["dim"], r["instance"], r["arm"]) not in done:
                    sink.write(json.dumps(r) + "\n")
            sink.flush()
            print(f"{suite}: {n}/{len(tasks)} chunks, {time.time() - t0:.0f} s", file=sys.stderr)


def load(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines() if line.strip()]


def paired_hits(records: list[dict], arms=("pycma", "mixing"), groups=GROUPS) -> str:
    """Whether a group's difference in hits is more than chance: the problems hit by one arm only, and the exact
    two-sided sign test on them (McNemar's exact test; the problems both or neither hit say nothing of the
    difference). With 36-45 problems a group, a difference of one or two hits is what two equal arms give."""
    from scipy.stats import binomtest

    hit = {(r["arm"], r["problem"]): r["hit"] for r in records}
    a, b = arms
    problems = sorted({r["problem"]: r["function"] for r in records if r["arm"] == a and (b, r["problem"]) in hit}.items())
    rows = [f"| group | hit by {b} only | hit by {a} only | sign test p |", "|---|---:|---:|---:|"]
    for label, functions in (*groups, ("all", range(0, 1000))):
        mine = [p for p, f in problems if f in functions]
        if not mine:
            continue  # a group the runs did not cover: no row, as in the table
        gained = sum(hit[(b, p)] and not hit[(a, p)] for p in mine)
        lost = sum(hit[(a, p)] and not hit[(b, p)] for p in mine)
        p_value = binomtest(gained, gained + lost, 0.5).pvalue if gained + lost else 1.0
        rows.append(f"| {label} | {gained} | {lost} | {p_value:.2f} |")
    return "\n".join(rows)


def table(records: list[dict], arms=("pycma", "mixing"), groups=GROUPS) -> str:
    """The markdown table: hits, the median runtime ratio where both hit, restarts, stops, exceptions. With
    ``NOISY_GROUPS`` (bbob-noisy) two columns more, read off the noise-free best f - f_opt each run reached
    (``best_delta``): hits at ``LOOSE_TARGET`` and the median best f - f_opt of each arm."""
    base, other = arms
    noisy = groups is NOISY_GROUPS
    by = {(r["function"], r["dim"], r["instance"], r["arm"]): r for r in records}
    keys = sorted({k[:3] for k in by if k[3] == base and (*k[:3], other) in by})
    lines = [
        f"| group | {base} hits | {other} hits | median runtime {other}/{base} where both hit (pairs) "
        f"| restarts {other}/{base} | tolflatfitness stops | exceptions |"
        + (
            f" hits at {_loose()} {base} / {other} | median best f - f_opt {base} / {other} | lower best f - f_opt {other} vs {base} where not both hit |"
            if noisy
            else ""
        ),
        "|---|---:|---:|---:|---:|---:|---:|" + ("---:|---:|---:|" if noisy else ""),
    ]
    all_ratios = []
    everything = range(min(min(f) for _, f in groups), max(max(f) for _, f in groups) + 1)
    for name, fids in (*groups, ("all", everything)):
        ks = [k for k in keys if k[0] in fids]
        if not ks:
            continue
        a = [by[(*k, base)] for k in ks]
        b = [by[(*k, other)] for k in ks]
        ratios = [y["runtime"] / x["runtime"] for x, y in zip(a, b) if x["runtime"] and y["runtime"]]
        if name != "all":
            all_ratios += ratios
        else:
            ratios = all_ratios
        ra, rb = sum(max(0, x["restarts"]) for x in a), sum(max(0, y["restarts"]) for y in b)
        fa = sum(x["stops"].get("tolflatfitness", 0) for x in a)
        fb = sum(y["stops"].get("tolflatfitness", 0) for y in b)
        exc = sum(bool(y["exception"]) for y in b)
        med = f"{np.median(ratios):.2f} ({len(ratios)})" if ratios else "-"
        rr = f"{rb / ra:.2f} ({rb}/{ra})" if ra else f"- ({rb}/{ra})"
        line = f"| {name} | {sum(x['hit'] for x in a)}/{len(ks)} | {sum(y['hit'] for y in b)}/{len(ks)} | {med} | {rr} | {fb} vs {fa} | {exc} |"
        if noisy:
            loose = [sum(r.get("best_delta", math.inf) <= LOOSE_TARGET for r in rs) for rs in (a, b)]
            best = [f"{np.median([r.get('best_delta', math.inf) for r in rs]):.2g}" for rs in (a, b)]
            pairs = [(x.get("best_delta", math.inf), y.get("best_delta", math.inf)) for x, y in zip(a, b) if not (x["hit"] and y["hit"])]
            lower = sum(fy < fx for fx, fy in pairs), sum(fx < fy for fx, fy in pairs)
            line += f" {loose[0]} / {loose[1]} | {best[0]} / {best[1]} | {lower[0]} vs {lower[1]} |"
        lines.append(line)
    return "\n".join(lines)


def _loose() -> str:
    return f"1e{round(math.log10(LOOSE_TARGET))}"


def overhead(records: list[dict], arms=("pycma", "mixing"), dim: int = 10) -> str:
    """Time per generation in ask + tell (the objective excluded), arm against arm, on the problems of ``dim``."""
    per = {a: [r["overhead_s"] / r["generations"] for r in records if r["arm"] == a and r["dim"] == dim and r["generations"]] for a in arms}
    if not all(per.values()):
        return ""
    a, b = (float(np.median(per[x])) * 1e3 for x in arms)
    return f"d = {dim}: median time per generation in ask + tell, {arms[1]} {b:.2f} ms, {arms[0]} {a:.2f} ms: {b / a:.2f}x"


def exceptions(records: list[dict]) -> str:
    bad = [r for r in records if r["exception"]]
    return "\n".join(f"- {r['arm']} {r['problem']}: {r['exception']}" for r in bad) or "no exception"


def stop_counts(records: list[dict], arms) -> str:
    lines = ["| stop criterion | " + " | ".join(arms) + " |", "|---|" + "---:|" * len(arms)]
    counts = {a: collections.Counter() for a in arms}
    for r in records:
        if r["arm"] in counts:
            counts[r["arm"]].update(r["stops"])
    for key in sorted(set().union(*counts.values())):
        lines.append(f"| {key} | " + " | ".join(str(counts[a][key]) for a in arms) + " |")
    return "\n".join(lines)


def cocopp_figures(out: Path, arms) -> Path:
    """cocopp's comparison of the arms' observer data into OUT/ppdata (runtime ECDFs per function group)."""
    import cocopp

    os.chdir(out)
    shutil.rmtree("ppdata", ignore_errors=True)
    cocopp.genericsettings.isConv = False
    cocopp.main("-o ppdata --no-svg " + " ".join(f"exdata/{a}" for a in arms))
    return out / "ppdata"


def restarts_per_evaluations(records: list[dict], arms) -> str:
    """Restarts per 10,000 evaluations and per 1,000 generations, and the mean run's length in generations, each arm
    over all its problems. A run that costs fewer evaluations per generation fits more generations, so more runs, in
    one budget: the raw count is read beside these. Whether pycma's stopping rules fire *sooner* with mixing is the
    per-generation figure (a run's length); the per-evaluation figure also counts the evaluations mixing saves.
    The IPOP/BIPOP arms record no generations: their per-generation part is left out."""
    parts = []
    for arm in arms:
        rs = [r for r in records if r["arm"] == arm]
        restarts, evaluations = sum(max(0, r["restarts"]) for r in rs), sum(r["evaluations"] for r in rs)
        generations, runs = sum(r["generations"] for r in rs), sum(max(0, r["restarts"]) + 1 for r in rs)
        text = f"{arm} {restarts} restarts in {evaluations:,} evaluations ({1e4 * restarts / max(1, evaluations):.2f} per 10,000"
        if generations:
            text += f"; {1e3 * restarts / generations:.2f} per 1,000 generations, runs of {generations / runs:.0f} generations on average"
        parts.append(text + ")")
    return "; ".join(parts)


#: The pairs of arms docs/adapters.md tabulates, each with what it compares.
DOC_PAIRS = (
    (("pycma", "mixing"), "pycma alone against the same ES wrapped (MixingES's defaults)"),
    (("pycma", "mixing-pop2"), "pycma alone at its default popsize against mixing at twice that popsize"),
    (("pycma-pop2", "mixing-pop2"), "both at twice pycma's default popsize"),
    (
        ("pycma", "mixing-pop3"),
        "pycma alone at its default popsize against mixing at three times that popsize (about pycma's "
        "number of fresh members per generation: the setting that reaches pycma's hits)",
    ),
    (("pycma-pop3", "mixing-pop3"), "both at three times pycma's default popsize"),
    (("pycma-ipop", "mixing-ipop"), "pycma's IPOP restarts (cma.fmin2(..., restarts=9, incpopsize=2)) against imix_cli.fmin2's"),
    (("pycma-bipop", "mixing-bipop"), "pycma's BIPOP restarts (cma.fmin2(..., restarts=9, bipop=True)) against imix_cli.fmin2's"),
    (("pycma", "mixing-cond"), 'pycma alone against mixing with variant "conditional" (MixingES(es, "conditional"))'),
    (("pycma", "mixing-cond-pop2"), 'pycma alone at its default popsize against "conditional" mixing at twice that popsize'),
    (("pycma", "mixing-tpa"), 'pycma alone against mixing with imix\'s two-point step size (PycmaES(es, step_size="tpa")): where the restarts come from'),
)
#: The arms cocopp draws (all in one figure per group).
COCOPP_ARMS = ("pycma", "mixing", "mixing-pop3")
#: cocopp's runtime ECDFs copied into the docs: every group at d = 10, all functions at each d.
DOC_FIGURES = [f"pprldmany_10D_{g}.svg" for g in ("separ", "lcond", "hcond", "multi", "mult2")] + [f"pprldmany_{d:02d}D_noiselessall.svg" for d in (2, 5, 10)]
BEGIN, END = "<!-- bbob:begin (benchmarks/bbob.py docs writes this part) -->", "<!-- bbob:end -->"
#: bbob-noisy's pairs, the arms cocopp draws and the figures copied: all functions at each d, the three groups at the
#: largest d run
NOISY_DOC_PAIRS = (
    (("pycma", "mixing"), "pycma alone against the same ES wrapped (MixingES's defaults: stored values keep their noise)"),
    (("pycma", "mixing-reeval2"), "pycma alone against mixing that re-evaluates 2 reused members per generation "
     "(MixingES(es, \"exact\", reeval_count=2)) and calibrates the others' stored values on them"),
    (("mixing", "mixing-reeval2"), "mixing without and with the re-evaluations"),
)  # fmt: skip
NOISY_COCOPP_ARMS = ("pycma", "mixing", "mixing-reeval2")
NOISY_BEGIN, NOISY_END = "<!-- bbob-noisy:begin (benchmarks/bbob.py docs --suite bbob-noisy writes this part) -->", "<!-- bbob-noisy:end -->"
#: suite -> what ``docs`` writes: the markers, the pairs tabled, cocopp's arms, the figures, the make target
DOCS = {
    "bbob": {"begin": BEGIN, "end": END, "pairs": DOC_PAIRS, "cocopp": COCOPP_ARMS, "figures": lambda dims: DOC_FIGURES,
             "make": "make bbob", "run": "benchmarks/bbob.py run", "where": "two processes on two cores"},
    "bbob-noisy": {"begin": NOISY_BEGIN, "end": NOISY_END, "pairs": NOISY_DOC_PAIRS, "cocopp": NOISY_COCOPP_ARMS,
                   "figures": lambda dims: [f"pprldmany_{max(dims):02d}D_{g}.svg" for g in ("nzmod", "nzsev", "nzsmm")]
                   + [f"pprldmany_{d:02d}D_nzall.svg" for d in sorted(dims)],
                   "make": "make bbob-noisy", "run": "benchmarks/bbob.py run --suite bbob-noisy", "where": "one process, the machine shared"},
}  # fmt: skip


def docs(out: Path, arms, page: Path, figures: Path, suite: str = "bbob") -> None:
    """The section of docs/adapters.md between the suite's markers (BEGIN and END for bbob, NOISY_BEGIN and NOISY_END
    for bbob-noisy), and cocopp's figures into ``figures``."""
    spec = DOCS[suite]
    groups = SUITES[suite]["groups"]
    records = load(out)
    meta = json.loads((out / "meta.json").read_text()) if (out / "meta.json").exists() else {}
    have = {r["arm"] for r in records}
    dims = sorted({r["dim"] for r in records})
    lines = [spec["begin"], ""]
    commits = meta.get("commits", {})
    scope = "" if suite == "bbob" else f", d = {', '.join(map(str, dims))}, {len({r['problem'] for r in records})} problems"  # no "; ": the mark's separator

    def mark(*pair):
        commit = next((commits[a] for a in pair[::-1] if a in commits), "0000000")
        return (f"<!-- provenance: commit={commit}; date={meta.get('date', '?')}; what={spec['make']} ({spec['run']} --arms "
                f"{','.join(pair)}{scope}); machine={meta.get('machine', '?')} -->")  # fmt: skip

    lines.append(f"{len({r['problem'] for r in records})} problems, {len(records)} runs, `{spec['make']}`.")
    for (a, b), what in spec["pairs"]:
        if a in have and b in have:
            lines += ["", f"**{b} against {a}**{mark(a, b)}: {what}.", "", table(records, (a, b), groups)]
    lines += ["", "Restarts per evaluation: " + restarts_per_evaluations(records, [a for a in arms if a in have]) + "."]
    for dim in (2, 5, 10):
        line = overhead(records, ("pycma", "mixing"), dim)
        if line:
            lines.append(f"Overhead, {line} (measured inside the runs, {spec['where']}).")
    lines += ["", "Stops by criterion (every run of every problem):", "", stop_counts(records, [a for a in arms if a in have]), ""]
    lines += [f"Exceptions: {exceptions(records)}.", ""]
    try:
        pp = cocopp_figures(out, [a for a in spec["cocopp"] if a in have])
    except Exception as err:  # noqa: BLE001 (the tables stand without the figures)
        lines += [f"cocopp failed: {type(err).__name__}: {err}", ""]
    else:
        folder = next(p for p in pp.iterdir() if p.is_dir())
        figures.mkdir(parents=True, exist_ok=True)
        shown = []
        for name in spec["figures"](dims):
            if (folder / name).exists():
                shutil.copy(folder / name, figures / name)
                shown.append(name)
        rel = os.path.relpath(figures, page.parent)
        lines += ["cocopp's runtime ECDFs (the fraction of (problem, target) pairs solved against evaluations / d; "
                  f"arms {', '.join(a for a in spec['cocopp'] if a in have)}):", ""]  # fmt: skip
        lines += [f"![{name}]({rel}/{name})" for name in shown] + [""]
    lines.append(spec["end"])
    text = page.read_text()
    if spec["begin"] not in text or spec["end"] not in text:
        raise SystemExit(f"{page}: no section between {spec['begin']} and {spec['end']}")
    head, _, rest = text.partition(spec["begin"])
    _, _, tail = rest.partition(spec["end"])
    page.write_text(head + "\n".join(lines) + tail)


def neutral(seeds: int = 20, generations: int = 100, dim: int = 5) -> str:
    """Why plateaus and multimodal functions lose under mixing: sigma under neutral selection.

    With no information in the values -- all equal (a plateau: ranks by the order told) or independent uniform
    draws (a rugged function seen at a small scale) -- CSA's sigma should do a random walk: its path is built from
    steps that random selection leaves N(0, I). The mean of log sigma after ``generations`` generations, pycma
    alone, wrapped with its CSA (the adapter's default) and wrapped with imix's TPA (``PycmaES(step_size="tpa")``).
    A reused member keeps its value: one that ranked well ranks well again, the mean does not move, CSA reads the
    short path as convergence and shrinks sigma -- reuse makes CMA-ES partly elitist.
    """
    import cma

    import imix_cli
    from imix_cli.core.adapters.pycma import PycmaES

    warnings.simplefilter("ignore")
    rows = ["| values | pycma alone | mixing, pycma's CSA (default) | mixing, imix's TPA |", "|---|---:|---:|---:|"]
    for label in ("all equal", "independent uniform"):
        cells = []
        for arm in ("alone", "pycma", "tpa"):
            logs = []
            for seed in range(seeds):
                options = {"seed": seed + 1, "verbose": -9, "tolflatfitness": 1e9, "tolfun": 0, "tolfunhist": 0, "tolstagnation": 0}
                es = cma.CMAEvolutionStrategy(np.zeros(dim), 1.0, options)
                m = es if arm == "alone" else imix_cli.MixingES(PycmaES(es, step_size=arm), "exact", rng=seed)
                values = np.random.default_rng(seed)
                for _ in range(generations):
                    x = m.ask()
                    m.tell(x, np.ones(len(x)) if label == "all equal" else values.random(len(x)))
                logs.append(math.log(es.sigma))
            cells.append(f"{np.mean(logs):+.2f} ± {np.std(logs, ddof=1) / math.sqrt(seeds):.2f}")
        rows.append(f"| {label} | " + " | ".join(cells) + " |")
    return f"mean log sigma after {generations} generations (sigma0 = 1), d = {dim}, {seeds} seeds, ± its standard error:\n\n" + "\n".join(rows)


def overhead_bench(dims=(2, 5, 10), generations: int = 200, repeats: int = 12) -> str:
    """The time per generation in ask + tell (the objective excluded), pycma alone against wrapped, measured in turn
    in this process: ``repeats`` pairs, each a run of pycma alone and one wrapped (the order alternating), on pycma's
    rotated ellipsoid (cma.ff.elli after a fixed rotation), x0 = 1, sigma0 = 0.5, default popsize. The ratio is the
    median of the pairs' ratios (with its quartiles): a pair runs under the same load, so it holds on a shared
    machine where absolute times drift. Times are the process's CPU time (waiting for a core is not counted);
    per generation and per evaluation (mixing evaluates fewer). The first pair warms the compiled kernels up."""
    import cma

    import imix_cli

    warnings.simplefilter("ignore")
    clock = time.process_time
    rows = ["| d | pycma alone, ms per generation | wrapped | ratio [quartiles] | ratio per evaluation |", "|---:|---:|---:|---:|---:|"]
    for dim in dims:
        q, _ = np.linalg.qr(np.random.default_rng(dim).standard_normal((dim, dim)))
        per = {"alone": [], "mixing": []}
        per_eval = {"alone": [], "mixing": []}
        for rep in range(repeats + 1):
            for arm in ("alone", "mixing") if rep % 2 else ("mixing", "alone"):
                es = cma.CMAEvolutionStrategy(np.ones(dim), 0.5, {"seed": rep + 1, "verbose": -9, "tolx": 0, "tolfun": 0, "tolfunhist": 0})
                m = es if arm == "alone" else imix_cli.MixingES(es, "exact", rng=rep)
                spent, evaluations = 0.0, 0
                for _ in range(generations):
                    t0 = clock()
                    x = m.ask()
                    t1 = clock()
                    f = [cma.ff.elli(q @ xi) for xi in x]
                    t2 = clock()
                    m.tell(x, f)
                    spent += (t1 - t0) + (clock() - t2)
                    evaluations += len(x)
                if rep:  # rep 0 warms up
                    per[arm].append(spent / generations)
                    per_eval[arm].append(spent / evaluations)
        ratio = np.array(per["mixing"]) / np.array(per["alone"])
        ratio_eval = np.array(per_eval["mixing"]) / np.array(per_eval["alone"])
        a, b = (float(np.median(per[k])) * 1e3 for k in ("alone", "mixing"))
        lo, med, hi = np.quantile(ratio, [0.25, 0.5, 0.75])
        rows.append(f"| {dim} | {a:.3f} | {b:.3f} | {med:.2f} [{lo:.2f}, {hi:.2f}] | {np.median(ratio_eval):.2f} |")
    return "\n".join(rows)


def _meta(out: Path, arms) -> None:
    """OUT/meta.json: the date and machine of the first run, and the commit each arm was run at (its provenance)."""
    import platform
    import subprocess

    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "?"
    cpu = (
        next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("model name")), platform.machine())
        if Path("/proc/cpuinfo").exists()
        else platform.machine()
    )
    if Path("/proc/cpuinfo").exists() and " hypervisor" in Path("/proc/cpuinfo").read_text():
        cpu += " VM"
    if hasattr(os, "getloadavg") and os.getloadavg()[0] >= 1:  # other processes were running when this one started
        cpu += ", shared"
    path = out / "meta.json"
    meta = json.loads(path.read_text()) if path.exists() else {"date": time.strftime("%Y-%m-%d"), "machine": f"{os.cpu_count()}-core {cpu}"}
    commits = meta.setdefault("commits", {})
    for arm in arms:
        commits.setdefault(arm, commit)
    path.write_text(json.dumps(meta))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("section", choices=["run", "table", "cocopp", "docs", "neutral", "overhead"])
    parser.add_argument("--page", type=Path, default=Path("docs/adapters.md"), help="docs: the page whose bbob section is rewritten")
    parser.add_argument("--figures", type=Path, default=Path("docs/bbob"), help="docs: where cocopp's figures go")
    parser.add_argument("--suite", choices=list(SUITES), default="bbob", help="COCO's suite (bbob-noisy: functions 101-130)")
    parser.add_argument("--out", type=Path, default=None, help="default results/<suite>")
    parser.add_argument("--functions", default=None, help="default: the suite's (bbob 1-24, bbob-noisy 101-130)")
    parser.add_argument("--dims", default="2,5,10")
    parser.add_argument("--instances", default="1-3")
    parser.add_argument("--arms", default="pycma,mixing", help="of " + ", ".join(ARMS) + "; table: the first two are compared")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--budget-per-dim", type=int, default=BUDGET_PER_DIM)
    parser.add_argument("--repeats", type=int, default=12, help="overhead: pairs of runs (pycma alone, wrapped) per dimension")
    args = parser.parse_args(argv)

    def ints(text, flag="--functions"):
        out = []
        for part in text.split(","):
            lo, _, hi = part.partition("-")
            try:
                out += list(range(int(lo), int(hi or lo) + 1))
            except ValueError:
                parser.error(f"{flag} {text!r}: integers and ranges, e.g. 1-3,5")
        return out

    arms = args.arms.split(",")
    unknown = [a for a in arms if a not in ARMS]
    if unknown:
        parser.error(f"unknown arm {unknown[0]!r}; valid: {', '.join(ARMS)}")
    spec = SUITES[args.suite]
    out = (args.out or Path(spec["out"])).resolve()
    functions = ints(args.functions or spec["functions"])
    if args.section == "run":
        valid = set(ints(spec["functions"]))
        if not set(functions) <= valid:
            parser.error(f"--functions {args.functions}: {args.suite}'s functions are {spec['functions']}")
        dims, instances = ints(args.dims, "--dims"), ints(args.instances, "--instances")
        missing = missing_problem(args.suite, _todo(functions, dims, instances))
        if missing:
            parser.error(f"--dims {args.dims} --instances {args.instances}: {missing}")
        out.mkdir(parents=True, exist_ok=True)
        _meta(out, arms)
        run(out, functions, dims, instances, arms, args.workers, args.budget_per_dim, args.suite)
    elif args.section == "table":
        records = load(out)
        print(table(records, arms[:2], spec["groups"]))
        print()
        print(paired_hits(records, arms[:2], spec["groups"]))
        print()
        for dim in (2, 5, 10):
            line = overhead(records, arms[:2], dim)
            if line:
                print(f"- {line}")
        print()
        print(stop_counts(records, arms))
        print()
        print(exceptions(records))
    elif args.section == "overhead":
        print(overhead_bench(tuple(ints(args.dims)), repeats=args.repeats))
    elif args.section == "neutral":
        print(neutral())
    elif args.section == "docs":
        docs(out, arms, args.page.resolve(), args.figures.resolve(), args.suite)
    else:
        print(cocopp_figures(out, arms))
    return 0


if __name__ == "__main__":
    sys.exit(main())
