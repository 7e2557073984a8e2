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

A figure (:data:`FIGURES`: the README's first-steps efficiency figure) is regenerated the same way: its
runs in a temporary folder, then ``imix plot``, and the PNG copied into docs/. What is checked is the
data the figure draws (:func:`imix_cli.plotting.figures.efficiency_curves`), written next to it as a
CSV: pixels change with matplotlib and fonts, the curves only with imix.
``python -m imix_cli.commands.docs_numbers check [name ...]`` re-runs the commands of :data:`BLOCKS` and
:data:`FIGURES` (default: all of them; ``make docs-numbers`` writes them all) in a temporary results folder and fails, naming the block, if
the docs no longer show what the code prints; ``write [name ...]`` regenerates the blocks (``write
main-job`` runs the README's main job: 25 seeds x 1000 generations). Wall times are the one part
of an output that is not compared. tests/test_docs.py runs ``check`` on every block and figure.
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
class FigureBlock:
    runs: tuple  # `imix run` argument lists, run in order (results_dir is added: a temporary folder)
    experiment: str
    env: str  # the efficiency figure of this env
    png: str  # where the README shows it (relative to the repository); the data goes to the same name .csv


FIGURES = {
    # The README's "what mixing gains" figure: CEM on CartPole without and with EIM, 5 seeds x 60 generations.
    "first-steps": FigureBlock(
        (("-m", "algo=cem", "env=cartpole", "eim=false,true", "seeds=5", "generations=60", "experiment=first_steps", "progress=false"),),
        "first_steps",
        "cartpole",
        "docs/first_steps_efficiency_cartpole.png",
    ),
}


@dataclass(frozen=True)
class Block:
    command: tuple  # `imix run` arguments (results_dir is added: a temporary folder)
    files: tuple  # Markdown files (relative to the repository) that show it


BLOCKS = {
    # The README's main job: what a user's first command prints (25 seeds x 1000 generations: a few seconds on 2 cores).
    "main-job": Block(("algo=snes", "env=cartpole", "eim=true", "progress=false"), ("README.md",)),
    # The getting-started guide: the same config without and with mixing, 3 seeds x 30 generations.
    "quick-mixing": Block(
        ("-m", "algo=snes", "env=cartpole", "eim=false,true", "seeds=3", "generations=30", "progress=false", "experiment=first"),
        ("docs/getting-started.md",),
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


def _run_imix(args, cwd: str) -> None:
    import os

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p), "MPLBACKEND": "Agg"}
    proc = subprocess.run([*_imix(), *args], capture_output=True, text=True, env=env, cwd=cwd)
    if proc.returncode != 0:
        raise RuntimeError(f"imix {' '.join(args)} failed: {proc.stderr.strip()[-500:]}")


def figure_data(name: str, png_to: Path | None = None) -> str:
    """The CSV of what figure ``name`` draws now, from its runs made afresh (and its PNG copied to ``png_to``)."""
    import io
    import shutil

    from imix_cli.plotting.data import PlotOptions, headline, load_experiment
    from imix_cli.plotting.figures import efficiency_curves, efficiency_groups

    block = FIGURES[name]
    with tempfile.TemporaryDirectory() as tmp:
        results = f"{tmp}/results"
        for args in block.runs:
            _run_imix(["run", *args, f"results_dir={results}"], tmp)
        if png_to is not None:
            _run_imix(["plot", f"results_dir={results}", f"experiment={block.experiment}", "only=efficiency", "formats=png"], tmp)
            shutil.copyfile(Path(results) / block.experiment / "figures" / f"efficiency_{block.env}.png", png_to)
        groups = efficiency_groups(load_experiment(results, block.experiment, warn=lambda _: None), block.env)
        column, measure = headline(groups, PlotOptions(warn=lambda _: None), "efficiency")  # as imix plot's default draws it
        log, curves = efficiency_curves(groups, column)
    out = io.StringIO()
    out.write(f"# the curves of {block.png} ({'log' if log else 'linear'} x): {measure} per seed on a common grid of episodes\n")
    out.write("run,episodes," + ",".join(f"seed_{k}" for k in range(max(len(m) for _, _, m in curves))) + "\n")
    for group, x, matrix in curves:
        for i, episodes in enumerate(x):
            out.write(f"{group.name},{episodes:.6g}," + ",".join("" if v != v else f"{v:.6g}" for v in matrix[:, i]) + "\n")
    return out.getvalue()


def _sidecar(name: str) -> Path:
    return ROOT / Path(FIGURES[name].png).with_suffix(".csv")


def _machine() -> str:
    """The machine an output's times were measured on: ``2-core AMD EPYC 7B13`` (the CPU's model, as Linux names it)."""
    import os

    model = platform.processor() or platform.machine()
    try:
        model = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{os.cpu_count()}-core {model}"


def _provenance(name: str, file: str) -> str:
    """The line above a block's output: the command, a link to the results page, and (in a comment the page
    collects) the commit, date, stack and machine that printed it."""
    import datetime
    import os

    load = os.getloadavg()[0]  # the 1-minute load average: how busy the machine was when the times were taken
    from imix_cli import __version__

    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip() or "unknown"
    except OSError:
        commit = "unknown"
    import numba
    import numpy

    command = "imix run " + " ".join(BLOCKS[name].command)
    stack = f"imix {__version__}, Python {platform.python_version()}, numpy {numpy.__version__}, numba {numba.__version__}, {platform.machine()}"
    mark = provenance_mark(commit, command, datetime.datetime.now(datetime.timezone.utc).date().isoformat(), f"{_machine()}, load {load:.1f}", stack)
    return f"*Printed by `{command}` ({_link(file)}); regenerate with `make docs-numbers`.*{mark}"


# ------------------------------------------------------------------------------------ the results page
#: The page that lists where each measured number of README.md and docs/ comes from: ``write`` makes it from the
#: provenance marks of the pages (``<!-- provenance: commit=...; what=...; ... -->``, written beside the numbers
#: instead of commit stamps in the prose), ``check`` fails when it is out of date.
RESULTS_PAGE = "docs/results.md"
_MARK = re.compile(r"<!-- provenance: (.*?) -->", re.S)
_FIELDS = ("commit", "date", "what", "machine", "stack")


def provenance_mark(commit: str, what: str, date: str = "", machine: str = "", stack: str = "") -> str:
    """The comment a page carries beside a measured number (invisible on the page, collected by :func:`results_page`)."""
    values = {"commit": commit, "date": date, "what": what, "machine": machine, "stack": stack}
    return "<!-- provenance: " + "; ".join(f"{k}={v}" for k, v in values.items() if v) + " -->"


def _link(file: str) -> str:
    """A link to the results page from ``file`` (a path below the repository)."""
    target = Path(RESULTS_PAGE).relative_to(Path(file).parent) if file.startswith("docs/") else Path(RESULTS_PAGE)
    return f"provenance: [results]({target.as_posix()})"


def _pages() -> list[Path]:
    return [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").rglob("*.md") if p != ROOT / RESULTS_PAGE)]


def provenance_rows() -> list[dict]:
    """Every provenance mark of README.md and docs/, in page order: its fields, its page and the heading above it."""
    rows = []
    for page in _pages():
        text = page.read_text()
        for match in _MARK.finditer(text):
            fields = dict(part.strip().split("=", 1) for part in match.group(1).split("; ") if "=" in part)
            unknown = set(fields) - set(_FIELDS)
            if unknown or "commit" not in fields or "what" not in fields:
                raise ValueError(f"{page.relative_to(ROOT)}: provenance mark {match.group(0)[:80]!r}: needs commit= and what=, knows {', '.join(_FIELDS)}")
            headings = [line.lstrip("#").strip() for line in text[: match.start()].splitlines() if line.startswith("#")]
            rows.append({**fields, "page": page.relative_to(ROOT).as_posix(), "section": headings[-1] if headings else ""})
    return rows


def results_page() -> str:
    """docs/results.md: one row per measured result of the docs, where it is shown and what produced it."""
    lines = [
        "# Results and their provenance",
        "",
        "Where each measured number of the README and of these pages comes from: the commit it was measured at,",
        "when, what ran and on which machine. The pages carry these as comments beside the numbers, not as",
        "commit stamps in their prose; `make docs-numbers` writes this page from them",
        "(`python -m imix_cli.commands.docs_numbers write`), and `tests/test_docs.py` fails when it is out of date.",
        "",
        "| page | section | what ran | commit | date | machine |",
        "|---|---|---|---|---|---|",
    ]
    for row in provenance_rows():
        page = row["page"]
        shown = f"[{page.removeprefix('docs/')}]({page.removeprefix('docs/')})" if page.startswith("docs/") else f"`{page}`"
        machine = "; ".join(v for v in (row.get("machine", ""), row.get("stack", "")) if v)
        cells = [shown, row["section"], row["what"], f"`{row['commit']}`", row.get("date", ""), machine]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines) + "\n"


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
    """Problems (one line each; empty when the docs show what the code prints and the results page lists their provenance)."""
    names = names or [*BLOCKS, *FIGURES]
    problems = [] if results_current() else [f"{RESULTS_PAGE}: out of date with the pages' provenance marks (make docs-numbers)"]
    for name in names:
        if name in FIGURES:
            sidecar = _sidecar(name)
            if not sidecar.exists() or sidecar.read_text() != figure_data(name):
                problems.append(f"{FIGURES[name].png}: the figure's data ({sidecar.relative_to(ROOT)}) differs from what its runs give now")
            continue
        now = printed(name)
        for file in BLOCKS[name].files:
            shown = [out for n, _, _, out in _blocks_in((ROOT / file).read_text()) if n == name]
            if not shown:
                problems.append(f"{file}: no <!-- output: {name} --> block")
            elif any(_comparable(s) != _comparable(now) for s in shown):
                problems.append(f"{file}: block {name} differs from what `imix run {' '.join(BLOCKS[name].command)}` prints now")
    return problems


def results_current() -> bool:
    page = ROOT / RESULTS_PAGE
    return page.exists() and page.read_text() == results_page()


def write_results_page() -> list[Path]:
    if results_current():
        return []
    (ROOT / RESULTS_PAGE).write_text(results_page())
    return [ROOT / RESULTS_PAGE]


def write(names=None) -> list[Path]:
    names = names or [*BLOCKS, *FIGURES]
    changed = []
    for name in names:
        if name in FIGURES:
            _sidecar(name).write_text(figure_data(name, png_to=ROOT / FIGURES[name].png))
            changed += [ROOT / FIGURES[name].png, _sidecar(name)]
            continue
        now = printed(name)
        for file in BLOCKS[name].files:
            path = ROOT / file
            text = path.read_text()
            for n, start, end, _ in reversed(list(_blocks_in(text))):
                if n == name:
                    text = text[:start] + f"{_provenance(name, file)}\n\n```\n{now.rstrip()}\n```\n" + text[end:]
            if text != path.read_text():
                path.write_text(text)
                changed.append(path)
    return changed + write_results_page()


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("check", "write") or any(n not in BLOCKS and n not in FIGURES for n in argv[1:]):
        print(f"usage: python -m imix_cli.commands.docs_numbers check|write [{'|'.join([*BLOCKS, *FIGURES])} ...]", file=sys.stderr)
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
