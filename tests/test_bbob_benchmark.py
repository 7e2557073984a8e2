"""The bbob benchmark (benchmarks/bbob.py, `make bbob`): its protocol on a few problems, end to end.

What `make bbob` publishes in docs/adapters.md comes from these commands: `run` (COCO's suite and observer, pycma
alone, wrapped, and pycma's IPOP restarts with imix_cli.fmin2), `table` and `docs` (cocopp's figures and the page's
section between its markers). Here on bbob f1 and f7 (the step ellipsoid whose plateaus the adapter's tie order is
for), d = 2, instance 1, with a budget of 300 d evaluations.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.bbob, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "bbob.py"


def _bbob(*args, cwd):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}  # this tree's imix_cli, not only the installed copy
    return subprocess.run([sys.executable, str(SCRIPT), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=900)


def test_the_bbob_protocol_runs_every_arm_and_writes_cocos_data_the_table_and_the_page(tmp_path):
    out = tmp_path / "bbob"
    arms = "pycma,mixing,pycma-ipop,mixing-ipop"
    done = _bbob("run", "--out", str(out), "--functions", "1,7", "--dims", "2", "--instances", "1", "--arms", arms,
                 "--workers", "1", "--budget-per-dim", "300", cwd=tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    records = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    assert sorted((r["function"], r["arm"]) for r in records) == sorted((f, a) for f in (1, 7) for a in arms.split(","))
    for r in records:
        assert r["exception"] is None, r
        assert r["evaluations"] <= 300 * 2 + 50, r  # the budget, plus at most the generation that crossed it
    sphere = {r["arm"]: r for r in records if r["function"] == 1}
    assert all(sphere[a]["hit"] for a in sphere), sphere
    assert sphere["mixing"]["runtime"] < sphere["pycma"]["runtime"], sphere  # the sphere: mixing saves evaluations
    assert list((out / "exdata" / "mixing").rglob("*.info")), "COCO's observer data for cocopp"
    again = _bbob("run", "--out", str(out), "--functions", "1,7", "--dims", "2", "--instances", "1", "--arms", arms, cwd=tmp_path)
    assert again.returncode == 0 and "done" in again.stderr, again.stderr  # finished problems are skipped
    table = _bbob("table", "--out", str(out), "--arms", "pycma,mixing", cwd=tmp_path)
    assert table.returncode == 0 and "| separable f1-5 | 1/1 | 1/1 |" in table.stdout, table.stdout + table.stderr
    page = tmp_path / "page.md"
    page.write_text("before\n<!-- bbob:begin (benchmarks/bbob.py docs writes this part) -->\nold\n<!-- bbob:end -->\nafter\n")
    made = _bbob("docs", "--out", str(out), "--arms", arms, "--page", str(page), "--figures", str(tmp_path / "figures"), cwd=tmp_path)
    assert made.returncode == 0, made.stderr[-2000:]
    text = page.read_text()
    assert text.startswith("before\n") and text.endswith("after\n") and "old" not in text
    assert "**mixing against pycma**" in text and "**mixing-ipop against pycma-ipop**" in text
    assert list((tmp_path / "figures").glob("pprldmany_02D_noiselessall.svg")), text


def test_the_bbob_noisy_suite_runs_the_three_arms_hits_on_the_noise_free_value_and_tables_cocos_groups(tmp_path):
    """`make bbob-noisy`'s commands on bbob-noisy f101 (sphere, moderate Gaussian noise) and f122 (Schaffer F7, severe
    noise, multimodal), d = 2, instance 1, 300 d evaluations: COCO's noisy suite and observer, a hit read off the
    observer's noise-free best f - f_opt (the noisy value never comes within 1e-8: it carries + 1.01e-8), cocopp's
    groups in the table, the page's own section."""
    out = tmp_path / "noisy"
    arms = "pycma,mixing,mixing-reeval2"
    done = _bbob("run", "--suite", "bbob-noisy", "--out", str(out), "--functions", "101,122", "--dims", "2", "--instances", "1",
                 "--arms", arms, "--workers", "1", "--budget-per-dim", "300", cwd=tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    records = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    assert sorted((r["function"], r["arm"]) for r in records) == sorted((f, a) for f in (101, 122) for a in arms.split(","))
    for r in records:
        assert r["exception"] is None, r
        assert r["problem"].startswith("bbob_noisy_f"), r  # the noisy suite's problems, not bbob's
        assert r["evaluations"] <= 300 * 2 + 50, r
        assert r["hit"] == (r["best_delta"] <= 1e-8), r  # the hit is the observer's noise-free value
    sphere = {r["arm"]: r for r in records if r["function"] == 101}
    assert sphere["pycma"]["hit"] and sphere["mixing"]["hit"], sphere  # problem.final_target_hit never fires here: the observer's value does
    for arm, r in ((a, r) for a, r in sphere.items() if r["hit"]):  # the runtime is the evaluation the observer logged first at <= 1e-8
        (dat,) = (out / "exdata" / arm).rglob("bbobexp_f101_DIM2.dat")
        rows = [line.split() for line in dat.read_text().splitlines() if not line.startswith("%")]
        assert r["runtime"] == next(int(row[0]) for row in rows if float(row[2]) <= 1e-8), (arm, r)
    (info,) = (out / "exdata" / "mixing-reeval2").rglob("bbobexp_f101.info")
    assert "suite = 'bbob-noisy'" in info.read_text() and "logger = 'bbob-noisy'" in info.read_text()
    table = _bbob("table", "--suite", "bbob-noisy", "--out", str(out), "--arms", "pycma,mixing", cwd=tmp_path)
    assert table.returncode == 0, table.stderr[-2000:]
    rows = {line.split("|")[1].strip(): line for line in table.stdout.splitlines() if line.startswith("| ")}
    assert "| moderate noise f101-106 | 1/1 | 1/1 |" in table.stdout, table.stdout
    assert "severe noise multimodal f122-130" in rows and "severe noise f107-121" not in rows, table.stdout  # cocopp's groups
    assert "hits at 1e-2 pycma / mixing" in table.stdout, table.stdout
    page = tmp_path / "page.md"
    page.write_text("before\n<!-- bbob:begin (benchmarks/bbob.py docs writes this part) -->\nbbob's\n<!-- bbob:end -->\n"
                    "<!-- bbob-noisy:begin (benchmarks/bbob.py docs --suite bbob-noisy writes this part) -->\nold\n"
                    "<!-- bbob-noisy:end -->\nafter\n")  # fmt: skip
    made = _bbob("docs", "--suite", "bbob-noisy", "--out", str(out), "--arms", arms, "--page", str(page), "--figures", str(tmp_path / "figures"),
                 cwd=tmp_path)  # fmt: skip
    assert made.returncode == 0, made.stderr[-2000:]
    text = page.read_text()
    assert text.startswith("before\n") and text.endswith("after\n") and "old" not in text and "bbob's" in text  # its own section only
    assert "**mixing against pycma**" in text and "**mixing-reeval2 against pycma**" in text and "make bbob-noisy" in text, text
    assert "<!-- provenance: commit=" in text and "what=make bbob-noisy (benchmarks/bbob.py run --suite bbob-noisy" in text, text
    assert list((tmp_path / "figures").glob("pprldmany_02D_nzall.svg")), text
    from imix_cli.commands.docs_numbers import _FIELDS, _MARK  # the marks parse as docs/results.md reads them

    for mark in _MARK.finditer(text):
        fields = dict(part.strip().split("=", 1) for part in mark.group(1).split("; ") if "=" in part)
        assert set(fields) <= set(_FIELDS) and {"commit", "what"} <= set(fields), mark.group(0)


def test_the_paired_sign_test_counts_problems_hit_by_one_arm_only():
    """`table`'s sign test: only the problems one arm hit and the other missed count. Made to fail: counting every
    problem an arm hit (discordant or not) gives 10 against 17 on the multimodal row and p 0.25, not 0 against 7 and 0.02."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("bbob_benchmark", SCRIPT)
    bbob = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bbob)
    records = []
    for i in range(45):  # f15-19: 10 hit by both, 7 by pycma only, 28 by neither
        problem, function = f"p{i}", 15 + i % 5
        records.append({"arm": "pycma", "problem": problem, "function": function, "hit": i < 17})
        records.append({"arm": "mixing", "problem": problem, "function": function, "hit": i < 10})
    text = bbob.paired_hits(records, ("pycma", "mixing"))
    assert "| multimodal f15-19 | 0 | 7 | 0.02 |" in text, text
    assert "| all | 0 | 7 | 0.02 |" in text and "separable" not in text, text  # no row for a group not run


def test_instances_outside_cocos_default_set_run_and_a_problem_coco_lacks_is_one_line(tmp_path):
    """The benchmark is run on instances it was not tuned on: COCO's default bbob suite holds only its year's instances
    (no instance 6), and ``run --instances 4-6`` once died in a worker with cocoex's traceback. The suite is now built
    with the instances and dimensions asked for (instances 1-3 give the same records as before: the problem is its id).
    Made to fail by building the suite with COCO's defaults again: instance 6 is then a traceback, exit 1."""
    out = tmp_path / "bbob"
    done = _bbob("run", "--out", str(out), "--functions", "1", "--dims", "2", "--instances", "6", "--arms", "pycma",
                 "--workers", "1", "--budget-per-dim", "300", cwd=tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    (record,) = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    assert record["problem"] == "bbob_f001_i06_d02" and record["hit"] and record["exception"] is None, record
    refused = _bbob("run", "--out", str(out), "--functions", "1", "--dims", "7", "--instances", "1", cwd=tmp_path)
    lines = refused.stderr.strip().splitlines()
    assert refused.returncode == 2 and "Traceback" not in refused.stderr, refused.stderr
    assert "bbob has no problem f1 d=7 instance 1" in lines[-1], lines
