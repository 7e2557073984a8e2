"""The table printed at the end of ``imix run``: this run and its siblings with other mixing settings."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imix_cli.core.stats import mean_ci
from imix_cli.running.config.run_spec import differing_keys, identity_of
from imix_cli.running.files.results import CorruptResultError, read_run_csv, seed_csv_path, seed_summary
from imix_cli.running.files.safe_yaml import load_yaml_file
from imix_cli.running.files.tracking import flat_keys
from imix_cli.running.trainers import trainer_for

#: Config keys that only say how (and whether) mixing is done: runs that differ in these alone are
#: "the same config with and without mixing", compared in the summary.
MIXING_KEYS = ("im", "eim", "im_variant", "im_alpha", "eim_generations", "min_fresh", "mixing")


def prepare_summary() -> None:
    """Import what :func:`summarize` needs beyond what a run has imported: scipy.special, for the CI
    (:func:`imix_cli.core.stats.mean_ci`), ~0.2 s. Why apart: the runner calls it while the last worker
    finishes its seeds, rather than after every worker is done."""
    import scipy.special  # noqa: F401


def summarize(spec, run_dir: Path | None = None, known: dict | None = None) -> dict:
    """Final mean score +- 68 % CI over seeds, evaluations and env steps (total over seeds and per
    seed), reuse %, non-finite returns -- of ``spec``'s run folder, or of ``run_dir`` (a sibling).

    ``known``: seed -> :func:`imix_cli.running.files.results.seed_summary` of the seeds just run, whose CSVs
    need not be read back; the other seeds' CSVs are read."""
    run_dir = spec.run_dir if run_dir is None else Path(run_dir)
    known = {} if known is None or run_dir != spec.run_dir else known
    if run_dir != spec.run_dir:  # a sibling: whatever seeds it has finished
        paths = sorted(run_dir.glob("seed_*[0-9].csv"))
        seeds = [None] * len(paths)
    else:
        seeds = list(range(spec.seeds))
        paths = [seed_csv_path(run_dir, seed) for seed in seeds]
    per_seed = [known[seed] if seed in known else seed_summary(read_run_csv(path)) for seed, path in zip(seeds, paths)]
    mean, half_width, _ = mean_ci([s["final"] for s in per_seed], level=0.68)
    thetas = [s.get("theta", float("nan")) for s in per_seed]
    thetas = [t for t in thetas if np.isfinite(t)]
    theta, theta_half, _ = mean_ci(thetas, level=0.68) if thetas else (float("nan"), float("nan"), 0)
    evaluations, env_steps = sum(s["evaluations"] for s in per_seed), sum(s["env_steps"] for s in per_seed)
    reused, members = sum(s["reused"] for s in per_seed), sum(s["members"] for s in per_seed)
    n = max(len(paths), 1)
    return {
        "run": run_dir.name,
        "mixing": per_seed[-1]["mixing"] if per_seed else spec.mixing,
        "seeds": len(paths),
        "final_mean_score": mean,
        "ci68": half_width,
        "theta_mean_score": theta,  # the distribution mean on fresh episodes (no reused returns), mean over seeds
        "theta_ci68": theta_half,
        "evaluations": evaluations,  # total over seeds
        "evaluations_per_seed": evaluations / n,
        "env_steps": env_steps,  # total over seeds
        "env_steps_per_seed": env_steps / n,
        "reuse_percent": 100.0 * reused / members if members else 0.0,
        "stalled_generations": sum(s.get("stalled", 0) for s in per_seed),  # no member evaluated (total over seeds)
        "nonfinite_returns": sum(s["nonfinite"] for s in per_seed),
        "diverged_seeds": sum(s["diverged"] for s in per_seed),
    }


