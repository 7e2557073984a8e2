"""Import layering: ``import imix_cli`` stays light, and no module imports a layer above its own.

Made to fail by putting ``from imix_cli import envs`` back into ``imix_cli/__init__.py`` (gymnasium
loads) and by importing :mod:`imix_cli.running.config.compose` from :mod:`imix_cli.core.parallel_evaluation`."""

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "imix_cli"

#: Lowest first; a module may import its own layer and those before it. An entry names a module or a
#: subpackage by its dotted path below ``imix_cli``; a module's layer is that of the longest entry its
#: dotted path starts with. The library is the top-level modules (``imix_cli.core.mixing``, ...);
#: ``running`` (what ``imix run`` does) and ``ddpg`` (the DDPG baseline) span several layers module by
#: module, and their own entries (their ``__init__``, and any module not listed yet) are the lowest.
LAYERS = [
    [
        "registry",
        "bounds",
        "messages",
        "processes",
        "stats",
        "numba_cache",
        "elementary",
        "elementary_tables",
        "linalg_kernels",
        "numerics",
        "distributions",
        "mixing",
        "mixing_kernels",
        "running",
        "running.safe_npz",
        "running.results",
        "writing",
        "ddpg",
        "ddpg.settings",
        "adapters",  # other libraries' ES seen as imix's (pycma, evosax): they read distributions only
        "adapters.pycma",
        "adapters.evosax",
    ],
    [
        "generation",
        "mirrored",
        "ask_tell",
        "algorithms",
        "divergence",
        "envs",
        "env_ids",
        "policies",
        "evaluation",
        "parallel_evaluation",
        "running.tracking",
        "running.checkpoints",
        "running.policy_files",
        "ddpg.agent",
        "adapters.checkpoint",
    ],
    ["running.config_checks", "running.config_keys", "running.run_spec", "running.es_config", "ddpg.config", "running.config"],
    [
        "running.lockstep",
        "running.compiled_loop",
        "running.warmup",
        "running.trainers",
        "running.seed_checks",
        "running.resume",
        "running.run_folder",
        "running.run_writer",
        "running.es_seeds",
        "ddpg.seeds",
        "running.pool",
        "running.summary",
        "running.runner",
    ],
    ["commands", "plotting", "bench", "experiment"],
]


#: Upward imports a module may make inside a function only (when called, never when the module loads), and why:
#: the registry names each ES class and each built-in's evaluator by a loader function that imports it.
DEFERRED_ONLY = {"imix_cli.core.registry": ("imix_cli.core.algorithms.", "imix_cli.core.evaluation")}


def _layer(module: str) -> int | None:
    """The layer of ``imix_cli.<dotted path>`` (a module, or a name imported from one), None outside LAYERS."""
    parts = module.split(".")[1:]
    for n in range(len(parts), 0, -1):
        layer = next((k for k, names in enumerate(LAYERS) if ".".join(parts[:n]) in names), None)
        if layer is not None:
            return layer
    return None


def _imports(path: Path, top_level: bool = False) -> set[str]:
    """What ``path`` imports of imix_cli, as ``imix_cli.<module>.<name>`` (``top_level``: what its body
    imports when it loads). ``from imix_cli.running import config`` is ``imix_cli.running.config.compose``: the
    name imported may be a module, so it is part of the path whose layer counts."""
    tree = ast.parse(path.read_text())
    found = set()
    for node in tree.body if top_level else ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "imix_cli":
            found.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("imix_cli."))
    return found


def _modules():
    """(dotted name, path) of every module of the package; a subpackage's ``__init__`` is the subpackage."""
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        yield ".".join(("imix_cli", *(parts[:-1] if parts[-1] == "__init__" else parts))), path


def test_every_module_has_a_layer():
    assert [module for module, _ in _modules() if module != "imix_cli" and _layer(module) is None] == []


def test_no_module_imports_a_layer_above_its_own():
    upward = []
    for module, path in _modules():
        mine = _layer(module)
        if mine is None:
            continue
        deferred, loaded = DEFERRED_ONLY.get(module, ()), _imports(path, top_level=True)
        upward += [
            f"{module} -> {dep}" for dep in sorted(_imports(path))
            if (_layer(dep) or 0) > mine and (dep in loaded or not dep.startswith(deferred))
        ]  # fmt: skip
    assert upward == []


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
