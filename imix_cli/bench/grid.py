"""``imix bench grid``: the paper's main grid, without mixing and with EIM, through :func:`imix_cli.running.runner.run`."""

from __future__ import annotations

import tempfile

from imix_cli.bench.common import cpu_seconds, table
from imix_cli.core.registry import MAIN_GRID_ENVS, PAPER_ES_NAMES

PAPER_GRID = [f"algo={','.join(PAPER_ES_NAMES)}", f"env={','.join(MAIN_GRID_ENVS)}"]  # as `make reproduce` (estool weight decay: the default)


def grid_rows(seeds: int | None, generations: int | None, algos, envs, extra: list[str], echo=None) -> list[dict]:
    """The paper's main grid, without mixing and with EIM, through imix_cli.running.runner.run."""
    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.runner import run

    rows = []
    with tempfile.TemporaryDirectory(prefix="imix-bench-grid-") as tmp:
        for eim in ("false", "true"):
            overrides = [f"algo={','.join(algos)}", f"env={','.join(envs)}", f"eim={eim}", *extra,
                         "progress=false", f"results_dir={tmp}", "experiment=grid"]  # fmt: skip
            if seeds is not None:
                overrides.append(f"seeds={seeds}")
            if generations is not None:
                overrides.append(f"generations={generations}")
            for spec in validate_overrides(overrides):
                before = cpu_seconds()
                summary = run(spec, echo=lambda *_: None)
                cpu = cpu_seconds() - before
                row = {"run": spec.run_name, "mixing": spec.mixing, "seeds": spec.seeds, "generations": spec.generations,
                       "wall": summary["wall_time"], "env_steps": summary["env_steps"],
                       "evaluations": summary["evaluations"], "final": summary["final_mean_score"], "cpu": cpu}  # fmt: skip
                rows.append(row)
                if echo:
                    echo(f"  {row['run']}: {row['wall']:.1f} s ({row['cpu']:.1f} s CPU), {row['env_steps']:,} env steps")
    return rows


def format_grid(rows: list[dict]) -> str:
    body = [[r["run"], r["seeds"], r["generations"], f"{r['wall']:.1f}", f"{r['cpu']:.1f}", f"{r['env_steps']:,}",
             f"{r['evaluations']:,}", f"{r['final']:.1f}"] for r in rows]  # fmt: skip
    groups = [(f"**total, mixing={m}**", [r for r in rows if r["mixing"] == m]) for m in ("none", "eim")]
    for label, sel in [*groups, ("**grid total**", rows)]:
        if sel:
            body.append([label, "", "", f"**{sum(r['wall'] for r in sel):.1f}**", f"{sum(r['cpu'] for r in sel):.1f}",
                         f"**{sum(r['env_steps'] for r in sel):,}**", f"{sum(r['evaluations'] for r in sel):,}", ""])  # fmt: skip
    header = ["run", "seeds", "generations", "wall (s)", "CPU (s)", "env steps", "evaluations", "final mean score"]
    return table(header, body, "lrrrrrrr")
