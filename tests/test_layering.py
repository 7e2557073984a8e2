"""Import layering: no module imports a layer above its own, no modules import each other in a circle, and
``import imix_cli`` stays light.

The graph is the code's own: every ``import`` and ``from ... import`` of every module of the package, those
inside functions included (a deferred import still ties two modules), resolved to the module it names
(``from imix_cli.core import mixing`` -> ``imix_cli.core.mixing``; ``from imix_cli.core.mixing import mix``
-> ``imix_cli.core.mixing``; relative imports too), with the packages each import runs: importing
``imix_cli.core.algorithms.snes`` runs ``core/algorithms/__init__`` first, so a module that imports it imports that
package too (unless the module is inside the package, whose ``__init__`` its own import started). The package's face, ``imix_cli/__init__.py``, is no
node: Python runs it before any module of the package, so importing a constant of it loads nothing; a
module that took one of its public names (each loaded on first read from a module of some layer) would be
reported.

Made to fail: by a package written to a temporary folder with a planted upward import and a planted circle
(:func:`test_the_checker_finds_a_planted_upward_import_and_a_planted_circle`), and in the real tree by
``from imix_cli.running.files.results import COLUMNS`` appended to ``core/mixing/__init__.py`` (an import that climbs,
and out of the numerical library) and ``from imix_cli.core import evaluation`` inside a function appended to
``core/evaluation/policies.py`` (a circle: evaluation imports policies): three tests failed, naming both. The packages an import
runs: with ``core/algorithms/__init__`` importing the registry again (as it did), whose loaders import the ES modules,
:func:`test_no_modules_import_each_other_in_a_circle` failed naming ``imix_cli.core.algorithms`` and
``imix_cli.core.registry``, a loop the graph of modules alone did not show.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "imix_cli"

#: Lowest first; a module may import its own layer and those below it. An entry names a module or a folder
#: by its dotted path below ``imix_cli``; a module's layer is that of the longest entry its path starts with.
LAYERS = [
    ["messages", "keyvalue"],  # one-line messages, the run's one-line error, a command line's key=value settings
    ["core"],  # the numerical library: no files, no Hydra, nothing of running, commands or plotting
    ["running.files"],  # what a run reads and writes (CSV contract, checkpoints, policies, locks, trackers)
    ["running.config"],  # the command line and conf/ into a checked RunSpec
    ["running.loop"],  # the generations (episodes) of a run's seeds
    ["running"],  # the run itself: seed grid, processes, run folder, trainers, warm-up, summary
    ["plotting", "bench", "commands", "experiment"],  # what a user calls: figures, benchmarks, the command line, imix_cli.run
]

#: The public names of the package's face (``imix_cli.MixingES``, ...), each imported from its module on first read.
FACE_NAMES = set(ast.literal_eval(next(
    node.value for node in ast.parse((PACKAGE / "__init__.py").read_text()).body
    if isinstance(node, ast.AnnAssign | ast.Assign) and getattr(getattr(node, "target", None) or node.targets[0], "id", "") == "_API"
)))  # fmt: skip


def modules_of(package: Path) -> dict[str, Path]:
    """Dotted name -> path of every module of ``package`` (a folder); a subpackage's ``__init__`` is the subpackage."""
    found = {}
    for path in sorted(package.rglob("*.py")):
        if "__pycache__" in path.parts:
            continue
        parts = (package.name, *path.relative_to(package).with_suffix("").parts)
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imports_of(name: str, path: Path, modules: dict[str, Path], root: str) -> set[str]:
    """The modules of ``modules`` that module ``name`` imports (anywhere in its code), ``root`` (the package's
    face) standing for a constant of the face, ``root.<public name>`` for one of its lazily loaded names."""
    is_package = path.name == "__init__.py"
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the module's own package (or above)
                base = name.split(".") if is_package else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                module = ".".join([*base, node.module] if node.module else base)
            else:
                module = node.module or ""
            targets = [f"{module}.{alias.name}" if f"{module}.{alias.name}" in modules else module for alias in node.names]
            if module == root:
                targets = [f"{root}.{alias.name}" if alias.name in FACE_NAMES else t for alias, t in zip(node.names, targets)]
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", None)) == "import_module":
            targets = [a.value for a in node.args[:1] if isinstance(a, ast.Constant) and isinstance(a.value, str)]
        else:
            continue
        for target in targets:
            if target.split(".")[0] != root:
                continue
            if target.count(".") != 1 or target.split(".")[1] not in FACE_NAMES:
                while target not in modules and "." in target:  # a name inside a module: the module
                    target = target.rsplit(".", 1)[0]
            found.add(target)
    found.discard(name)
    return found


