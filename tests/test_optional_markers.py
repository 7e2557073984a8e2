"""Every test that needs an optional extra says so with the extra's marker (tests/conftest.py: EXTRAS),
so that `make install` then `make test` passes without any extra, and CI runs exactly the extras' tests
after `make install-all`.

This file imports nothing optional: it reads the test files' source (ast) and finds, per test, the
optional modules it imports (in its body, in the module's top level, or in a helper of the same file
it calls), the MuJoCo envs it runs, and any ``pytest.importorskip`` or ``find_spec`` skip of an
optional module (a second mechanism, which this one replaces).
"""

import ast
import re
from pathlib import Path

from conftest import EXTRAS

TESTS = Path(__file__).resolve().parent

#: top-level module -> the markers any one of which covers it
COVERS: dict[str, set[str]] = {}
for _extra, (_modules, _install) in EXTRAS.items():
    for _module in _modules:
        COVERS.setdefault(_module.split(".")[0], set()).add(_extra)
#: the cluster extra's launcher plugins live in the namespace package hydra_plugins
COVERS["hydra_plugins"] = {"cluster"}
COVERS["sb3_contrib"] = {"ars"}
#: MuJoCo envs given to `imix run` in a test's strings (env=hopper): running them needs the mujoco module (mujoco or ars marker)
MUJOCO_ENV = re.compile(r"\benv=(swimmer|hopper|halfcheetah|walker2d|ant)\b")
#: other command-line words a test can give `imix run` that need an extra: the pattern, its markers
NEEDS_EXTRA = [
    (MUJOCO_ENV, {"mujoco", "ars"}),
    (re.compile(r"\bhydra/launcher=(joblib|submitit_local|slurm|ray\w*)|\bevaluator=ray\b"), {"cluster"}),
    (re.compile(r"\blogger=tensorboard\b"), {"tensorboard"}),
    (re.compile(r"\bhydra/sweeper=optuna\b"), {"search"}),
]
#: tests that name such a word on purpose without the extra (the missing-extra message, a config check)
NAMED_NOT_RUN = {
    ("test_mujoco.py", "test_missing_mujoco_names_the_extra_in_one_line"),
    ("test_missing_extra.py", "test_every_missing_extra_is_one_line_from_the_clone_and_exit_2"),  # hides each extra: nothing of it runs
    ("test_bad_input.py", "test_malformed_invocation"),  # its joblib case is a pytest.param with the cluster mark
    ("test_bad_values_sweeps_and_signals.py", "test_fast_validation_composes_what_hydra_composes"),  # adds its joblib point if extra_installed("cluster")
    ("test_optional_markers.py", "test_the_check_finds_an_unmarked_import_a_helpers_import_an_importorskip_and_a_mujoco_env"),
}


def _imported_roots(node: ast.AST) -> set[str]:
    roots = set()
    for sub in ast.walk(node):
        if isinstance(sub, ast.Import):
            roots |= {alias.name.split(".")[0] for alias in sub.names}
        elif isinstance(sub, ast.ImportFrom) and sub.module and sub.level == 0:
            roots.add(sub.module.split(".")[0])
    return {root for root in roots if root in COVERS}


def _skip_mechanisms(node: ast.AST) -> list[str]:
    """``pytest.importorskip("x")`` / ``find_spec("x")`` of an optional module: the second mechanism."""
    found = []
    for sub in ast.walk(node):
        if isinstance(sub, ast.Call) and sub.args and isinstance(sub.args[0], ast.Constant) and isinstance(sub.args[0].value, str):
            name = sub.func.attr if isinstance(sub.func, ast.Attribute) else getattr(sub.func, "id", "")
            if name in ("importorskip", "find_spec") and sub.args[0].value.split(".")[0] in COVERS:
                found.append(f"{name}({sub.args[0].value!r})")
    return found


def _markers(decorators: list[ast.expr]) -> set[str]:
    names = set()
    for dec in decorators:
        for sub in ast.walk(dec):
            if isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Attribute) and sub.value.attr == "mark":
                names.add(sub.attr)
    return names


def _module_markers(tree: ast.Module) -> set[str]:
    names, aliases = set(), {}
    for stmt in tree.body:
        if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 and isinstance(stmt.targets[0], ast.Name):
            marks = _markers([stmt.value])
            if stmt.targets[0].id == "pytestmark":
                names |= marks
            elif marks:
                aliases[stmt.targets[0].id] = marks  # needs_mujoco = pytest.mark.mujoco
    return names, aliases


def _functions(tree: ast.Module):
    """(name, node, decorators) of the module's functions and its classes' methods (a class's decorators apply to its methods)."""
    for stmt in tree.body:
        if isinstance(stmt, ast.FunctionDef):
            yield stmt.name, stmt, stmt.decorator_list
        elif isinstance(stmt, ast.ClassDef):
            for sub in stmt.body:
                if isinstance(sub, ast.FunctionDef):
                    yield f"{stmt.name}.{sub.name}", sub, [*stmt.decorator_list, *sub.decorator_list]


