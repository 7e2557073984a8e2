"""Numbers in the docs with provenance: each printed output shown in README.md or docs/ is a marked
block that a command regenerates and a check compares with what the code prints now.

A block in a Markdown file::

    <!-- output: quick-mixing -->
    ...a line naming the command, imix's version, the commit and the stack...
    ```
    ...what the command printed...
    ```
    <!-- /output -->

(the README's main job: ``<!-- main-job-output -->`` ... ``<!-- /main-job-output -->``).
``python -m imix_cli.commands.docs_numbers check [name ...]`` re-runs the commands of :data:`BLOCKS` (default:
the cheap ones, a few seconds each) in a temporary results folder and fails, naming the block, if
the docs no longer show what the code prints; ``write [name ...]`` regenerates the blocks (``write
main-job`` runs the README's main job: 25 seeds x 1000 generations). Wall times are the one part
of an output that is not compared. tests/test_docs.py runs ``check`` on the cheap blocks.
"""

from __future__ import annotations

import platform
import re
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class Block:
    command: tuple  # `imix run` arguments (results_dir is added: a temporary folder)
    files: tuple  # Markdown files (relative to the repository) that show it
    cheap: bool  # checked by the test suite and by `check` without names


BLOCKS = {
    # The README's main job: what a user's first command prints (about 20 s on 2 cores).
    "main-job": Block(("algo=snes", "env=cartpole", "eim=true", "progress=false"), ("README.md",), cheap=False),
    # The getting-started guide: the same config without and with mixing, 3 seeds x 30 generations.
    "quick-mixing": Block(
        ("-m", "algo=snes", "env=cartpole", "eim=false,true", "seeds=3", "generations=30", "progress=false", "experiment=first"),
        ("docs/getting-started.md",),
        cheap=True,
    ),  # fmt: skip
}

# <!-- output: NAME --> ... <!-- /output -->, or the README's <!-- NAME-output --> ... <!-- /NAME-output -->
_START = re.compile(r"<!-- (?:output: ([a-z0-9-]+)|([a-z0-9-]+)-output) -->\n")
_END = re.compile(r"<!-- /(?:[a-z0-9-]+-)?output -->")
_WALL_TIME = re.compile(r"\d+(\.\d+)? s\)")


def _imix() -> list[str]:
    script = Path(sys.executable).parent / "imix"
    return [str(script)] if script.exists() else [sys.executable, "-m", "imix_cli.commands.cli"]


def printed(name: str) -> str:
    """What block ``name``'s command prints now (run in a temporary results folder, shown as ``results/``)."""
    block = BLOCKS[name]
    with tempfile.TemporaryDirectory() as tmp:
        env_path = str(ROOT)
        import os

        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (env_path, os.environ.get("PYTHONPATH", "")) if p)}
        proc = subprocess.run([*_imix(), "run", *block.command, f"results_dir={tmp}/results"], capture_output=True, text=True, env=env, cwd=tmp)
        if proc.returncode != 0:
            raise RuntimeError(f"{name}: imix run {' '.join(block.command)} failed: {proc.stderr.strip()[-500:]}")
        return proc.stdout.replace(f"{tmp}/", "")


def _provenance(name: str) -> str:
    from imix_cli import __version__

    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip() or "unknown"
    except OSError:
        commit = "unknown"
    import numba
    import numpy

    command = "imix run " + " ".join(BLOCKS[name].command)
    return (
        f"*Printed by `{command}` (imix {__version__}, commit {commit}, Python {platform.python_version()}, numpy {numpy.__version__}, "
        f"numba {numba.__version__}, {platform.machine()}); regenerate with `python -m imix_cli.commands.docs_numbers write {name}`.*"
    )


def _blocks_in(text: str):
    """``(name, start, end, output)`` of every block: ``text[start:end]`` is its body, ``output`` its fenced text."""
    for match in _START.finditer(text):
        end = _END.search(text, match.end()).start()
        body = text[match.end() : end]
        fenced = re.search(r"```[a-z]*\n(.*?)```", body, re.S)
        yield match.group(1) or match.group(2), match.end(), end, fenced.group(1) if fenced else ""


def _comparable(output: str) -> str:
    return _WALL_TIME.sub("s)", output).strip()


def check(names=None) -> list[str]:
    """Problems (one line each; empty when the docs show what the code prints)."""
    names = names or [n for n, b in BLOCKS.items() if b.cheap]
    problems = []
    for name in names:
        now = printed(name)
        for file in BLOCKS[name].files:
            shown = [out for n, _, _, out in _blocks_in((ROOT / file).read_text()) if n == name]
            if not shown:
                problems.append(f"{file}: no <!-- output: {name} --> block")
            elif any(_comparable(s) != _comparable(now) for s in shown):
                problems.append(f"{file}: block {name} differs from what `imix run {' '.join(BLOCKS[name].command)}` prints now")
    return problems


def write(names=None) -> list[Path]:
    names = names or [n for n, b in BLOCKS.items() if b.cheap]
    changed = []
    for name in names:
        now = printed(name)
        for file in BLOCKS[name].files:
            path = ROOT / file
            text = path.read_text()
            for n, start, end, _ in reversed(list(_blocks_in(text))):
                if n == name:
                    text = text[:start] + f"{_provenance(name)}\n\n```\n{now.rstrip()}\n```\n" + text[end:]
            if text != path.read_text():
                path.write_text(text)
                changed.append(path)
    return changed


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("check", "write") or any(n not in BLOCKS for n in argv[1:]):
        print(f"usage: python -m imix_cli.commands.docs_numbers check|write [{'|'.join(BLOCKS)} ...]", file=sys.stderr)
        return 2
    if argv[0] == "write":
        for path in write(argv[1:]):
            print(f"wrote {path}")
        return 0
    problems = check(argv[1:])
    for line in problems:
        print(f"docs_numbers: {line}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
