"""numba's on-disk cache of imix's kernels, stamped with every compiled source of the package: computed, never written by hand.

Why. numba keeps a cached function valid while *its own* file is unchanged (it stores the file's
hash beside the cached machine code), not while the functions it calls from other files are: and
imix's kernels call across files all the time (:mod:`imix_cli.core.elementary`'s exp and log are compiled
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

This module is imported by :mod:`imix_cli.core.elementary`, which every imix kernel module imports before
it defines a kernel: the locator is in place before the first ``@njit(cache=True)`` of the package
runs (``tests/test_numba_cache.py`` checks every cached kernel uses it). A ``NUMBA_CACHE_LOCATOR_CLASSES``
set by the user replaces numba's locator list, this one included.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

from numba.core import caching

__all__ = ["PACKAGE", "SOURCE_DIGEST", "compiled_sources", "source_digest"]


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
    (whose constants numba compiles in: :mod:`imix_cli.core.elementary_tables`' tables, an environment's
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


class _PackageLocator(caching._CacheLocator):
    """numba's own locator for the function (its cache directory), with :data:`SOURCE_DIGEST` in its stamp."""

    def __init__(self, inner):
        self._inner = inner

    def ensure_cache_path(self):
        self._inner.ensure_cache_path()

    def get_cache_path(self):
        return self._inner.get_cache_path()

    def get_source_stamp(self):
        return (self._inner.get_source_stamp(), SOURCE_DIGEST)

    def get_disambiguator(self):
        return self._inner.get_disambiguator()

    @classmethod
    def from_function(cls, py_func, py_file):
        try:
            Path(py_file).resolve().relative_to(PACKAGE)
        except (ValueError, OSError):
            return None  # not imix's: numba's own locators
        for other in caching.CacheImpl._locator_classes:
            if other is not cls:
                inner = other.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner)
        return None


if _PackageLocator not in caching.CacheImpl._locator_classes:
    caching.CacheImpl._locator_classes.insert(0, _PackageLocator)
