"""How often glibc's two builds of its math functions disagree: the reason for imix_cli.core.numerics.elementary.

glibc's x86-64 libm picks, when a program starts, an FMA-compiled build of several functions on CPUs
with FMA and AVX2 and a plain SSE2 build on the others (``GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA``
makes it pick the SSE2 one, as on a CPU without FMA). This script calls the C library (ctypes) on the
same random inputs in two processes, one per build, and counts the results that differ in any bit:

    python benchmarks/libm_variants.py              # 200,000 inputs per function

It needs glibc on an x86-64 CPU with FMA (otherwise both processes run the same build and it says so).
"""

import os
import subprocess
import sys

import numpy as np

N = 200_000
FUNCTIONS = ("exp", "log", "log1p", "expm1", "tanh", "sin", "cos", "pow")


def _inputs():
    rng = np.random.default_rng(1)
    return {
        "exp": rng.uniform(-30, 30, N), "log": np.exp(rng.uniform(-30, 30, N)), "log1p": rng.uniform(-0.999, 3, N),
        "expm1": rng.uniform(-3, 44, N), "tanh": rng.normal(0, 3, N), "sin": rng.uniform(-20, 20, N), "cos": rng.uniform(-20, 20, N),
        "pow": (rng.uniform(0.5, 1.0, N), rng.uniform(0, 2000, N)),
    }  # fmt: skip


def _dump(path: str) -> None:
    import ctypes

    libm = ctypes.CDLL("libm.so.6")
    out = {}
    for name, xs in _inputs().items():
        f = getattr(libm, name)
        f.restype = ctypes.c_double
        if name == "pow":
            f.argtypes = [ctypes.c_double, ctypes.c_double]
            out[name] = np.array([f(float(a), float(b)) for a, b in zip(*xs)])
        else:
            f.argtypes = [ctypes.c_double]
            out[name] = np.array([f(float(x)) for x in xs])
    np.savez(path, **out)


def main() -> int:
    if len(sys.argv) == 3 and sys.argv[1] == "--dump":
        _dump(sys.argv[2])
        return 0
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        paths = {}
        for build, tunables in (("FMA", None), ("SSE2", "glibc.cpu.hwcaps=-AVX2,-FMA")):
            env = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES"}
            if tunables:
                env["GLIBC_TUNABLES"] = tunables
            paths[build] = os.path.join(tmp, f"{build}.npz")
            subprocess.run([sys.executable, __file__, "--dump", paths[build]], env=env, check=True)
        fma, sse2 = np.load(paths["FMA"]), np.load(paths["SSE2"])
        print("| function | inputs | results that differ between glibc's FMA and SSE2 builds |\n|---|---:|---:|")
        for name in FUNCTIONS:
            differ = int(np.sum(fma[name].view(np.int64) != sse2[name].view(np.int64)))
            print(f"| {name} | {N:,} | {differ} ({differ / N:.3%}) |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
