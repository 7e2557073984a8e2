"""numba's on-disk cache of imix's kernels, stamped with every compiled source of the package: computed, never written by hand.

Why. numba keeps a cached function valid while *its own* file is unchanged (it stores the file's
hash beside the cached machine code), not while the functions it calls from other files are: and
imix's kernels call across files all the time (:mod:`imix_cli.core.numerics.elementary`'s exp and log are compiled
into the episodes, the mixing step and the ES updates; the compiled generation loop compiles in the ES's
update and mixing's step). Editing a callee would leave its callers' cached machine code in use:
old numbers from new source, silently.

How. imix's functions get their own cache locator (:class:`_PackageLocator`): the cache files stay
where numba would put them, but the source stamp they are checked against is the pair (the function's
own file's stamp, :data:`SOURCE_DIGEST`), the latter a hash of every module of the package that uses
numba (:func:`compiled_sources`, :func:`source_digest`, computed at import). Editing any of them recompiles every imix kernel
on its next use (a few minutes, ``python -m imix_cli.running.warmup`` does it at once); none is ever
stale, and there is no stamp line to rewrite by hand. Functions outside the package keep numba's own
locators (an ES added outside the package is keyed by its own file in the compiled loop's entry).

Where. Not in ``__pycache__`` beside each copy of the package but in one folder per content of the
package, inside the Python environment: ``<sys.prefix>/var/cache/imix_cli-numba/<digest>/`` (the
folder tree of the package below it, :func:`shared_cache_root`). Why: ``make install`` compiles every
kernel into the *installed* copy (its warm-up), and ``make test`` then imports the *source tree* (the
current folder is on ``sys.path``), whose ``__pycache__`` is empty: on a fresh clone the suite spent
~100 s of its ~7 min compiling again what the install had just compiled. In the shared folder a
kernel's stamp is the hash of its file's bytes (not numba's, which is the file's mtime in some numba
versions and would differ between the copies) with :data:`SOURCE_DIGEST`, and numba's index key is the
function's bytecode, so two copies with the same sources share machine code; keyed by
:data:`SOURCE_DIGEST`, copies that differ never overwrite each other's. An edit makes a new folder; the oldest are removed beyond the newest :data:`KEEP`
(:func:`_prune`). When ``sys.prefix`` is not writable (a system Python) or the user set
``NUMBA_CACHE_DIR``, numba's own folder is used, as before.

This module is imported by :mod:`imix_cli.core.numerics.elementary`, which every imix kernel module imports before
it defines a kernel: the locator is in place before the first ``@njit(cache=True)`` of the package
runs (``tests/test_numba_cache.py`` checks every cached kernel uses it). A ``NUMBA_CACHE_LOCATOR_CLASSES``
set by the user replaces numba's locator list, this one included.
"""

from __future__ import annotations

import functools
import hashlib
import os
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

from numba.core import caching

__all__ = ["KEEP", "LOCATOR_API", "PACKAGE", "SOURCE_DIGEST", "compiled_sources", "shared_cache_root", "source_digest"]


def _top_package(folder: Path) -> Path:
    """The outermost package holding ``folder`` (this module may sit in a subpackage: the stamp covers the whole package)."""
    while (folder.parent / "__init__.py").is_file():
        folder = folder.parent
    return folder


#: The package whose functions this locator stamps: the top package this module is in (``imix_cli``).
PACKAGE = _top_package(Path(__file__).resolve().parent)


_IMPORT = re.compile(r"^\s*(?:from ([\w.]+) import \(?([\w, ]+)|import ([\w.]+))", re.MULTILINE)
_COMPILED = ("@njit", "@jit", "@intrinsic", "@overload", "@vectorize", "@guvectorize", "@generated_jit")  # decorators of compiled code


def compiled_sources(root: Path = PACKAGE) -> list[Path]:
    """The modules under ``root`` that define compiled functions, and the modules of ``root`` they import
    (whose constants numba compiles in: :mod:`imix_cli.core.numerics.elementary_tables`' tables, an environment's
    constants), in a fixed order."""
    texts = {p: p.read_text(encoding="utf-8") for p in root.rglob("*.py")}
    compiled = [p for p, text in texts.items() if any(mark in text for mark in _COMPILED)]
    found = set(compiled)
    for path in compiled:
        for module, names, plain in _IMPORT.findall(texts[path]):
            for name in [module, *(f"{module}.{n.split(' as ')[0].strip()}" for n in names.split(","))] if module else [plain.split(" as ")[0]]:
                parts = name.split(".")
                if parts[0] != root.name:
                    continue
                for candidate in (root.joinpath(*parts[1:]).with_suffix(".py"), root.joinpath(*parts[1:], "__init__.py")):
                    if candidate.is_file():
                        found.add(candidate)
    return sorted(found)


