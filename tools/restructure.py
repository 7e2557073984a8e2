"""Move imix_cli's modules into their layers' folders, and rewrite every reference to them. Idempotent.

``python tools/restructure.py`` (from the repository root, with the project's venv: it ends with its
ruff) does, for every row of :data:`MOVES`:

1. ``git mv`` the module (or the whole folder) to its new place -- skipped when it is there already; a
   file that another branch added at an old place of a moved folder afterwards is moved in after it;
2. rewrite every reference in the tracked text files (Python, Markdown, YAML, TOML, the Makefile):
   dotted names (``imix_cli.mixing`` -> ``imix_cli.core.mixing``, also in strings: monkeypatch targets,
   ``python -m`` lines), ``from imix_cli import mixing`` (-> ``from imix_cli.core import mixing``),
   paths (``imix_cli/mixing.py``, ``running/config.py``, the regex-escaped path of the cache stamp),
   and pyproject's list of packages;
3. write the ``__init__.py`` of every new folder (:data:`NEW_PACKAGES`), sort the imports it changed
   (``ruff check --select I --fix``, ``ruff format``); the numba cache stamp is computed
   (:mod:`imix_cli.core.numba_cache`), so nothing else is rewritten;
4. report what the table does not place: a module at the top of ``imix_cli/`` or ``imix_cli/running/``
   that is neither moved nor meant to stay there (:data:`STAYS`) -- a module another branch added since.
   Add a row for it and run the script again.

Run again on a tree where other branches were merged after the move, it moves what is still at an
old place and rewrites what still names one; on a tree already done it changes nothing.
Why a script and not a commit alone: other branches edit these modules meanwhile; their merge
then needs the script, not a hand-made rename of every line they touched.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "imix_cli"

#: (old path, new path) below ``imix_cli/``; a folder moves whole. A row that moves a file out of a folder
#: that is itself moved comes before the folder's row.
MOVES = [
    # the numerical library: no files, no Hydra, no processes of a run (imports nothing of running, commands, plotting)
    ("distributions.py", "core/distributions.py"),
    ("divergence.py", "core/divergence.py"),
    ("mixing.py", "core/mixing.py"),
    ("mixing_kernels.py", "core/mixing_kernels.py"),
    ("generation.py", "core/generation.py"),
    ("mirrored.py", "core/mirrored.py"),
    ("ask_tell.py", "core/ask_tell.py"),
    ("elementary.py", "core/elementary.py"),
    ("elementary_tables.py", "core/elementary_tables.py"),
    ("linalg_kernels.py", "core/linalg_kernels.py"),
    ("stats.py", "core/stats.py"),
    ("policies.py", "core/policies.py"),
    ("evaluation.py", "core/evaluation.py"),
    ("parallel_evaluation.py", "core/parallel_evaluation.py"),
    ("processes.py", "core/processes.py"),
    ("registry.py", "core/registry.py"),
    ("env_ids.py", "core/env_ids.py"),
    ("bounds.py", "core/bounds.py"),
    ("numerics.py", "core/numerics.py"),
    ("numba_cache.py", "core/numba_cache.py"),
    ("algorithms", "core/algorithms"),
    ("envs", "core/envs"),
    ("adapters/checkpoint.py", "running/files/mixing_checkpoint.py"),  # MixingES's checkpoint: a file, written by the one writer
    ("adapters", "core/adapters"),
    ("ddpg/config.py", "running/config/ddpg.py"),  # the DDPG baseline: its keys with the run's config,
    ("ddpg/seeds.py", "running/loop/ddpg_seeds.py"),  # its seeds with the run's loops,
    ("ddpg", "core/ddpg"),  # its agent and settings with the numerical library
    # below every layer that reads a command line's key=value settings (plot, bench, eval, render, status)
    ("commands/keyvalue.py", "keyvalue.py"),
    # the process `imix bench memory` measures runs the command line: it lives with it (bench never imports commands)
    ("bench/memory_child.py", "commands/bench_memory_child.py"),
    # running/files: what a run reads and writes (CSV contract, checkpoints, policies, locks, trackers), one safe writer
    ("writing.py", "running/files/writing.py"),
    ("running/results.py", "running/files/results.py"),
    ("running/safe_npz.py", "running/files/safe_npz.py"),
    ("running/run_lock.py", "running/files/run_lock.py"),
    ("running/checkpoints.py", "running/files/checkpoints.py"),
    ("running/policy_files.py", "running/files/policy_files.py"),
    ("running/run_writer.py", "running/files/run_writer.py"),
    ("running/tracking.py", "running/files/tracking.py"),
    # running/config: the command line and conf/ into a checked RunSpec
    ("running/config.py", "running/config/compose.py"),
    ("running/config_checks.py", "running/config/checks.py"),
    ("running/config_keys.py", "running/config/keys.py"),
    ("running/es_config.py", "running/config/es_config.py"),
    ("running/run_spec.py", "running/config/run_spec.py"),
    # running/loop: the generations of a seed (lockstep and compiled loops, resume, stop requests)
    ("running/lockstep.py", "running/loop/lockstep.py"),
    ("running/compiled_loop.py", "running/loop/compiled_loop.py"),
    ("running/stopping.py", "running/loop/stopping.py"),
    ("running/es_seeds.py", "running/loop/es_seeds.py"),
    ("running/resume.py", "running/loop/resume.py"),
]

#: Modules meant to stay where they are: the top of ``imix_cli/`` and of ``imix_cli/running/`` (the run itself:
#: the seed grid, the processes, the run folder, the trainers, the warm-up, the summary).
STAYS = {
    "": {"__init__.py", "experiment.py", "messages.py", "keyvalue.py"},
    "running": {"__init__.py", "runner.py", "pool.py", "trainers.py", "run_folder.py", "seed_checks.py", "summary.py", "warmup.py"},
}

#: The new folders and what each holds (their ``__init__.py`` docstring; the package imports nothing).
NEW_PACKAGES = {
    "core": "The numerical library: distributions, mixing and its compiled kernels, the evolution strategies, the\n"
    "environments and policies, their evaluation, the elementary functions, statistics. No files, no Hydra: it\n"
    "imports nothing of :mod:`imix_cli.running`, :mod:`imix_cli.commands` or :mod:`imix_cli.plotting`\n"
    "(tests/test_layering.py).",
    "running/files": "What a run reads and writes: the CSV contract, checkpoints, policy files, the run folder's lock, trackers,\n"
    "and the one safe writer (atomic writes, symbolic links refused).",
    "running/config": "``imix run``'s command line and ``conf/`` composed by Hydra and checked into an immutable RunSpec.",
    "running/loop": "The generations of a run's seeds: the lockstep and compiled loops, resuming from checkpoints, stop requests.",
}

TEXT_SUFFIXES = {".py", ".md", ".yml", ".yaml", ".toml", ".txt", ".cfg", ".ini", ".sh"}
TEXT_NAMES = {"Makefile", ".gitignore"}
SKIP = {"tools/restructure.py"}  # its table names the old places on purpose


def git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True, text=True).stdout


def dotted(path: str) -> str:
    """``running/config.py`` -> ``running.config``; a folder's path -> its package's name."""
    return path.removesuffix(".py").replace("/", ".")


# ------------------------------------------------------------------------------------------- 1. moves
def deepen(path: Path, levels: int) -> None:
    """A module that moved ``levels`` folders deeper finds the repository's files ``levels`` parents further up:
    ``Path(__file__).resolve().parents[2]`` becomes ``parents[3]`` (done once, when the module moves)."""
    if levels and path.suffix == ".py":
        text = path.read_text()
        new = re.sub(r"(Path\(__file__\)(?:\.resolve\(\))?\.parents\[)(\d+)\]", lambda m: f"{m.group(1)}{int(m.group(2)) + levels}]", text)
        if new != text:
            path.write_text(new)


def remove_if_empty(folder: Path) -> None:
    """Remove ``folder`` (and its empty sub-folders) if no file but bytecode caches is left in it."""
    if not folder.is_dir() or folder == ROOT / PACKAGE or any(p.is_file() and "__pycache__" not in p.parts for p in folder.rglob("*")):
        return
    for path in sorted(folder.rglob("*"), key=lambda p: len(p.parts), reverse=True):
        path.unlink() if path.is_file() else path.rmdir()
    folder.rmdir()


def move_files() -> list[str]:
    """``git mv`` every row still at its old place; what was moved, as lines."""
    pkg, done = ROOT / PACKAGE, []
    for old, new in MOVES:
        src, dst = pkg / old, pkg / new
        if not src.exists():
            continue
        if src.is_dir():  # move file by file: a folder already moved may meet files added at its old place since
            for path in sorted(p for p in src.rglob("*") if p.is_file() and "__pycache__" not in p.parts):
                target = dst / path.relative_to(src)
                if target.exists():
                    done.append(f"CONFLICT: {path.relative_to(ROOT)} and {target.relative_to(ROOT)} both exist; merge them by hand")
                    continue
                if not git("ls-files", str(path.relative_to(ROOT))).strip():
                    continue  # untracked (a cache): not ours to move
                target.parent.mkdir(parents=True, exist_ok=True)
                git("mv", str(path.relative_to(ROOT)), str(target.relative_to(ROOT)))
                done.append(f"moved {path.relative_to(ROOT)} -> {target.relative_to(ROOT)}")
                deepen(target, len(target.parts) - len(path.parts))
            remove_if_empty(src)
        elif dst.exists():
            done.append(f"CONFLICT: {src.relative_to(ROOT)} and {dst.relative_to(ROOT)} both exist; merge them by hand")
        else:
            dst.parent.mkdir(parents=True, exist_ok=True)
            git("mv", str(src.relative_to(ROOT)), str(dst.relative_to(ROOT)))
            done.append(f"moved {src.relative_to(ROOT)} -> {dst.relative_to(ROOT)}")
            deepen(dst, len(dst.parts) - len(src.parts))
        remove_if_empty(src.parent)
    for folder, doc in NEW_PACKAGES.items():
        init = pkg / folder / "__init__.py"
        if not init.exists():
            init.parent.mkdir(parents=True, exist_ok=True)
            init.write_text(f'"""{doc}\n"""\n')
            git("add", str(init.relative_to(ROOT)))
            done.append(f"wrote {init.relative_to(ROOT)}")
    return done


# ---------------------------------------------------------------------------------------- 2. rewrites
def module_map() -> dict[str, str]:
    """Old dotted name (below imix_cli) -> new one, longest first (a file's row before its folder's)."""
    return dict(sorted(((dotted(o), dotted(n)) for o, n in MOVES), key=lambda kv: -len(kv[0])))


def new_modules() -> set[str]:
    """Dotted names (below imix_cli) of the modules and packages of the tree as it stands after the moves."""
    pkg, names = ROOT / PACKAGE, set()
    for path in pkg.rglob("*.py"):
        rel = path.relative_to(pkg).with_suffix("").parts
        names.add(".".join(rel[:-1] if rel[-1] == "__init__" else rel))
    return names - {""}


class Rewriter:
    def __init__(self) -> None:
        self.map = module_map()
        self.new = new_modules()

    def target(self, name: str, following: str | None = None) -> str | None:
        """The new dotted name of ``name`` (below imix_cli; a module or a name inside one), None if it did not move.

        ``following``: the name after it (``name.following``, or ``from name import following``). An old name that is
        also a new package (``running.config``, the old module and the new folder) followed by one of the new
        package's modules names the folder already."""
        for old, new in self.map.items():
            if name == old or name.startswith(old + "."):
                if name == new or name.startswith(new + "."):  # already at its new place (a new name under its old one)
                    return None
                after = name[len(old) + 1 :].split(".")[0] if name != old else following
                if old in self.new and after is not None and f"{old}.{after}" in self.new:  # e.g. running.config.checks
                    return None
                return new + name[len(old) :]
        return None

    # dotted names: imix_cli.a.b.c (in code, strings, docs); the last parts may be attributes
    DOTTED = re.compile(rf"(?<![\w.]){PACKAGE}((?:\.\w+)+)")

    def dotted(self, text: str) -> str:
        def one(m: re.Match) -> str:
            parts = m.group(1)[1:].split(".")
            for n in range(len(parts), 0, -1):  # the longest prefix that names an old module
                head = ".".join(parts[:n])
                following = parts[n] if n < len(parts) else None
                new = self.target(head, following)
                if new is not None and any(head == o or head.startswith(o + ".") for o in self.map):
                    return f"{PACKAGE}." + ".".join([new, *parts[n:]])
            return m.group(0)

        return self.DOTTED.sub(one, text)

    FROM = re.compile(rf"^([ \t]*)from[ \t]+({PACKAGE}(?:\.\w+)*)[ \t]+import[ \t]+(\([^)]*\)|[^\n]*)", re.MULTILINE)

    def from_imports(self, text: str) -> str:
        def one(m: re.Match) -> str:
            indent, module, names = m.group(1), m.group(2), m.group(3)
            body, comment = names, ""
            if not body.startswith("("):
                body, _, comment = body.partition("#")
                comment = "  #" + comment if comment else ""
            items = [i.strip() for i in re.sub(r"#[^\n]*", "", body.strip("()")).replace("\n", " ").split(",") if i.strip()]
            if not items or items == ["*"]:
                return m.group(0)
            base = module[len(PACKAGE) + 1 :] if module != PACKAGE else ""
            groups: dict[str, list[str]] = {}
            changed = False
            for item in items:
                name, _, alias = (p.strip() for p in item.partition(" as "))
                full = f"{base}.{name}" if base else name
                new_full = self.target(full) if any(full == o or full.startswith(o + ".") for o in self.map) else None
                if new_full is not None and (full in self.new or full in self.map or new_full in self.new):  # a module imported by name
                    parent, _, last = new_full.rpartition(".")
                    groups.setdefault(f"{PACKAGE}.{parent}" if parent else PACKAGE, []).append(
                        last if (alias or name) == last and not alias else f"{last} as {alias or name}"
                    )
                    changed = True
                    continue
                new_base = self.target(base, name) if base else None
                mod = f"{PACKAGE}.{new_base}" if new_base is not None else module
                changed |= mod != module
                groups.setdefault(mod, []).append(item)
            if not changed:
                return m.group(0)
            lines = [f"{indent}from {mod} import {', '.join(group)}" for mod, group in groups.items()]
            return "\n".join(lines) + comment

        return self.FROM.sub(one, text)

    def paths(self, text: str) -> str:
        for old, new in self.map.items():
            old_path, new_path = old.replace(".", "/"), new.replace(".", "/")
            is_dir = (ROOT / PACKAGE / new_path).is_dir()
            tail = r"(?!\w)" if is_dir else r"\.py\b"
            new_tail = "" if is_dir else ".py"
            # imix_cli/old.py, and its regex-escaped form (imix_cli/elementary\.py, the cache stamp's pattern)
            text = re.sub(rf"(?<![\w./]){PACKAGE}/{re.escape(old_path)}{tail}", f"{PACKAGE}/{new_path}{new_tail}", text)
            if not is_dir:
                text = re.sub(rf"(?<![\w./]){PACKAGE}/{re.escape(old_path)}\\\.py\b", f"{PACKAGE}/{new_path}\\\\.py", text)
            if "/" in old_path:  # running/config.py, algorithms/ars.py: a path below imix_cli/ written without it
                text = re.sub(rf"(?<![\w./]){re.escape(old_path)}{tail}", f"{new_path}{new_tail}", text)
        return text

    def rewrite(self, text: str) -> str:
        # from-imports first (they name modules by their last part), then every dotted name outside them
        out, last = [], 0
        for m in self.FROM.finditer(text):
            out.append(self.dotted(text[last : m.start()]))
            out.append(self.from_imports(m.group(0)))
            last = m.end()
        out.append(self.dotted(text[last:]))
        return self.paths("".join(out))


