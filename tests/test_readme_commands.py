"""Every command the README and the commands' --help show runs as shown, in a fresh folder, in the order shown.

The commands are read from the README (its ```bash blocks, its inline `imix ... key=value` spans and its
```python block) and from the output of `imix --help`, `imix run --help`, `imix bench --help` and the
other commands' --help, and run with the installed `imix` in a new working directory (so a fresh
`results/`). A README block preceded by ``<!-- readme-test: key=value ... -->`` gets those keys added to
its `imix run` lines (small budgets: seeds=2 generations=3), which the marker comment says; the --help
examples get theirs from HELP_OVERRIDES below (each key must still be an example, so the table cannot
outlive one). `make` targets are not run here (CI runs `make install`, `make test` and `make
reproduce-quick`); each one shown must be a target of the Makefile.

algo=ddpg without torch: the one line naming the extra, exit status 2 (every missing extra's) and no run folder.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import extra_installed

ROOT = Path(__file__).resolve().parents[1]
IMIX = str(Path(sys.executable).parent / "imix")
SMALL = "seeds=2 generations=3"
MARKER = re.compile(r"<!--\s*readme-test:\s*(.*?)\s*-->")

#: --help examples -> what the test adds (budgets only: the examples' own keys stay as shown)
HELP_OVERRIDES = {
    "imix run algo=cmaes env=acrobot im=true seeds=5 generations=100 experiment=try": SMALL,
    "imix run -m algo=openes,snes,cem,cmaes env=cartpole,acrobot eim=false,true experiment=paper": SMALL,
    "imix run env=gym env.id=CartPole-v1 seeds=3 generations=100": SMALL,
    "imix run -m algo=snes env=cartpole eim=true popsize=10,25,50 sigma=0.05,0.1,0.25 experiment=grid": SMALL,
    "imix run algo=ddpg env=continuous_cartpole seeds=5": "seeds=1 total_steps=200",
    "imix eval experiment=try episodes=100 which=mean": "episodes=3",
}
#: every `imix bench` example: one repeat of each measurement on the smallest inputs
BENCH_SMALL = "repeats=1 min_seconds=0.01 naive_members=2 sizes=2 dims=130 seeds=2 generations=3 popsize=4 mujoco_envs=hopper"
HELP_PAGES = [["--help"], ["run", "--help"], ["plot", "--help"], ["bench", "--help"], ["eval", "--help"], ["render", "--help"], ["status", "--help"]]


def _strip_comment(line: str) -> str:
    return line.split(" #", 1)[0].strip() if not line.lstrip().startswith("#") else ""


def _runs(command: str, keys: str) -> str:
    """A readme-test marker's keys are for the block's `imix run` lines only."""
    return keys if re.search(r"\bimix run\b", command) else ""


def readme_commands(text: str) -> list[tuple[str, str]]:
    """(command, keys the test adds to it) in the README's order: bash lines, inline `imix ...=...` spans, python blocks."""
    found, pending, block, lang = [], "", None, ""
    for line in text.splitlines():
        marker = MARKER.search(line)
        if marker:
            pending = marker.group(1)
            continue
        if line.startswith("```"):
            if block is None:
                block, lang = [], line[3:].strip()
            else:
                if lang == "bash":
                    found += [(command, _runs(command, pending)) for command in (_strip_comment(b) for b in block) if command]
                elif lang == "python":
                    found.append(("python -c " + shlex.quote("\n".join(block)), ""))
                block, pending = None, ""
            continue
        if block is not None:
            block.append(line)
            continue
        for span in re.findall(r"`([^`]+)`", line):
            if re.match(r"(\w+=\S+ )*imix \w+ .*=", span):
                found.append((span, _runs(span, pending)))
        if not line.strip():
            pending = "" if not MARKER.search(line) else pending
    return found


def help_commands() -> list[tuple[str, str]]:
    found = []
    for page in HELP_PAGES:
        out = subprocess.run([IMIX, *page], capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, (page, out.stderr)
        for line in out.stdout.splitlines():
            command = re.split(r"\s{2,}\(", line.strip())[0]  # "imix run ...   (any gymnasium id)"
            if re.match(r"imix \w+", command) and not re.search(r"[\[\]<>]|\.\.\.", command):
                extra = BENCH_SMALL if command.startswith("imix bench") else HELP_OVERRIDES.get(command, "")
                if (command, extra) not in found:  # `imix --help` and `imix run --help` show some of the same
                    found.append((command, extra))
    return found


def _with(command: str, extra: str) -> list[str]:
    return shlex.split(command) + shlex.split(extra)


def run_as_shown(command: str, extra: str, cwd: Path) -> subprocess.CompletedProcess:
    words = _with(command, extra)
    env = {**os.environ, "MPLBACKEND": "Agg"}
    env.pop("PYTHONPATH", None)
    while words and re.match(r"\w+=", words[0]):  # VAR=value imix ...
        name, value = words.pop(0).split("=", 1)
        env[name] = value
    if words[0] == "imix":
        words[0] = IMIX
    elif words[0] == "python":
        words[0] = sys.executable
    return subprocess.run(words, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)


def _fresh_folder(tmp_path: Path) -> Path:
    """A user's working directory: the repository's examples/ (the README's own env lives there), no results/."""
    work = tmp_path / "work"
    shutil.copytree(ROOT / "examples", work / "examples")
    return work


def _check(commands: list[tuple[str, str]], work: Path) -> None:
    torch = extra_installed("ddpg")
    for command, extra in commands:
        if command.startswith("make "):
            continue
        if "algo=ddpg" in command and not torch:
            before = sorted(work.rglob("*"))
            proc = run_as_shown(command, extra, work)
            assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and '".[ddpg]" from the imix clone' in proc.stderr, (command, proc.stderr[-2000:])
            assert sorted(work.rglob("*")) == before, "algo=ddpg without its extra left files behind"
            continue
        proc = run_as_shown(command, extra, work)
        assert proc.returncode == 0, f"{command} {extra}: exit {proc.returncode}\n{proc.stdout[-1500:]}\n{proc.stderr[-2500:]}"


def test_the_readme_lists_what_the_test_runs():
    """The parser finds the README's commands (a README rewritten into another shape must not leave this test empty)."""
    commands = [c for c, _ in readme_commands((ROOT / "README.md").read_text())]
    assert "imix run algo=snes env=cartpole eim=true" in commands
    assert any(c.startswith("PYTHONPATH=") and "imix eval" in c for c in commands) and any(c.startswith("python -c") for c in commands)
    makefile = (ROOT / "Makefile").read_text()
    for command in commands:
        if command.startswith("make "):
            assert re.search(rf"^{re.escape(command.split()[1])}:", makefile, re.M), f"{command}: no such target in the Makefile"


@pytest.mark.slow
def test_the_help_overrides_are_still_examples():
    shown = {command for command, _ in help_commands()}
    assert set(HELP_OVERRIDES) <= shown, set(HELP_OVERRIDES) - shown
    assert "imix run algo=snes env=cartpole eim=true" in shown and any(c.startswith("imix bench") for c in shown)


@pytest.mark.slow
@pytest.mark.install  # minutes of CPU (the main job twice, sweeps, every bench section): make test-install, run by CI
def test_every_readme_command_runs_as_shown(tmp_path):
    _check(readme_commands((ROOT / "README.md").read_text()), _fresh_folder(tmp_path))


@pytest.mark.slow
@pytest.mark.install
def test_every_help_example_runs_as_shown(tmp_path):
    _check(help_commands(), _fresh_folder(tmp_path))
