"""Same seed, same numbers, whatever BLAS kernel, SIMD code path or C-library build the CPU selects.

numpy hands matrix products, ``np.dot`` and ``np.linalg`` to OpenBLAS, which picks a kernel for
the CPU at start-up (``OPENBLAS_CORETYPE`` forces one). Kernels sum in different orders, so
results computed through BLAS differ in the last bits from one CPU to the next, and an ES
amplifies those bits into different runs (the main job's final mean was 192.46 / 194.24 /
193.27 under Prescott / Haswell / SkylakeX before imix computed its linear algebra in compiled
loops with one fixed order: :mod:`imix_cli.core.numerics.linalg_kernels`). Each test here runs a small job
in fresh processes under each kernel and requires every CSV to be identical (but for
``wall_time``); a last run also switches off numpy's AVX-512/AVX2 code paths
(``NPY_DISABLE_CPU_FEATURES``), as on a CPU without them, and another makes glibc run the SSE2 build
of its math functions instead of the FMA one (``GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA``), as on a
CPU without FMA: before imix computed exp, log, pow, tanh, sin and cos itself (:mod:`imix_cli.core.numerics.elementary`),
every SNES seed of the main job ran a different search from generation 6-15 on under it.

The whole-run tests (the main job, CMA-ES: five fresh processes each, ~40 s of CPU together) check a
property of what was installed (numpy's OpenBLAS, glibc), so they run in ``make test-install`` (CI runs it
on every fresh clone); ``make test`` keeps the TPA points test, which goes through the same kernels.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

IMIX = str(Path(sys.executable).parent / "imix")
CORETYPES = ("Prescott", "Haswell", "SkylakeX")


def _numpy_dispatched_features() -> str:
    """The CPU features numpy dispatches to on this machine above its baseline (disabled in the last run)."""
    from numpy._core._multiarray_umath import __cpu_baseline__, __cpu_dispatch__, __cpu_features__

    return " ".join(f for f in __cpu_dispatch__ if __cpu_features__.get(f) and f not in __cpu_baseline__)


def _glibc_has_fma_build() -> bool:
    """Whether the C library here is glibc on an x86-64 CPU with FMA, so that masking FMA/AVX2 (GLIBC_TUNABLES)
    changes which build of its math functions runs."""
    import platform

    flags = (
        next((line.split() for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags")), [])
        if Path("/proc/cpuinfo").exists()
        else []
    )
    return platform.machine() == "x86_64" and platform.libc_ver()[0] == "glibc" and {"fma", "avx2"} <= set(flags)


def _outputs(root: Path) -> dict:
    """Every seed's CSV (but for ``wall_time``) and saved policies (the mean's and the best member's
    parameters, full float64: the CSVs' 10 significant digits could hide a last-bit difference)."""
    found = sorted(p for p in root.rglob("seed_*.csv") if not p.name.endswith(".partial.csv"))
    assert found, f"no CSV under {root}"
    outputs = {p.relative_to(root): pd.read_csv(p).drop(columns=["wall_time"]) for p in found}
    for p in sorted(root.rglob("policy_*.npz")):
        with np.load(p) as npz:
            outputs[p.relative_to(root)] = {k: npz[k] for k in npz.files}
    return outputs