def text_files() -> list[Path]:
    files = []
    for name in git("ls-files").splitlines():
        path = ROOT / name
        if name in SKIP or name.startswith("results/") or not path.is_file():
            continue
        if path.suffix in TEXT_SUFFIXES or path.name in TEXT_NAMES:
            files.append(path)
    return files


def rewrite_files() -> list[str]:
    rw, changed = Rewriter(), []
    for path in text_files():
        text = path.read_text()
        if path.name == "pyproject.toml":  # its list of packages is made anew from the folders (a package name is no module's)
            block = PACKAGES.search(text)
            new = rw.rewrite(text[: block.start(1)]) + block.group(1) + rw.rewrite(text[block.end(1) :]) if block else rw.rewrite(text)
            new = list_packages(new)
        else:
            new = rw.rewrite(text)
        if new != text:
            path.write_text(new)
            changed.append(str(path.relative_to(ROOT)))
    return changed


PACKAGES = re.compile(r"^packages = \[\n(.*?)^\]", re.MULTILINE | re.DOTALL)


def list_packages(text: str) -> str:
    """pyproject's ``packages = [...]``: every package folder of imix_cli listed once, in path order."""
    m = PACKAGES.search(text)
    if not m:
        return text
    listed = re.findall(r'"([\w.]+)"', m.group(1))
    on_disk = sorted(
        ".".join((PACKAGE, *p.parent.relative_to(ROOT / PACKAGE).parts)) for p in (ROOT / PACKAGE).rglob("__init__.py") if "__pycache__" not in p.parts
    )
    missing = [p for p in on_disk if p not in listed]
    gone = [p for p in listed if p.startswith(PACKAGE) and not p.startswith(f"{PACKAGE}.conf") and p not in on_disk]
    if not missing and not gone:
        return text
    lines = [line for line in m.group(1).splitlines(keepends=True) if not any(f'"{g}"' in line for g in gone)]
    conf = next((k for k, line in enumerate(lines) if f'"{PACKAGE}.conf' in line), len(lines))
    lines[conf:conf] = [f'    "{p}",\n' for p in missing]
    return text[: m.start(1)] + "".join(lines) + text[m.end(1) :]


