"""imix's numba cache stamp (imix_cli.core.numerics.numba_cache): computed from every compiled source, used by every cached kernel.

What must hold: editing a function recompiles its callers in other files (numba alone keeps their stale
machine code); every cached kernel of the package carries the computed stamp; no stamp is written by hand.
"""

import os
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from imix_cli.core.numerics import numba_cache

_CALLEE = "from numba import njit\n\n\n@njit(cache=True)\ndef f(x):\n    return x + {}\n"
_CALLER = textwrap.dedent(
    """
    from numba import njit
    {}
    from pkg import callee


    @njit(cache=True)
    def g(x):
        return callee.f(x) * 2.0
    """
)


def _run_twice(tmp_path: Path, stamped: bool) -> tuple[str, str]:
    """``g(1.0)`` in a fresh process, before and after ``f`` (another file) changes from x + 1 to x + 2."""
    pkg = tmp_path / ("stamped" if stamped else "plain") / "pkg"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "numba_cache.py").write_text(Path(numba_cache.__file__).read_text())  # stamps its own folder's sources
    (pkg / "caller.py").write_text(_CALLER.format("from pkg import numba_cache  # noqa: F401" if stamped else ""))
    out = []
    for term in ("1.0", "2.0"):
        (pkg / "callee.py").write_text(_CALLEE.format(term))
        done = subprocess.run([sys.executable, "-c", "from pkg import caller; print(caller.g(1.0))"], cwd=pkg.parent, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr[-2000:]
        out.append(done.stdout.strip())
    return tuple(out)


@pytest.mark.slow
def test_an_edit_of_a_callee_in_another_file_recompiles_its_callers(tmp_path):
    assert _run_twice(tmp_path, stamped=False) == ("4.0", "4.0")  # numba alone: the caller's stale machine code
    assert _run_twice(tmp_path, stamped=True) == ("4.0", "6.0")


_CHECK = """
import importlib, sys
modules = [importlib.import_module(name) for name in sys.argv[1:]]  # the package's own imports, in a fresh process
from numba.core.caching import FunctionCache
from numba.core.registry import CPUDispatcher
from imix_cli.core.numerics import numba_cache
assert numba_cache.SOURCE_DIGEST == numba_cache.source_digest()
cached = 0
for module in modules:
    for value in vars(module).values():
        if isinstance(value, CPUDispatcher) and value.py_func.__module__ == module.__name__ and isinstance(value._cache, FunctionCache):
            cached += 1
            locator = value._cache._impl.locator
            assert isinstance(locator, numba_cache._PackageLocator), f"{module.__name__}.{value.__name__} is not stamped"
            assert locator.get_source_stamp()[1] == numba_cache.SOURCE_DIGEST
assert cached > 50, cached  # the elementary functions, the linear algebra, mixing, episodes, the ES updates
"""


def test_every_cached_kernel_of_the_package_carries_the_computed_stamp():
    package = numba_cache.PACKAGE
    names = [".".join(("imix_cli", *p.relative_to(package).with_suffix("").parts)).removesuffix(".__init__") for p in numba_cache.compiled_sources()]
    assert (
        "imix_cli.core.numerics.elementary" in names
        and "imix_cli.core.algorithms.snes" in names
        and "imix_cli.core.mixing.compiled_generation" in names
        and "imix_cli.running.loop.compiled_loop" not in names
    )
    done = subprocess.run([sys.executable, "-c", _CHECK, *sorted(names, key=lambda n: "numba_cache" in n)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]


def test_no_stamp_is_written_by_hand():
    hand_written = [p.name for p in numba_cache.PACKAGE.rglob("*.py") if "numba cache stamp:" in p.read_text()]
    assert not hand_written, hand_written


_SHARED_CHECK = """
import os, sys
sys.prefix = sys.argv[1]  # the environment whose cache folder the package uses (read when the first kernel is made)
if sys.argv[2] == "mtime":  # a numba whose source stamp is the file's mtime and size (as numba's was before it hashed the bytes)
    from numba.core import caching
    caching._SourceFileBackedLocatorMixin.get_source_stamp = lambda self: (os.stat(self._py_file).st_mtime, os.stat(self._py_file).st_size)
from pkg import caller
print(caller.g(1.0), sum(caller.g.stats.cache_hits.values()), sum(caller.g.stats.cache_misses.values()))
"""


@pytest.mark.slow
@pytest.mark.parametrize("numba_stamp", ["content", "mtime"])
def test_two_copies_of_the_same_sources_share_their_compiled_kernels(tmp_path, numba_stamp):
    """The installed package and a source tree with the same files (``make install`` then ``make test``;
    the copies' files have different mtimes): what the first compiled, the second loads, whether numba
    stamps a file by its bytes or by its mtime; a copy that differs compiles its own, beside it."""
    copies = []
    for age, (name, term) in enumerate((("installed", "1.0"), ("source_tree", "1.0"), ("edited", "2.0"))):
        pkg = tmp_path / name / "pkg"
        pkg.mkdir(parents=True)
        (pkg / "__init__.py").write_text("")
        (pkg / "numba_cache.py").write_text(Path(numba_cache.__file__).read_text())
        (pkg / "caller.py").write_text(_CALLER.format("from pkg import numba_cache  # noqa: F401"))
        (pkg / "callee.py").write_text(_CALLEE.format(term))
        for path in pkg.iterdir():
            os.utime(path, (time.time() - 1000 * (age + 1),) * 2)
        copies.append(pkg.parent)
    prefix = tmp_path / "env"
    runs = []
    for folder in copies:
        done = subprocess.run([sys.executable, "-c", _SHARED_CHECK, str(prefix), numba_stamp], cwd=folder, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr[-2000:]
        runs.append(done.stdout.split())
    assert runs == [["4.0", "0", "1"], ["4.0", "1", "0"], ["6.0", "0", "1"]]  # compiled, loaded, compiled
    contents = sorted(p.name for p in (prefix / "var" / "cache" / "pkg-numba").iterdir())
    assert len(contents) == 2, contents  # one folder per content of the sources
    assert not list(tmp_path.rglob("__pycache__/*.nbi")), "a copy wrote beside its sources"


def test_old_contents_are_removed_beyond_the_newest_kept(tmp_path):
    def make(count: int, hours_ago) -> list[Path]:
        folders = []
        for i in range(count):
            folder = tmp_path / f"digest{i}"
            (folder / "core").mkdir(parents=True)
            (folder / ".used").touch()
            then = time.time() - 3600 * hours_ago(i)
            os.utime(folder / ".used", (then, then))
            folders.append(folder)
        return folders

    current = tmp_path / "current"
    current.mkdir()
    folders = make(numba_cache.KEEP + 3, lambda i: 10 - i)  # digest0 the least recently used
    numba_cache._prune(current)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["current", *(f.name for f in folders[-(numba_cache.KEEP - 1) :])])
    for folder in tmp_path.iterdir():
        if folder != current:
            shutil.rmtree(folder)
    folders = make(numba_cache.KEEP + 3, lambda i: 0)  # all in use a moment ago (other processes may still save there)
    numba_cache._prune(current)
    assert len(list(tmp_path.iterdir())) == numba_cache.KEEP + 4


_WITHOUT_PRIVATE_API = """
import numba.core.caching as caching
del caching._CacheLocator  # a numba release that renamed its private locator base
import imix_cli.core.algorithms  # every ES module: their kernels are defined (cache=True) at import
from imix_cli.core import numerics as xp
from imix_cli.core.numerics import numba_cache
assert not numba_cache.LOCATOR_API
assert numba_cache._PackageLocator not in caching.CacheImpl._locator_classes
print(xp.log(2.0))
"""


def test_imix_imports_and_runs_on_a_numba_without_the_private_names_its_locator_uses(tmp_path):
    """``pip install`` takes the newest numba, and numba_cache's locator subclasses two private names: a release without
    them must leave imix importable, its kernels on numba's own locators. Made to fail by subclassing the private
    base unconditionally again."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}  # numba's own folder: nothing of imix's shared cache touched
    done = subprocess.run([sys.executable, "-c", _WITHOUT_PRIVATE_API], capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert float(done.stdout) == 0.6931471805599453
