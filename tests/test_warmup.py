"""A first run compiles its kernels once, spread over processes, before its workers start.

With an empty numba cache (a fresh NUMBA_CACHE_DIR), ``warm_up`` compiles the run's groups in
parallel processes; a run afterwards compiles nothing (numba's compile events, counted in the
run's own process), and a second ``warm_up`` starts nothing.

Cold compiles are most of these tests' time (minutes of CPU each), so each cache is filled once,
by the thing under test, and the counter's own check (that it does see a run's compiles) costs
one kernel's compile: in a copy of the warm cache with that kernel's entries removed, the run
compiles exactly it. (A whole cold run, once per case, used to show the same.)
"""

import os
import shutil
import subprocess
import sys

import pytest

COUNT_COMPILES = """
import sys, tempfile
from numba.core import event
from imix_cli.commands.cli import main
with event.install_recorder("numba:compile") as rec:
    assert main(["run", *sys.argv[1:], "results_dir=" + tempfile.mkdtemp(), "progress=false", "workers=1"]) == 0
print(sorted({e.data["dispatcher"].py_func.__qualname__ for _, e in rec.buffer if e.is_start}))
"""

WARM_UP = """
import sys
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.warmup import _cached, compile_groups, warm_up
(spec,) = validate_overrides(sys.argv[1:])
groups = compile_groups(spec)
cold = sum(not all(_cached(e) for e in entries) for _, entries in groups)
warmed = warm_up(spec, 2)
print(cold, warmed, sum(not all(_cached(e) for e in entries) for _, entries in groups))
"""


def _python(code, args, cache_dir, **environ):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir), **environ}
    out = subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True, text=True, timeout=1800)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout.strip().splitlines()[-1]


def _without(cache, kernel: str, copy):
    """A copy of numba cache ``cache`` without the entries of the kernel named ``kernel`` (its index and code)."""
    shutil.copytree(cache, copy)
    removed = [p for p in copy.rglob(f"*.{kernel}-*") if p.suffix in (".nbi", ".nbc")]
    assert removed, f"no cache entry of {kernel} in {cache}"
    for path in removed:
        path.unlink()
    return copy


@pytest.mark.slow
@pytest.mark.install
@pytest.mark.parametrize("args", [["algo=snes", "env=cartpole", "eim=true"], ["algo=cmaes", "env=acrobot", "im=true", "popsize=10"]])
def test_after_the_warm_up_a_run_compiles_nothing(tmp_path, args):
    """In an empty cache every group is cold; the warm-up compiles each (its count says so) and leaves none cold;
    a run then compiles nothing, and a second warm-up starts nothing."""
    cache = tmp_path / "numba_cache"
    cold, warmed, still_cold = map(int, _python(WARM_UP, args, cache).split())
    assert cold >= 2 and warmed == cold and still_cold == 0  # >= 2: the mixing step's kernels and the episodes
    assert _python(COUNT_COMPILES, [*args, "seeds=2", "generations=5"], cache) == "[]"
    assert _python(WARM_UP, args, cache).split() == ["0", "0", "0"]


@pytest.mark.slow
@pytest.mark.install
def test_the_install_warm_up_covers_every_built_in_kernel(tmp_path):
    cache = tmp_path / "numba_cache"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    out = subprocess.run([sys.executable, "-m", "imix_cli.running.warmup"], env=env, capture_output=True, text=True, timeout=1800)
    assert out.returncode == 0, out.stderr[-3000:]
    for args in (
        ["algo=cem", "env=acrobot", "eim=true"],
        ["algo=openes", "env=continuous_cartpole", "im=true", "im_variant=sun2009"],
        ["algo=cmaes", "env=cartpole", "im=true"],
        ["algo=snes", "env=gym", "env.id=Pendulum-v1", "env.max_steps=20", "eim=true"],
        ["algo=ars", "env=acrobot", "eim=true"],  # ARS's compiled-loop entry (mirrored pairs), on the other env
    ):
        assert _python(COUNT_COMPILES, [*args, "seeds=1", "generations=4", "popsize=10"], cache) == "[]", args
    # the count sees a run's compiles: with one kernel's entries gone, the run compiles that kernel (and nothing it calls);
    # in the Python loop, which calls the evaluator's kernel (the compiled loop's entry holds its own copy)
    partial = _without(cache, "acrobot_seeded_episodes", tmp_path / "partial_cache")
    args = ["algo=cem", "env=acrobot", "eim=true", "seeds=1", "generations=2", "popsize=10"]
    compiled = _python(COUNT_COMPILES, args, partial, IMIX_COMPILED_LOOP="0")
    assert "'acrobot_seeded_episodes'" in compiled, compiled


def test_make_install_warms_the_package_that_the_imix_command_runs(tmp_path):
    """The install's warm-up must compile into the cache of the *installed* package: run from the
    repository, ``python -m imix_cli...`` imports the source tree instead (cwd first on sys.path), so a
    non-editable install's first run compiled everything again (a first run took 33 s against 7 s)."""
    import re
    import shlex
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    recipe = [line.strip() for line in (root / "Makefile").read_text().splitlines() if "imix_cli.running.warmup" in line and not line.strip().startswith("#")]
    assert len(recipe) == 1, recipe
    venv = Path(sys.executable).parents[1]
    command = recipe[0].split("#")[0].replace("$(VENV)", str(venv)).replace("$(PY)", str(venv / "bin" / "python"))
    where = "import imix_cli, os; print(os.path.dirname(os.path.realpath(imix_cli.__file__)))"
    command = re.sub(r"-m imix_cli\.running\.warmup", "-c " + shlex.quote(where), command)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    warmed = subprocess.run(["sh", "-c", command], cwd=root, env=env, capture_output=True, text=True, timeout=120)
    assert warmed.returncode == 0, warmed.stderr
    used = subprocess.run([sys.executable, "-c", where], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert warmed.stdout.strip() == used.stdout.strip()