# ------------------------------------------------------------------------------------ 3. and 4. after
def unplaced() -> list[str]:
    """Modules at the top of imix_cli/ or imix_cli/running/ that the table neither moves nor keeps there."""
    out = []
    for folder, keep in STAYS.items():
        for path in sorted((ROOT / PACKAGE / folder).glob("*.py")):
            if path.name not in keep:
                out.append(f"UNPLACED: {path.relative_to(ROOT)} (add a row to MOVES, or to STAYS, and run again)")
    return out


def tidy() -> list[str]:
    notes = []
    ruff = Path(sys.executable).parent / "ruff"
    exe = str(ruff) if ruff.exists() else "ruff"
    for args in (["check", "--select", "I", "--fix", "--quiet"], ["format", "--quiet"]):
        try:
            subprocess.run([exe, *args, PACKAGE, "tests", "benchmarks"], cwd=ROOT, check=False)  # tests/test_lint.py's paths
        except FileNotFoundError:
            notes.append("ruff not found: sort the imports with `ruff check --select I --fix` and `ruff format`")
            break
    # the numba cache stamp is computed (core/numba_cache.py), nothing to rewrite
    return notes


def main() -> int:
    moved = move_files()
    changed = rewrite_files()
    notes = tidy()
    for line in moved:
        print(line)
    print(f"rewrote references in {len(changed)} files")
    for line in [*notes, *unplaced()]:
        print(line)
    top = sorted(p.name for p in (ROOT / PACKAGE).glob("*.py"))
    print(f"{len(top)} modules at the top of {PACKAGE}/: {', '.join(top)}")
    return 1 if any(line.startswith(("CONFLICT", "UNPLACED")) for line in moved + notes + unplaced()) else 0


if __name__ == "__main__":
    sys.exit(main())