def counterpart_runs(spec) -> list[Path]:
    """Sibling run folders of the same experiment holding the same config with other mixing settings
    (and at least one finished seed), e.g. the ``-none`` run of an ``-eim`` run."""

    mine = {k: v for k, v in spec.identity().items() if k not in MIXING_KEYS}
    found = []
    for other in sorted(spec.run_dir.parent.iterdir()):
        if other == spec.run_dir or not (other / "config.yaml").is_file() or not any(other.glob("seed_*[0-9].csv")):
            continue
        try:
            config = load_yaml_file(other / "config.yaml")  # bounded: size, nesting, aliases expanded, tags
        except Exception:  # an unreadable sibling is simply not compared
            continue
        if isinstance(config, dict) and {k: v for k, v in identity_of(config).items() if k not in MIXING_KEYS} == mine:
            found.append(other)
    return found


def _score(mean: float, half: float) -> str:
    if not np.isfinite(mean):
        return "-"
    return f"{mean:.2f}" + (f" ± {half:.2f}" if np.isfinite(half) else "")


#: The footnote of every summary table: which score is free of reused returns.
SCORES_NOTE = (
    "θ fresh: distribution mean on fresh episodes (free of reused returns; the measure to compare runs by); "
    "population: last generation's mean return (reused members with stored returns); "
    "no-fresh: generations in which every member was reused (all seeds)"
)


def format_table(rows: list[dict]) -> list[str]:
    """The table's header and one line per summary of :func:`summarize`."""
    width = max(32, *(len(r["run"]) for r in rows))
    header = (
        f"{'run':<{width}} {'seeds':>5} {'θ fresh (68% CI)':>20} {'population (68% CI)':>22} {'episodes/seed':>14} "
        f"{'env steps/seed':>15} {'reuse':>7} {'no-fresh':>8} {'non-finite':>10} {'diverged':>8}"
    )
    lines = [header]
    for r in rows:
        theta = _score(r.get("theta_mean_score", float("nan")), r.get("theta_ci68", float("nan")))
        lines.append(
            f"{r['run']:<{width}} {r['seeds']:>5} {theta:>20} {_score(r['final_mean_score'], r['ci68']):>22} {r['evaluations_per_seed']:>14,.0f} "
            f"{r['env_steps_per_seed']:>15,.0f} {r['reuse_percent']:>6.1f}% {r.get('stalled_generations', 0):>8} {r['nonfinite_returns']:>10} "
            f"{r['diverged_seeds']:>8}"
        )
    return lines


def format_summary(spec, s: dict) -> str:
    """The summary table: this run, then any sibling with the same config and other mixing, and the reduction."""
    rows = [s]
    for other in counterpart_runs(spec) if trainer_for(spec).compares_mixing else []:
        try:
            rows.append(summarize(spec, other))
        except CorruptResultError:
            continue
    lines = format_table(rows)
    without = [r for r in rows if r["mixing"] == "none"]
    with_mixing = [r for r in rows if r["mixing"] != "none"]
    for base in without[:1]:
        for r in with_mixing:
            if r["evaluations_per_seed"]:
                lines.append(
                    f"  {r['run']} vs {base['run']} (the same settings but the mixing): {base['evaluations_per_seed'] / r['evaluations_per_seed']:.2f}x "
                    f"fewer episodes for the same {spec.generations} generations (final θ fresh {_score(r['theta_mean_score'], float('nan'))} vs "
                    f"{_score(base['theta_mean_score'], float('nan'))}; sample efficiency to a threshold: imix plot)"
                )
    lines.append(SCORES_NOTE)
    if "seeds_run" in s:
        lines.append(f"results: {spec.run_dir}/seed_*.csv  ({s['seeds_run']} seed(s) run now, {s['wall_time']:.1f} s)")
    return "\n".join(lines)


