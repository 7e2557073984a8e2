"""One error boundary for every command (imix_cli.commands.boundary).

Each command (run, plot, eval, render, status, bench) is run in a process of its own and stopped the ways a
user's session stops one -- Ctrl-C (SIGINT), SIGTERM, MemoryError, its output's reader going away (EPIPE) --
and, for the commands that step envs (run, eval, render), by a user env raising in ``__init__`` or mid-episode,
returning an observation of the wrong shape, or a string reward. Each ends with one line naming what happened
and its documented exit status; never a traceback (unless asked for with ``--debug`` / ``IMIX_DEBUG=1``),
and never a half-written file.

The signals are sent by the process to itself from inside a function the command calls mid-work (the hook
below), so they land at a known point without any timing.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import covering_grid

from imix_cli.commands.cli import main

RUN = "cem-cartpole-none-popsize=6"
TINY = ["algo=cem", "env=cartpole", "seeds=2", "generations=2", "popsize=6", "progress=false", "workers=1"]

#: Replaces ``module.attr`` by a function that first does ``action`` (send itself a signal, or raise
#: MemoryError), then runs the command ``argv``.
HOOK = """
import importlib, os, signal, sys
from imix_cli.commands.cli import main

module, attr, action, *argv = sys.argv[1:]
mod = importlib.import_module(module)
real = getattr(mod, attr)


def hooked(*args, **kwargs):
    if action == "MemoryError":
        raise MemoryError()
    os.kill(os.getpid(), getattr(signal, action))
    return real(*args, **kwargs)


setattr(mod, attr, hooked)
sys.exit(main(argv))
"""


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("results")
    assert main(["run", *TINY, f"results_dir={root}", "experiment=e"]) == 0
    assert main(["plot", f"results_dir={root}", "experiment=e", "only=iqm"]) == 0
    return root


def commands(root: Path, tmp_path: Path) -> dict:
    """command -> (module, function it calls mid-work, argv)."""
    base = [f"results_dir={root}", "experiment=e"]
    return {
        "run": ("imix_cli.running.runner", "run", ["run", *TINY, f"results_dir={root}", "experiment=fresh"]),
        "plot": ("imix_cli.plotting.tables", "write_table", ["plot", *base, "only=iqm"]),
        "eval": ("imix_cli.commands.eval_command", "evaluate_policy", ["eval", *base, "episodes=2"]),
        "render": ("imix_cli.commands.render", "_image", ["render", *base, "frames=3", f"out={tmp_path / 'out.gif'}"]),
        "status": ("imix_cli.commands.status", "run_status", ["status", *base]),
        "bench": ("imix_cli.bench.cli", "mixing_rows", ["bench", "mixing", "dims=130", "repeats=1"]),
    }


def one_line(stderr: str, command: str) -> str:
    """The single line the command ended with (warnings aside); no traceback."""
    assert "Traceback" not in stderr and "Exception ignored" not in stderr, stderr
    lines = [line for line in stderr.splitlines() if line.strip() and "warning" not in line.lower() and "logger.warn" not in line]
    assert len(lines) == 1 and lines[0].startswith(f"imix {command}"), stderr
    return lines[0]


def snapshot(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()} if folder.is_dir() else {}


EXPECTED = {"SIGINT": (130, "interrupted"), "SIGTERM": (143, "terminated"), "MemoryError": (1, "out of memory")}


@pytest.mark.parametrize(("command", "action"), covering_grid(["run", "plot", "eval", "render", "status", "bench"], list(EXPECTED)))
def test_each_command_ends_in_one_line_on_sigint_sigterm_and_memoryerror(trained, tmp_path, command, action):
    root = tmp_path / "r"
    shutil.copytree(trained, root)
    module, attr, argv = commands(root, tmp_path)[command]
    figures = root / "e" / "figures"
    before = snapshot(figures)
    proc = subprocess.run([sys.executable, "-c", HOOK, module, attr, action, *argv], capture_output=True, text=True, timeout=600)
    status, word = EXPECTED[action]
    assert proc.returncode == status, proc.stderr
    assert word in one_line(proc.stderr, command)
    assert snapshot(figures) == before  # plot stopped mid-table: every file as it was, no temporary left
    assert not (tmp_path / "out.gif").exists()  # render stopped mid-GIF: no file at all, not half of one


@pytest.mark.parametrize("command", ["run", "plot", "status", *(pytest.param(c, marks=pytest.mark.slow) for c in ("eval", "render", "bench"))])
def test_a_closed_output_pipe_ends_each_command_silently_with_141(trained, tmp_path, command):
    """``imix status | head -1``: BrokenPipeError tracebacks; ``imix run ... | true``: "cannot write: Broken pipe", exit 1
    after every result was written. Now: nothing said, exit 141 (128 + SIGPIPE, as a shell reports a program SIGPIPE
    stops), and run's results are all there."""
    root = tmp_path / "r"
    shutil.copytree(trained, root)
    _, _, argv = commands(root, tmp_path)[command]
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the first line: the first write fails with EPIPE
    try:
        proc = subprocess.run([sys.executable, "-m", "imix_cli.commands.cli", *argv], stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=600)
    finally:
        os.close(write_end)
    assert proc.returncode == 141, proc.stderr
    assert "Traceback" not in proc.stderr and "Broken pipe" not in proc.stderr and "Exception ignored" not in proc.stderr, proc.stderr
    if command == "run":
        assert sorted(p.name for p in (root / "fresh" / RUN).glob("seed_*.csv")) == ["seed_0.csv", "seed_1.csv"]