def _run(args, results_dir: Path, **env) -> dict:
    full_env = {**os.environ, **env}
    proc = subprocess.run([IMIX, "run", *args, f"results_dir={results_dir}", "progress=false"], env=full_env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return _outputs(results_dir)


def _assert_same_everywhere(args, tmp_path, stop_at=None, c_library=True):
    """Every run of ``args`` (which must say ``workers=1``) gives the same files: under each kernel, without
    numpy's dispatched SIMD code, with glibc's SSE2 math functions and, if ``stop_at`` (a generation count) is given, with two workers and
    stopped at ``stop_at`` generations then continued from the checkpoint to the full count."""
    runs = {ct: _run(args, tmp_path / ct, OPENBLAS_CORETYPE=ct) for ct in CORETYPES}
    features = _numpy_dispatched_features()
    if features:
        runs["no numpy SIMD dispatch"] = _run(args, tmp_path / "nosimd", OPENBLAS_CORETYPE="Prescott", NPY_DISABLE_CPU_FEATURES=features)
    if c_library and _glibc_has_fma_build():
        runs["glibc's SSE2 math"] = _run(args, tmp_path / "sse2", GLIBC_TUNABLES="glibc.cpu.hwcaps=-AVX2,-FMA")
    if stop_at is not None:
        two_workers = [a if a != "workers=1" else "workers=2" for a in args]
        assert two_workers != args
        stopped = _run(
            [a if not a.startswith("generations=") else f"generations={stop_at}" for a in two_workers], tmp_path / "resumed", OPENBLAS_CORETYPE="Haswell"
        )
        assert all(len(frame) == stop_at for frame in stopped.values() if isinstance(frame, pd.DataFrame))
        runs["two workers, stopped and continued"] = _run(two_workers, tmp_path / "resumed", OPENBLAS_CORETYPE="Haswell")
    reference_name, reference = next(iter(runs.items()))
    for name, csvs in runs.items():
        assert csvs.keys() == reference.keys()
        for path, found in csvs.items():
            where = f"{path} under {name} vs {reference_name}"
            if isinstance(found, pd.DataFrame):
                pd.testing.assert_frame_equal(found, reference[path], check_exact=True, obj=where)
            else:
                assert found.keys() == reference[path].keys(), where
                for key, array in found.items():
                    np.testing.assert_array_equal(array, reference[path][key], err_msg=f"{where}: {key}", strict=True)
    return reference


@pytest.mark.slow
@pytest.mark.install  # a property of the installed numpy/glibc: make test-install
def test_main_job_is_bit_identical_under_every_blas_kernel(tmp_path):
    outputs = _assert_same_everywhere(["algo=snes", "env=cartpole", "eim=true", "seeds=2", "generations=40", "workers=1"], tmp_path, stop_at=12)
    frames = [f for f in outputs.values() if isinstance(f, pd.DataFrame)]
    assert sum(len(f) for f in frames) == 80 and all(np.isfinite(f["mean_score"]).all() for f in frames)


@pytest.mark.slow
@pytest.mark.install  # a property of the installed numpy/glibc: make test-install
def test_cmaes_is_bit_identical_under_every_blas_kernel(tmp_path):
    # Acrobot: returns rarely tie, so every rank (and so every bit of the update) matters.
    _assert_same_everywhere(["algo=cmaes", "env=acrobot", "eim=true", "seeds=2", "generations=15", "popsize=20", "workers=1"], tmp_path, stop_at=7)


@pytest.mark.slow
@pytest.mark.mujoco
def test_mujoco_linear_run_is_bit_identical_under_every_blas_kernel(tmp_path):
    args = ["algo=snes", "env=swimmer", "eim=true", "policy.hidden=[]", "env.max_steps=100", "seeds=1", "generations=8", "popsize=10", "workers=1"]
    # Not under glibc's SSE2 math: MuJoCo's own library calls the C library's sin, cos, ... in its physics, so
    # its episodes follow the machine's C library (the best member's return moved by an ulp there); what imix
    # computes around them (policies, rewards, mixing, updates) does not.
    _assert_same_everywhere(args, tmp_path, c_library=False)


_TPA_PROBES = """
import hashlib, numpy as np
from imix_cli.core.algorithms.cmaes import CMAES
es, rng, seen = CMAES(130, popsize=50, step_size_control="tpa"), np.random.default_rng(0), hashlib.sha256()
for _ in range(30):
    x = es.ask(rng)
    probes = es.probes(rng)
    f = lambda y: -np.sum(y * y, axis=1)
    es.tell(x, f(x), probe_fitness=None if probes is None else f(probes))
    seen.update(b"" if probes is None else probes.tobytes())
print(seen.hexdigest())
"""


@pytest.mark.slow
def test_cmaes_tpa_points_are_bit_identical_under_every_blas_kernel():
    """CMA-ES's two TPA points scale the last move by two vector lengths; through numpy's BLAS dot
    (``np.linalg.norm``) those differ in the last bits from one kernel to the next. A run's CSVs
    rarely show it (only the points' ranks matter), so the points themselves are compared."""
    digests = {}
    for coretype in CORETYPES:
        env = {**os.environ, "OPENBLAS_CORETYPE": coretype}
        proc = subprocess.run([sys.executable, "-c", _TPA_PROBES], env=env, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr[-2000:]
        digests[coretype] = proc.stdout.strip()
    assert len(set(digests.values())) == 1, digests
