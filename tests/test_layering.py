"""Import layering: ``import imix_cli`` stays light, and no module imports a layer above its own.

Made to fail by putting ``from imix_cli import envs`` back into ``imix_cli/__init__.py`` (gymnasium
loads) and by importing :mod:`imix_cli.config` from :mod:`imix_cli.parallel_evaluation`."""

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "imix_cli"

#: Lowest first; a module may import its own layer and those before it (names are module prefixes).
LAYERS = [
    [
        "registry",
        "config_keys",
        "messages",
        "processes",
        "keyvalue",
        "stats",
        "safe_npz",
        "linalg_kernels",
        "distributions",
        "mixing",
        "mixing_kernels",
        "results",
    ],
    [
        "generation",
        "ask_tell",
        "tracking",
        "algorithms",
        "divergence",
        "envs",
        "env_ids",
        "policies",
        "evaluation",
        "parallel_evaluation",
        "checkpoints",
        "policy_files",
    ],
    ["config_checks", "run_spec", "es_config", "ddpg_config", "config"],
    ["lockstep", "warmup", "trainers", "resume", "run_folder", "es_seeds", "ddpg_seeds", "pool", "summary", "runner"],
    ["evaluate", "render", "status", "plotting", "bench", "experiment", "cli"],
]


#: Upward imports a module may make inside a function only (when called, never when the module loads), and why:
#: the registry names each ES class and each built-in's evaluator by a loader function that imports it.
DEFERRED_ONLY = {"imix_cli.registry": ("imix_cli.algorithms.", "imix_cli.evaluation")}


def _layer(module: str) -> int | None:
    top = module.split(".")[1] if module.count(".") else None
    return next((k for k, names in enumerate(LAYERS) if top in names), None)


def _imports(path: Path, top_level: bool = False) -> set[str]:
    """The imix_cli modules ``path`` imports (``top_level``: those its body imports when it loads)."""
    tree = ast.parse(path.read_text())
    found = set()
    for node in tree.body if top_level else ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("imix_cli."):
            found.add(node.module)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module == "imix_cli":
            found.update(f"imix_cli.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("imix_cli."))
    return found


def test_no_module_imports_a_layer_above_its_own():
    upward = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = ".".join(("imix_cli", *path.relative_to(PACKAGE).with_suffix("").parts))
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
        "from imix_cli.processes import one_blas_thread\n"
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