def _strings(node: ast.AST) -> str:
    return "\n".join(sub.value for sub in ast.walk(node) if isinstance(sub, ast.Constant) and isinstance(sub.value, str))


def violations(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    module_marks, aliases = _module_markers(tree)
    top_level = [stmt for stmt in tree.body if not isinstance(stmt, ast.FunctionDef | ast.ClassDef)]
    functions = {name: (node, decorators) for name, node, decorators in _functions(tree)}
    needs = {name: _imported_roots(node) for name, (node, _) in functions.items()}
    # a helper's optional imports are its callers' too (to a fixed point: helpers calling helpers)
    calls = {name: {sub.id for sub in ast.walk(node) if isinstance(sub, ast.Name)} for name, (node, _) in functions.items()}
    changed = True
    while changed:
        changed = False
        for name in functions:
            for callee in calls[name] & functions.keys():
                if not needs[callee] <= needs[name]:
                    needs[name] |= needs[callee]
                    changed = True
    problems = [f"{path.name}: {found}: use the extra's marker (tests/conftest.py EXTRAS) instead" for found in _skip_mechanisms(tree)]
    module_needs = set().union(*(_imported_roots(stmt) for stmt in top_level)) if top_level else set()
    for root in sorted(module_needs):
        if not COVERS[root] & module_marks:
            problems.append(f"{path.name}: imports {root} at the top level without pytestmark = pytest.mark.<{'|'.join(sorted(COVERS[root]))}>")
    for name, (node, decorators) in functions.items():
        if not name.split(".")[-1].startswith("test"):
            continue
        marks = module_marks | _markers(decorators) | set().union(*(aliases.get(getattr(d, "id", ""), set()) for d in decorators))
        for root in sorted(needs[name]):
            if not COVERS[root] & marks:
                problems.append(f"{path.name}::{name} imports {root} without @pytest.mark.<{'|'.join(sorted(COVERS[root]))}>")
        for pattern, markers in NEEDS_EXTRA:
            found = pattern.search(_strings(node))
            if found and (path.name, name) not in NAMED_NOT_RUN and not markers & marks:
                problems.append(f"{path.name}::{name} runs {found.group(0)} without @pytest.mark.<{'|'.join(sorted(markers))}>")
    return problems


def test_every_test_that_needs_an_extra_carries_its_marker():
    problems = [problem for path in sorted(TESTS.glob("test_*.py")) for problem in violations(path)]
    assert not problems, "\n".join(problems)


def test_the_check_finds_an_unmarked_import_a_helpers_import_an_importorskip_and_a_mujoco_env(tmp_path):
    """The check itself: each of these four unmarked tests is reported, and their marked twins are not."""
    sample = tmp_path / "test_sample.py"
    sample.write_text(
        "import pytest\n\n"
        "def _helper():\n    import torch\n\n"
        "def test_direct():\n    import ray\n\n"
        "def test_through_helper():\n    _helper()\n\n"
        "def test_skip():\n    pytest.importorskip('mkdocs')\n\n"
        "def test_env():\n    main(['run', 'env=hopper'])\n\n"
        "@pytest.mark.cluster\ndef test_direct_marked():\n    import ray\n\n"
        "@pytest.mark.ddpg\ndef test_through_helper_marked():\n    _helper()\n\n"
        "@pytest.mark.mujoco\ndef test_env_marked():\n    main(['run', 'env=hopper'])\n"
    )
    found = "\n".join(violations(sample))
    for name in ("test_direct ", "test_through_helper ", "importorskip('mkdocs')", "test_env "):
        assert name in found, found
    assert "marked" not in found, found


def test_ci_runs_the_readmes_two_commands_first_then_only_the_extras_tests():
    """.ci/run starts with the README's set-up and test commands as written (on the fresh clone, no extra
    installed); the extras' tests it runs after `make install-all` are those of every extra `all` installs."""
    import tomllib

    root = TESTS.parent
    readme = (root / "README.md").read_text()
    install_block = re.search(r"## Install\s+```bash\n(.*?)```", readme, re.S).group(1)
    readme_commands = [line.split("#")[0].strip() for line in install_block.splitlines() if line.split("#")[0].strip()]
    ci = [line.strip() for line in (root / ".ci" / "run").read_text().splitlines() if line.strip() and not line.lstrip().startswith("#")]
    # each step may run through the `step` timer (`step make test`): the command is what follows it
    commands = [line.removeprefix("step ") for line in ci[ci.index("rm -rf .venv") + 1 :] if not line.startswith("step()")]
    assert commands[: len(readme_commands)] == readme_commands == ["make install", "make test"], commands
    assert commands[len(readme_commands) :][:3] == ["make test-install", "make install-all", "make test-extras"], commands
    makefile = (root / "Makefile").read_text()
    markers = re.search(r"^EXTRA_TESTS\s*=\s*(.*)$", makefile, re.M).group(1).split(" or ")
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    all_extras = re.search(r"\[(.*)\]", project["all"][0]).group(1).split(",")
    assert sorted(markers) == sorted(set(all_extras) - {"test", "render"}) and all(marker in EXTRAS for marker in markers), markers