def with_packages(name: str, targets: set[str], modules: dict[str, Path], root: str) -> set[str]:
    """``targets`` and the packages Python runs to import them: importing ``a.b.c`` runs ``a/__init__`` and
    ``a/b/__init__`` first -- all but the packages module ``name`` itself is in (its import started them already)."""
    found = set(targets)
    for target in targets:
        parts = target.split(".")
        for n in range(2, len(parts)):
            package = ".".join(parts[:n])
            if package in modules and package != root and name != package and not name.startswith(package + "."):
                found.add(package)
    return found


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> the modules it imports, for every module of ``package`` but its face (the root ``__init__``), with
    the packages each import runs (:func:`with_packages`)."""
    modules = modules_of(package)
    root = package.name
    return {name: with_packages(name, imports_of(name, path, modules, root), modules, root) - {root} for name, path in modules.items() if name != root}


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (modules importing each other in a loop), sorted."""
    index, low, stack, on_stack, found, counter = {}, {}, [], set(), [], [0]

    def visit(v: str) -> None:  # Tarjan's algorithm
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def layer_of(module: str, layers: list[list[str]] = LAYERS) -> int | None:
    """The layer of ``<root>.<dotted path>``: that of the longest entry of ``layers`` its path starts with."""
    parts = module.split(".")[1:]
    for n in range(len(parts), 0, -1):
        layer = next((k for k, names in enumerate(layers) if ".".join(parts[:n]) in names), None)
        if layer is not None:
            return layer
    return None


def climbing(graph: dict[str, set[str]], layers: list[list[str]] = LAYERS) -> list[str]:
    """``a -> b`` for every import of a module of a higher layer (and of a public name of the face, which loads one)."""
    root_names = {f"{m.split('.')[0]}.{n}" for m in graph for n in FACE_NAMES}
    out = []
    for module, deps in sorted(graph.items()):
        mine = layer_of(module, layers)
        for dep in sorted(deps):
            if dep in root_names or (mine is not None and (layer_of(dep, layers) or 0) > mine):
                out.append(f"{module} -> {dep}")
    return out


GRAPH = import_graph()


def test_every_module_has_a_layer():
    assert [module for module in GRAPH if layer_of(module) is None] == []


def test_no_module_imports_a_layer_above_its_own():
    assert climbing(GRAPH) == []


def test_no_modules_import_each_other_in_a_circle():
    assert circles(GRAPH) == []


def test_the_numerical_library_imports_nothing_of_running_commands_or_plotting():
    outside = [f"{m} -> {d}" for m, deps in GRAPH.items() if m.startswith("imix_cli.core") for d in deps if not d.startswith("imix_cli.core")]
    assert outside == []


def test_at_most_twelve_modules_at_the_top_of_the_package():
    assert len(list(PACKAGE.glob("*.py"))) <= 12