def source_digest(root: Path = PACKAGE) -> str:
    """A hash of the names and contents of :func:`compiled_sources` of ``root``."""
    h = hashlib.sha256()
    for path in compiled_sources(root):
        h.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


#: :func:`source_digest` of the package as imported: part of every imix kernel's cache stamp.
SOURCE_DIGEST = source_digest()


#: How many contents of the package keep their compiled kernels in the environment (the newest by use).
KEEP = 4

#: A content folder younger than this is never removed: a process that started on it may still save to it.
_GRACE_SECONDS = 600.0


def shared_cache_root(prefix: str | os.PathLike | None = None, package: Path = PACKAGE, digest: str = "") -> Path:
    """The folder holding the package's compiled kernels for one content of its sources (``digest``,
    :data:`SOURCE_DIGEST` by default): shared by every copy of the package that runs in the environment
    ``prefix`` (``sys.prefix`` when the call is made; the installed copy and a source tree alike)."""
    return Path(sys.prefix if prefix is None else prefix) / "var" / "cache" / f"{package.name}-numba" / (digest or SOURCE_DIGEST)[:20]


def _prune(root: Path) -> None:
    """Mark ``root`` used now and remove the content folders beside it beyond the :data:`KEEP` most
    recently used (unless used in the last :data:`_GRACE_SECONDS`); called once per process, when its
    first kernel of the package is defined."""
    stamp = root / ".used"
    stamp.touch()
    others = []
    for folder in root.parent.iterdir():
        mark = folder / ".used"
        if folder != root and mark.is_file():
            others.append((mark.stat().st_mtime, folder))
    now = time.time()
    for used, folder in sorted(others, reverse=True)[KEEP - 1 :]:
        if now - used > _GRACE_SECONDS:
            shutil.rmtree(folder, ignore_errors=True)


def _shared_root() -> Path | None:
    """:func:`shared_cache_root` when it can be written and the user did not choose a cache folder, else None."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    root = shared_cache_root()
    try:
        root.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=root).close()
        _prune(root)
    except OSError:
        return None
    return root


_SHARED: list[Path | None] = []  # computed once per process, on the first kernel that asks


@functools.cache
def _file_hash(path: str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


#: Whether this numba has the two private names the locator needs (``caching._CacheLocator``, ``CacheImpl._locator_classes``;
#: numba 0.61-0.68 have them). Why private names, and not ``NUMBA_CACHE_DIR`` per :data:`SOURCE_DIGEST` (documented): that
#: variable is read once, when numba is first imported -- by the user's code too, before imix's -- and it would move the
#: user's own cached functions with imix's (measured when it was weighed: a copy at another path recompiled for 61 s).
#: Why a fallback: ``pip install imix`` takes the newest numba, and a release without them must not stop imix from
#: importing. Without them numba's own locators key each kernel by its own file only (a callee edited in another file
#: can leave its callers' cached code in use: a developer's risk, not an installed release's, whose files change all at
#: once); ``tests/test_numba_cache.py`` fails then, so the constraints' numba is not raised past a release without them.
LOCATOR_API = hasattr(caching, "_CacheLocator") and isinstance(getattr(getattr(caching, "CacheImpl", None), "_locator_classes", None), list)


class _PackageLocator(caching._CacheLocator if LOCATOR_API else object):
    """numba's own locator for the function, with :data:`SOURCE_DIGEST` in its stamp and the cache in
    :func:`shared_cache_root` (the function's folder in the package below it) when that can be written."""

    def __init__(self, inner, shared: Path | None = None, py_file: str = ""):
        self._inner = inner
        self._shared = shared
        self._py_file = py_file

    def ensure_cache_path(self):
        if self._shared is None:
            self._inner.ensure_cache_path()
        else:
            self._shared.mkdir(parents=True, exist_ok=True)

    def get_cache_path(self):
        return self._inner.get_cache_path() if self._shared is None else str(self._shared)

    def get_source_stamp(self):
        if self._shared is None:
            return (self._inner.get_source_stamp(), SOURCE_DIGEST)
        return (_file_hash(self._py_file), SOURCE_DIGEST)  # the same for every copy of the same file

    def get_disambiguator(self):
        return self._inner.get_disambiguator()

    @classmethod
    def from_function(cls, py_func, py_file):
        try:
            folder = Path(py_file).resolve().parent.relative_to(PACKAGE)
        except (ValueError, OSError):
            return None  # not imix's: numba's own locators
        if not _SHARED:
            _SHARED.append(_shared_root())
        shared = None if _SHARED[0] is None else _SHARED[0].joinpath(*folder.parts)
        for other in caching.CacheImpl._locator_classes:
            if other is not cls:
                inner = other.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner, shared, py_file)
        return None


if LOCATOR_API and _PackageLocator not in caching.CacheImpl._locator_classes:
    caching.CacheImpl._locator_classes.insert(0, _PackageLocator)