# ------------------------------------------------------------------ a user env that breaks
BAD_ENV = """
import os
import numpy as np
import gymnasium as gym
from gymnasium import spaces

MODE = os.environ.get("BAD_ENV_MODE", "ok")


class Bad(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode=None):
        if MODE == "init":
            raise RuntimeError("cannot open the simulator\\nsecond line of the message")
        self.observation_space = spaces.Box(-10.0, 10.0, (2,), dtype=np.float32)
        self.action_space = spaces.Discrete(2)
        self.t = 0

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(2, dtype=np.float32), {}

    def step(self, action):
        self.t += 1
        if MODE == "step" and self.t == 3:
            raise ValueError("the physics diverged\\nsecond line of the message")
        obs = np.zeros(3 if MODE == "shape" else 2, dtype=np.float32)
        return obs, ("a lot" if MODE == "reward" else 1.0), self.t >= 10, False, {}

    def render(self):
        return np.zeros((8, 8, 3), dtype=np.uint8)


gym.register("Bad-v0", entry_point=Bad, max_episode_steps=10)
"""

#: mode -> what the one line must say (the env's first line, or the broken contract).
BAD_MODES = {"init": "cannot open the simulator", "step": "the physics diverged", "shape": "observation of shape (3,)", "reward": "'a lot'"}


@pytest.fixture(scope="module")
def bad_env(tmp_path_factory):
    """A results folder with a finished run of the user env Bad-v0 (mode ok), and the env's module folder."""
    folder = tmp_path_factory.mktemp("bad_env")
    (folder / "bad_env.py").write_text(BAD_ENV)
    root = folder / "results"
    proc = _imix(
        ["run", "env.id=bad_env:Bad-v0", "algo=cem", "seeds=1", "generations=1", "popsize=4", "progress=false", "workers=1", f"results_dir={root}"],
        folder,
        "ok",
    )
    assert proc.returncode == 0, proc.stderr
    return folder, root


def _imix(argv, folder, mode, debug=False):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(folder), os.environ.get("PYTHONPATH")])), "BAD_ENV_MODE": mode}
    env.pop("IMIX_DEBUG", None)
    if debug:
        env["IMIX_DEBUG"] = "1"
    return subprocess.run([sys.executable, "-m", "imix_cli.commands.cli", *argv], capture_output=True, text=True, env=env, cwd=folder, timeout=600)


@pytest.mark.parametrize(("command", "mode"), covering_grid(["run", "eval", "render"], list(BAD_MODES)))
def test_a_user_env_that_breaks_ends_in_one_line_naming_it(bad_env, tmp_path, command, mode):
    folder, root = bad_env
    if command == "render" and mode == "reward":
        pytest.skip("render shows frames; it does not add up rewards")
    argv = {
        "run": ["run", "env.id=bad_env:Bad-v0", "algo=cem", "seeds=1", "generations=1", "popsize=4", "progress=false", "workers=1", f"results_dir={tmp_path}"],
        "eval": ["eval", f"results_dir={root}", "import=bad_env", "episodes=2"],
        "render": ["render", f"results_dir={root}", "import=bad_env", f"out={tmp_path / 'x.gif'}"],
    }[command]
    proc = _imix(argv, folder, mode)
    assert proc.returncode == 1, proc.stderr
    line = one_line(proc.stderr, command)
    assert "Bad-v0" in line and BAD_MODES[mode] in line and "second line" not in line, line
    assert not (tmp_path / "x.gif").exists()
    hint = " (run with --debug or IMIX_DEBUG=1 for the traceback)"
    if hint in line:  # (render names an env it cannot make in its own line: "cannot render <id>: <message>")
        debug = _imix(argv, folder, mode, debug=True)  # IMIX_DEBUG=1: the full traceback, then the same line
        assert debug.returncode == 1 and "Traceback" in debug.stderr and debug.stderr.rstrip().splitlines()[-1] == line.replace(hint, "")


def test_the_debug_flag_prints_the_traceback(bad_env, tmp_path):
    folder, root = bad_env
    proc = _imix(["eval", f"results_dir={root}", "import=bad_env", "episodes=2", "--debug"], folder, "step")
    assert proc.returncode == 1 and "Traceback" in proc.stderr and "the physics diverged" in proc.stderr.splitlines()[-1]
