"""Fixtures shared by several test files.

The test process is one of imix's own: it gets imix's one-BLAS-thread default before anything loads
numpy (``import imix_cli`` no longer sets it; tiny CMA-ES matrices on two BLAS threads of a loaded
2-core machine ran ~5x slower). The test of the library's promise runs in a subprocess of its own.
"""

import errno
import importlib.util
from pathlib import Path

import pytest

from imix_cli.core.processes import set_one_blas_thread

set_one_blas_thread()


def interrupted_run(common: list[str], results_dir: Path, after: int):
    """Start ``imix run common`` in-process and stop it after ``after`` generations (the progress counts of the
    run's seeds, summed: with one seed, its generations); return its spec."""
    from imix_cli.running.config.compose import validate_overrides
    from imix_cli.running.run_folder import prepare_run_dir
    from imix_cli.running.runner import run_seeds

    (spec,) = validate_overrides([*common, f"results_dir={results_dir}"])
    todo = prepare_run_dir(spec)
    done = {"n": 0}

    def interrupt(n):
        done["n"] += n
        if done["n"] >= after:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_seeds(spec, todo, progress=interrupt)
    return spec


@pytest.fixture
def csv_disk_full(monkeypatch):
    """Every fsync of a seed CSV being written (its ``.seed_*.csv.*`` temporary; not a checkpoint's) fails with ENOSPC, as on a full disk."""
    import imix_cli.running.files.results as results_module

    real_fsync = results_module.os.fsync

    def fsync_fails_for_csvs(fd):
        name = Path(f"/proc/self/fd/{fd}").resolve().name
        if name.startswith(".seed_") and ".csv." in name:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_fsync(fd)

    monkeypatch.setattr(results_module.os, "fsync", fsync_fails_for_csvs)


# One mechanism for the tests of an optional extra: the marker named after it. A test that needs an
# extra carries @pytest.mark.<extra> (or its module sets pytestmark) and is skipped, with the install
# line in the reason, where one of the extra's modules is not importable. `make test` after a plain
# `make install` therefore passes, and CI runs exactly these tests after `make install-all` with
# -m "<extra> or ...". tests/test_optional_markers.py checks that no test imports an optional module
# without its marker.
EXTRAS = {
    # marker: (the modules it needs, how to install them)
    "mujoco": (("mujoco",), 'pip install ".[mujoco]"'),
    "ddpg": (("torch", "stable_baselines3"), 'pip install torch==2.13.0 ".[ddpg]"'),
    "cluster": (
        ("joblib", "ray", "hydra_plugins.hydra_joblib_launcher", "hydra_plugins.hydra_submitit_launcher", "hydra_plugins.hydra_ray_launcher"),
        'pip install ".[cluster]"',
    ),
    "tensorboard": (("tensorboard",), 'pip install ".[tensorboard]"'),
    "docs": (("mkdocs", "mkdocstrings", "material"), 'pip install ".[docs]"'),
    "bbob": (("cocoex", "cocopp"), 'pip install ".[bbob]"'),
    "search": (("optuna",), 'pip install ".[search]"'),
    "peers": (("jax", "evosax", "gymnax"), 'pip install ".[peers]"'),
    "ars": (("sb3_contrib", "stable_baselines3", "torch", "mujoco"), 'pip install torch==2.13.0 ".[ars]"'),
    "mlflow": (("mlflow",), 'pip install ".[mlflow]"'),
    "wandb": (("wandb",), 'pip install ".[wandb]"'),
    # not an extra of imix: an outside reference the statistics are checked against
    "rliable": (("rliable",), "pip install rliable"),
}

#: The extras `make install-all` installs (pyproject's `all`): CI runs their tests with -m "mujoco or ddpg or ...".
INSTALL_ALL = ("mujoco", "ddpg", "cluster", "tensorboard", "docs", "bbob", "search")


def importable(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a missing parent package (hydra_plugins) raises instead of returning None
        return False


def missing_modules(extra: str) -> list[str]:
    return [module for module in EXTRAS[extra][0] if not importable(module)]


def extra_installed(extra: str) -> bool:
    """For a marked module's guarded imports (it is collected, then skipped by its marker, without the extra)."""
    return not missing_modules(extra)


def covering_grid(first: list, second: list) -> list:
    """Every pair of ``first`` × ``second`` as a parameter (id ``a-b``, as two stacked parametrizes give);
    ``make test-fast`` keeps a subset where each value of either list appears at least once (the i-th of
    the longer list with the (i mod n)-th of the shorter), the other pairs are marked slow (``make test``
    runs them all). For grids of subprocess tests, whose every pair costs a process start (1-4 s)."""
    longer = max(len(first), len(second))
    kept = {(first[i % len(first)], second[i % len(second)]) for i in range(longer)}
    return [pytest.param(a, b, id=f"{a}-{b}", marks=() if (a, b) in kept else pytest.mark.slow) for a in first for b in second]


def pytest_configure(config):
    for extra, (modules, install) in EXTRAS.items():
        config.addinivalue_line("markers", f"{extra}: needs {', '.join(modules)} ({install}); skipped without them")


def pytest_collection_modifyitems(config, items):
    missing = {extra: missing_modules(extra) for extra in EXTRAS}
    for item in items:
        for extra in EXTRAS:
            if missing[extra] and item.get_closest_marker(extra) is not None:
                item.add_marker(pytest.mark.skip(reason=f"needs the {extra} extra ({EXTRAS[extra][1]}): {', '.join(missing[extra])} not importable"))
                break