def parameter_counts(package: Path, limit: int) -> list[str]:
    """Every function or method of ``package`` that takes more than ``limit`` parameters (``self``/``cls`` not
    counted; ``*args``/``**kwargs`` count one each), as ``path:line name (n)``."""
    found = []
    for path in sorted(package.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                a = node.args
                names = [*a.posonlyargs, *a.args, *a.kwonlyargs, *(x for x in (a.vararg, a.kwarg) if x)]
                n = len(names) - (1 if names and names[0].arg in ("self", "cls") else 0)
                if n > limit:
                    found.append(f"{path.relative_to(package.parent)}:{node.lineno} {node.name} ({n})")
    return found


def test_no_function_takes_more_than_twelve_parameters():
    """A function of more parameters is a record in pieces (the compiled loop's chunk took 44, by position): the
    pieces that travel together go as one tuple or record. Compiled kernels too: numba types a tuple's fields."""
    assert parameter_counts(PACKAGE, 12) == []


def _write_package(pkg, files: dict):
    """A toy package written to ``pkg``: relative path -> source; returns ``pkg``."""
    for rel, text in files.items():
        (pkg / rel).parent.mkdir(parents=True, exist_ok=True)
        (pkg / rel).write_text(text)
    return pkg


def test_the_checker_finds_a_planted_upward_import_and_a_planted_circle(tmp_path):
    """A package written to a temporary folder, with one import that climbs (inside a function, relative) and one
    circle (through a deferred import): both found; the same package without them: nothing found."""
    pkg = _write_package(
        tmp_path / "toy",
        {
            "__init__.py": "",
            "base/__init__.py": "",
            "base/a.py": "from toy.base import b\n",
            "base/b.py": "def f():\n    from ..top import cli  # climbs\n",
            "base/c.py": "import toy.base.d\n",
            "base/d.py": "def g():\n    from toy.base.c import h  # closes the circle c -> d -> c\n",
            "top/__init__.py": "",
            "top/cli.py": "from toy.base import c\n",
        },
    )
    layers = [["base"], ["top"]]
    graph = import_graph(pkg)
    assert graph["toy.base.b"] == {"toy.top", "toy.top.cli"} and graph["toy.top.cli"] == {"toy.base", "toy.base.c"}
    assert climbing(graph, layers) == ["toy.base.b -> toy.top", "toy.base.b -> toy.top.cli"]
    assert circles(graph) == [["toy.base.c", "toy.base.d"]]
    (pkg / "base/b.py").write_text("def f():\n    pass\n")
    (pkg / "base/d.py").write_text("def g():\n    pass\n")
    graph = import_graph(pkg)
    assert climbing(graph, layers) == [] and circles(graph) == []


def test_the_checker_sees_the_packages_an_import_runs(tmp_path):
    """A registry whose deferred loader imports a module of a package whose ``__init__`` imports the registry: a loop
    through the package's ``__init__``, found; a module of a package importing its sibling is none."""
    pkg = _write_package(
        tmp_path / "toy",
        {
            "__init__.py": "",
            "registry.py": "def load():\n    from toy.algos.one import One  # runs toy/algos/__init__ first\n",
            "algos/__init__.py": "from toy.algos.one import One\nfrom toy.registry import load\n",
            "algos/one.py": "from toy.algos import two\n",
            "algos/two.py": "",
        },
    )
    graph = import_graph(pkg)
    assert graph["toy.registry"] == {"toy.algos", "toy.algos.one"} and graph["toy.algos.one"] == {"toy.algos.two"}
    assert circles(graph) == [["toy.algos", "toy.registry"]]
    (pkg / "algos/__init__.py").write_text("from toy.algos.one import One\n")
    assert circles(import_graph(pkg)) == []


def test_the_checker_on_a_synthetic_graph():
    graph = {"p.low": {"p.high"}, "p.high": {"p.low2"}, "p.low2": {"p.low"}, "p.alone": set()}
    assert circles(graph) == [["p.high", "p.low", "p.low2"]]
    assert climbing(graph, [["low", "low2", "alone"], ["high"]]) == ["p.low -> p.high"]


def test_import_imix_cli_loads_neither_numpy_nor_gymnasium():
    code = "import sys, imix_cli; print(sorted(m for m in ('numpy', 'gymnasium') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_import_imix_cli_leaves_the_users_blas_threads_alone_and_imix_workers_get_one():
    """The one-BLAS-thread default belongs to imix's own processes: the importing process keeps its
    environment (also after reading the public API), a worker spawned by imix gets 1."""
    import os

    code = (
        "import os, multiprocessing as mp, imix_cli; imix_cli.MixingES; imix_cli.run\n"
        "from imix_cli.core.processes import one_blas_thread\n"
        "print(sorted(v for v in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS') if v in os.environ))\n"
        "if __name__ == '__main__':\n"
        "    ctx = mp.get_context('spawn')\n"
        "    with one_blas_thread(), ctx.Pool(1) as pool:\n"
        "        print(pool.apply(os.getenv, ('OPENBLAS_NUM_THREADS',)))\n"
        "    print(sorted(v for v in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS') if v in os.environ))\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env).stdout.split("\n")
    assert out[:3] == ["[]", "1", "[]"]


def test_every_compiled_kernel_lives_in_the_core():
    """The generation's logic -- the archive, a mixed generation's fitness, the mixing -- is written in ``core/`` only:
    the compiled generation too (``core/mixing/compiled_generation.py``), which the run's loop calls with a seed's arrays.
    A compiled kernel outside ``core/`` would be a second copy of some of it (the compiled chunk once sat in
    ``running/loop/compiled_loop.py``: made to fail by it, naming that file)."""
    from imix_cli.core.numerics import numba_cache

    outside = [str(p.relative_to(PACKAGE)) for p in numba_cache.compiled_sources() if p.relative_to(PACKAGE).parts[0] != "core"]
    assert not outside, f"compiled code outside core/: {outside}"
