"""Reading an ``.npz`` that may lie: every member's size is checked before a byte of it is inflated.

Why: an ``.npz`` is a zip of ``.npy`` files, and ``np.load`` allocates whatever shape a member's
``.npy`` header declares, then inflates the member into it. A 2 MB zip can declare gigabytes (a
zip bomb: a deflated run of zeros), so a checkpoint or policy file from elsewhere could take all
the memory of the machine that opens it. :func:`read_npz` reads the zip's central directory and
each member's ``.npy`` header first, and refuses the file -- one line, :class:`NpzLimitError` --
unless

* every member is a plain ``.npy`` (stored or deflated), of a numeric or boolean dtype (no
  Python objects, strings or records), and its declared shape times its item size is exactly
  the member's uncompressed size in the zip's directory (zipfile never inflates past that size);
* each member's size is within what the caller allows (``check(name, shape, dtype)``, e.g. the
  shapes a run's config implies) and the members' total within ``max_bytes``.

Only then are the arrays read, so the memory used is bounded by ``max_bytes`` whatever the file says.
"""

from __future__ import annotations

import math
import zipfile
from collections.abc import Callable

import numpy as np

#: Dtype kinds an array read back may have: bool, signed and unsigned integers, floats.
_NUMERIC_KINDS = "biuf"
#: The largest ``.npy`` header numpy reads (its own default), and the most members a file may hold.
_MAX_NPY_HEADER = 10_000
MAX_MEMBERS = 100_000


class NpzLimitError(ValueError):
    """An ``.npz`` refused before inflating it; ``str(err)`` says why in a few words."""


def member_header(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> tuple[tuple, np.dtype, int]:
    """``(shape, dtype, header_bytes)`` of one ``.npy`` member, read without inflating its data."""
    with archive.open(info) as fh:
        try:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh, max_header_size=_MAX_NPY_HEADER)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh, max_header_size=_MAX_NPY_HEADER)
            else:
                raise NpzLimitError(f"member {info.filename!r}: .npy version {version}")
        except NpzLimitError:
            raise
        except Exception as err:  # a damaged .npy header: numpy raises ValueError, SyntaxError, ...
            raise NpzLimitError(f"member {info.filename!r}: not a .npy array ({type(err).__name__})") from None
        return tuple(shape), dtype, fh.tell()


def read_npz(path, max_bytes: int, check: Callable[[str, tuple, np.dtype], None] | None = None, names=None, only: str | None = None) -> dict:
    """The arrays of the ``.npz`` at ``path`` (member name without ``.npy`` -> array), memory bounded.

    ``max_bytes``: the most uncompressed bytes all members may hold together. ``check(name, shape,
    dtype)`` raises (NpzLimitError or ValueError) for a member the caller does not expect; ``names``,
    if given, is the exact set of member names the file must hold; ``only``: read just that member
    (the others are checked, not read). Raises NpzLimitError before
    anything is inflated if the file breaks a limit, zipfile/OS errors if it is not a zip at all.
    """
    arrays = {}
    with zipfile.ZipFile(path) as archive:
        infos = archive.infolist()
        if len(infos) > MAX_MEMBERS:
            raise NpzLimitError(f"{len(infos)} members, at most {MAX_MEMBERS}")
        found = [info.filename[: -len(".npy")] for info in infos]
        if any(not info.filename.endswith(".npy") for info in infos) or len(set(found)) != len(found):
            raise NpzLimitError("not an .npz of distinct .npy members")
        if names is not None and set(found) != set(names):
            raise NpzLimitError(f"holds {sorted(found)[:6]}, expected {sorted(names)}")
        total = sum(info.file_size for info in infos)
        if total > max_bytes:
            raise NpzLimitError(f"declares {total:,} bytes uncompressed, more than the {max_bytes:,} this file can need")
        for info, name in zip(infos, found, strict=True):
            if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                raise NpzLimitError(f"member {name!r}: compression method {info.compress_type}")
            if info.flag_bits & 0x1:
                raise NpzLimitError(f"member {name!r}: encrypted")
            shape, dtype, header_bytes = member_header(archive, info)
            if dtype.hasobject or dtype.kind not in _NUMERIC_KINDS and not (dtype.kind == "U" and shape == ()):
                raise NpzLimitError(f"member {name!r}: dtype {dtype.str} is not a number")
            if dtype.byteorder not in ("=", "<", "|") or not all(isinstance(n, int) and n >= 0 for n in shape):
                raise NpzLimitError(f"member {name!r}: unexpected layout ({dtype.str}, {shape})")
            if math.prod(shape) * dtype.itemsize != info.file_size - header_bytes:
                raise NpzLimitError(f"member {name!r}: its shape does not match its size")
            if check is not None:
                check(name, shape, dtype)
        for info, name in zip(infos, found, strict=True):
            if only is not None and name != only:
                continue
            with archive.open(info) as fh:  # zipfile stops at the directory's size and checks the CRC
                arrays[name] = np.lib.format.read_array(fh, allow_pickle=False, max_header_size=_MAX_NPY_HEADER)
    return arrays
