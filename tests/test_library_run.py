"""``imix_cli.run`` as a user calls it: at a script's top level, from a notebook-like main, after the command
line's main job, and with keyword values that look like override syntax."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

import imix_cli
from imix_cli.commands.cli import main
from imix_cli.experiment import DEFAULT_EXPERIMENT, Experiment
from imix_cli.running.files.results import read_run_csv

SMALL = {"algo": "cem", "env": "cartpole", "seeds": 2, "generations": 3, "popsize": 8, "eval_mean_every": 0}

# No `if __name__ == "__main__":`, as the README's line is written. Every execution of the top level leaves a
# line in `ran.txt`: a worker that re-ran the script would add one (and, before the fix, found the folder locked).
SCRIPT = """\
import imix_cli
with open({ran!r}, "a") as fh:
    fh.write("top level\\n")
df = imix_cli.run(algo="cem", env="cartpole", seeds=2, generations=3, popsize=8, eval_mean_every=0, workers=2, results_dir={results!r}, echo=None)
print(len(df), sorted(map(int, df["seed"].unique())))
"""


def _python(args, tmp_path, stdin=None):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parent.parent), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, *args], input=stdin, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=env)


@pytest.mark.parametrize("how", ["python script.py", pytest.param("python - (no __file__, as a notebook)", marks=pytest.mark.slow)])
def test_run_at_a_scripts_top_level_with_two_workers_runs_the_script_once(tmp_path, how):
    code = SCRIPT.format(ran=str(tmp_path / "ran.txt"), results=str(tmp_path / "results"))
    if how.startswith("python script.py"):
        (tmp_path / "script.py").write_text(code)
        proc = _python(["script.py"], tmp_path)
    else:
        proc = _python(["-"], tmp_path, stdin=code)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "6 [0, 1]", proc.stdout
    assert (tmp_path / "ran.txt").read_text() == "top level\n"  # the workers did not re-run it
    assert "Traceback" not in proc.stderr and "in use" not in proc.stderr, proc.stderr
    assert len(list((tmp_path / "results" / DEFAULT_EXPERIMENT).glob("*/seed_*.csv"))) == 2


def test_the_library_default_experiment_is_not_the_command_lines(tmp_path, capsys):
    """`imix run`'s main job in results/default/ (more generations) must not make a later library call, with
    fewer generations and no experiment=, refuse to shorten it."""
    common = [f"{k}={v}" for k, v in SMALL.items()] + ["workers=1", "progress=false", f"results_dir={tmp_path}"]
    assert main(["run", *common[:-3], "generations=5", *common[-2:]]) == 0
    frame = imix_cli.run(**SMALL, workers=1, results_dir=str(tmp_path), echo=None)
    assert len(frame) == 2 * 3
    assert len(read_run_csv(tmp_path / "default" / "cem-cartpole-none-popsize=8" / "seed_0.csv")) == 5  # the CLI's, untouched
    assert len(read_run_csv(tmp_path / DEFAULT_EXPERIMENT / "cem-cartpole-none-popsize=8" / "seed_0.csv")) == 3


def test_keyword_values_are_values_not_override_syntax(tmp_path):
    # a comma is not a sweep: one experiment, named as given
    (spec,) = Experiment(**SMALL, results_dir=str(tmp_path), experiment="lib,evil").specs
    assert spec.experiment == "lib,evil"
    # an interpolation is text, not resolved
    home = "${oc.env:HOME}"
    (spec,) = Experiment(**SMALL, results_dir=str(tmp_path), experiment=home).specs
    assert spec.experiment == home and spec.run_dir.parent.name == home
    with pytest.raises(imix_cli.ConfigError, match=r"experiment='a\\\\\$\{x\}': must be a plain folder name"):  # as given, backslash kept
        Experiment(**SMALL, results_dir=str(tmp_path), experiment="a\\${x}")
    # a sweep or a grammar function in a value is refused by the key's own check, never expanded
    for value in ("10,25", "range(8,10)"):
        with pytest.raises(imix_cli.ConfigError, match="popsize"):
            Experiment(**{**SMALL, "popsize": value}, results_dir=str(tmp_path))
    with pytest.raises(imix_cli.ConfigError, match="unknown algo"):
        Experiment(**{**SMALL, "algo": "cem,snes"}, results_dir=str(tmp_path))
    with pytest.raises(imix_cli.ConfigError, match="unknown key 'seeds=1,2'"):
        Experiment(**SMALL, results_dir=str(tmp_path), **{"seeds=1,2": 3})
    # positional strings keep the command line's syntax, sweeps included
    assert len(Experiment("popsize=8,10", **{k: v for k, v in SMALL.items() if k != "popsize"}, results_dir=str(tmp_path)).specs) == 2


# Runs a page's python block as a notebook would show it: the value of each top-level expression, in order.
NOTEBOOK = """\
import ast, sys
tree = ast.parse(sys.stdin.read())
namespace, shown = {}, []
for node in tree.body:
    if isinstance(node, ast.Expr):
        shown.append(repr(eval(compile(ast.Expression(node.value), "<page>", "eval"), namespace)))
    else:
        exec(compile(ast.Module([node], []), "<page>", "exec"), namespace)
print("=== shown ===")
print("\\n\\n".join(shown))
"""


def test_the_library_pages_example_shows_what_it_gives_and_no_column_of_nans(tmp_path):
    """docs/library.md's `imix_cli.run` example, run as written in a fresh folder: what its expressions give is the
    output the page shows, and none of it is NaN (the page's old example, mean_policy_score per generation, was
    NaN in 9 rows of 10: theta is measured every eval_mean_every generations). Made to fail: the old example
    (issue 48, friction 7) gave 45 NaN of 50 rows."""
    import re

    page = (Path(__file__).resolve().parent.parent / "docs" / "library.md").read_text()
    section = page.split("## Running an experiment from Python", 1)[1]
    code, shown = re.search(r"```python\n(.*?)```.*?```text\n(.*?)```", section, re.S).groups()
    proc = _python(["-c", NOTEBOOK], tmp_path, stdin=code)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = proc.stdout.split("=== shown ===\n", 1)[1]

    def lines(text):
        return [line.rstrip() for line in text.strip().splitlines()]

    assert "NaN" not in got and "nan" not in got, got
    assert lines(got) == lines(shown), got