#: RunSpec fields a sweep point's name may leave out, by the config key shown for them; the name's own
#: spelling, where it differs, in :data:`_NAMED_AS`. The algo, env and mixing are in every name.
_SHOWN_KEYS = {
    "generations": "generations", "total_steps": "total_steps", "popsize": "popsize", "sigma": "sigma", "lr": "lr",
    "weight_decay": "weight_decay", "weight_decay_form": "weight_decay_form", "im_alpha": "im_alpha", "eim_generations": "eim_generations",
    "reeval_age": "reeval_age", "reeval_prob": "reeval_prob", "reeval_count": "reeval_count", "env_max_steps": "env.max_steps",
    "hidden": "policy.hidden", "obs_norm": "policy.obs_norm", "obs_var_floor": "policy.obs_var_floor", "policy_bias": "policy.bias",
    "policy_output": "policy.output", "obs_norm_freeze": "policy.obs_norm_freeze",
}  # fmt: skip
_NAMED_AS = {"env_max_steps": "env.max_steps", "policy_bias": "bias", "policy_output": "output"}


def hidden_values(specs) -> dict[str, str]:
    """Run name -> ``key=value, ...`` of the keys whose values differ between the points of a sweep but that its name
    does not show. Why: a folder is named by the values that differ from the paper's (``snes-cartpole-none-popsize=100``),
    so the point that ran with ``popsize=50`` reads ``snes-cartpole-none``; and ``generations`` (1000 for snes, 400
    for cem) names none. Each run's config.yaml has every value; the sweep's table shows these next to the names."""
    differing = [f for f in _SHOWN_KEYS if len({repr(getattr(spec, f)) for spec in specs}) > 1]
    out = {}
    for spec in specs:
        name = spec.run_name
        shown = [f"{_SHOWN_KEYS[f]}={_value(getattr(spec, f))}" for f in differing if f"{_NAMED_AS.get(f, f)}=" not in name]
        if shown:
            out[name] = ", ".join(shown)
    return out


def _value(v) -> str:
    return str(list(v)) if isinstance(v, tuple) else str(v)


def _without_mixing(spec) -> dict:
    return {k: v for k, v in flat_keys(spec.identity()).items() if k.split(".")[0] not in MIXING_KEYS}


def mixing_pairs_note(specs) -> str | None:
    """What a sweep's runs with mixing differ in from their nearest run without it, besides the mixing: one line saying that
    the pairs differ in the mixing alone, or one line per run with mixing naming the other settings (None if the sweep
    has no run on one side). Every resolved setting is compared (config.yaml's), so a preset or a default that changes
    with the mixing is named here."""
    plain = [s for s in specs if s.mixing == "none"]
    mixed = [s for s in specs if s.mixing != "none"]
    if not plain or not mixed:
        return None
    lines = []
    for spec in mixed:
        mine = _without_mixing(spec)
        differing, twin = min(((differing_keys(mine, _without_mixing(p)), p) for p in plain), key=lambda pair: len(pair[0]))
        if differing:
            lines.append(f"{spec.run_name} vs {twin.run_name}: differ in {', '.join(differing)} besides the mixing")
    return "\n".join(lines) if lines else "with and without mixing: each pair of runs differs in the mixing alone"


def format_sweep_table(specs) -> str | None:
    """One table of every point of a sweep (``imix run -m``), printed after the last one; None for a single run.
    A run's name is followed by the values its name leaves out that differ between the points (:func:`hidden_values`).

    A point whose seeds are not all finished (a failed job of a launcher) is named, not tabled."""
    if len(specs) < 2:
        return None
    rows, missing = [], []
    for spec in specs:
        try:
            rows.append(summarize(spec))
        except (OSError, CorruptResultError):
            missing.append(spec.run_name)
    if not rows:
        return None
    hidden = hidden_values(specs)
    rows = [{**r, "run": f"{r['run']} ({hidden[r['run']]})"} if hidden.get(r["run"]) else r for r in rows]
    lines = [f"sweep: {len(rows)} run(s) of {specs[0].results_dir}/{specs[0].experiment}", *format_table(rows), SCORES_NOTE]
    pairs = mixing_pairs_note(specs)
    if pairs:
        lines.append(pairs)
    if missing:
        lines.append(f"not finished: {', '.join(missing)}")
    return "\n".join(lines)
