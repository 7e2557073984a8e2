"""The numerics rule in one place (imix_cli.core.numerics): Python code takes exp, log, products ... from the facade.

What must hold: no module computes on a run's path with numpy's, math's or BLAS's versions of what the facade
gives (their last bits depend on the CPU), nor reaches past the facade for the Python-callable kernels; and the
facade's scalar and vector forms are the same functions.
"""

import ast
from pathlib import Path

import numpy as np
from numba.core.registry import CPUDispatcher

import imix_cli
from imix_cli.core import numerics as xp
from imix_cli.core.numerics import elementary, linalg_kernels

PACKAGE = Path(imix_cli.__file__).parent
#: The numerical library itself: the kernels and the facade (they define what the others call).
LIBRARY = {f"core/numerics/{name}" for name in ("__init__.py", "elementary.py", "elementary_tables.py", "linalg_kernels.py", "numba_cache.py")}
LIBRARY |= {"core/mixing/kernels.py", "core/envs/kernels.py", "core/envs/mujoco_kernels.py"}
#: Code outside a run's numbers: commands, benchmarks, figures, adapters to other libraries, DDPG (torch).
OUTSIDE = ("commands/", "bench/", "plotting/", "core/adapters/", "core/ddpg/")
#: What the facade replaces: numpy's and math's functions of these names (and ``@``, np.linalg's solvers).
NUMPY_NAMES = {"exp", "log", "log1p", "expm1", "tanh", "power", "dot", "matmul", "vdot", "inner"}
MATH_NAMES = {"exp", "log", "log1p", "expm1", "tanh", "pow"}
#: Known, documented exceptions: (module, what) -- each says why in its module.
ALLOWED = {
    ("core/envs/continuous_cartpole.py", "np.cos"),  # the gymnasium env's own Python step (the compiled episodes use elementary)
    ("core/envs/continuous_cartpole.py", "np.sin"),
    # ARS's step: BLAS's product, numpy's bits (numba's np.dot, compiled): a fixed order would change ARS's numbers
    ("core/algorithms/ars.py", "np.dot"),
}


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        name = path.relative_to(PACKAGE).as_posix()
        if name not in LIBRARY and not name.startswith(OUTSIDE):
            yield name, ast.parse(path.read_text())


def _violations(name: str, tree: ast.AST) -> list[str]:
    found = []
    # compiled code (@njit functions) calls the kernels themselves: the numba functions of the two modules
    compiled_only = {alias: {n for n, v in vars(m).items() if isinstance(v, CPUDispatcher)} for alias, m in (("lk", linalg_kernels), ("el", elementary))}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module in ("imix_cli.core.numerics.elementary", "imix_cli.core.numerics.linalg_kernels"):
            found.append(f"from {node.module} import ...")
        elif isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult):
            found.append("@")
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            what = f"{node.value.id}.{node.attr}"
            if node.value.id == "np" and node.attr in NUMPY_NAMES | {"sin", "cos"} or node.value.id == "math" and node.attr in MATH_NAMES:
                found.append(what)
            elif node.value.id in compiled_only and (node.attr not in compiled_only[node.value.id] or node.attr.startswith("math_")):
                found.append(what)  # a Python-callable kernel: xp's name instead
        elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute) and getattr(node.value.value, "id", None) == "np":
            if node.value.attr == "linalg" and node.attr != "LinAlgError":
                found.append(f"np.linalg.{node.attr}")
    return [f"{name}: {w}" for w in found if (name, w) not in ALLOWED]


def test_python_code_takes_its_math_from_the_facade():
    modules = dict(_modules())
    assert "core/algorithms/snes.py" in modules and "core/mixing/__init__.py" in modules and len(modules) > 40
    bad = [v for name, tree in modules.items() for v in _violations(name, tree)]
    assert not bad, bad


def test_the_rule_sees_what_it_forbids():
    planted = "import math\nimport numpy as np\nfrom imix_cli import linalg_kernels as lk\n"
    planted += "a = np.exp(x) + math.log(y) + lk.dot(x, x) + (x @ x) + np.linalg.eigh(c)[0] + lk.vec_mat_kernel(u, x)\n"
    assert sorted(_violations("x.py", ast.parse(planted))) == sorted(["x.py: np.exp", "x.py: math.log", "x.py: lk.dot", "x.py: @", "x.py: np.linalg.eigh"])


def test_scalar_and_vector_forms_are_the_same_functions():
    v = np.random.default_rng(5).uniform(-30, 30, 257)
    pos = np.abs(v) + 1e-300
    assert [xp.exp(float(x)) for x in v] == xp.exp(v).tolist()
    assert [xp.log(float(x)) for x in pos] == xp.log(pos).tolist()
    assert type(xp.exp(np.float64(1.5))) is float and type(xp.log(2)) is float
    assert xp.log1p(-1.0) == -np.inf and xp.power(2.0, 10.0) == 1024.0


def test_the_written_out_constants_are_the_facades_and_importing_imix_runs_no_kernel():
    """log(2 pi) is written out (elementary.LOG_2PI, for the Gaussians' and mixing's log densities): a kernel called at import starts numba
    (~1.5 s) in every process, one that only refuses a bad key included. Importing the config, the ES registry and
    mixing must leave every imix kernel unloaded."""
    import subprocess
    import sys

    assert xp.LOG_2PI == elementary.LOG_2PI == xp.log(2.0 * np.pi)
    probe = (
        "import sys\n"
        "import imix_cli.running.config.compose, imix_cli.core.algorithms, imix_cli.core.mixing, imix_cli.commands.cli\n"
        "from numba.core.registry import CPUDispatcher\n"
        "loaded = sorted(f'{m}.{k}' for m, mod in list(sys.modules.items()) if m.startswith('imix_cli')\n"
        "                for k, v in vars(mod).items() if isinstance(v, CPUDispatcher) and v.overloads)\n"
        "print(' '.join(loaded))\n"
    )
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "", f"kernels loaded at import: {proc.stdout.strip()}"
