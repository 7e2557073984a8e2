"""The one writer: every file any imix command writes goes through :func:`atomic_writer`.

Why: a results folder travels (copied from a cluster, shared, downloaded). A symbolic link planted in
it -- ``figures -> ~/.ssh`` or ``figures/iqm.md -> ~/.bashrc`` -- must never make imix write outside it,
and a write cut short (kill -9, a full disk, a machine crash) must never leave a truncated or empty
file where a good one was.

How, for ``<root>/<a>/<b>/<name>``:

* The walk from ``root`` down is done on folder descriptors opened with ``O_NOFOLLOW``: ``root`` itself
  is followed (the user chose it: ``results_dir`` may be a link), every folder below it must be a real
  folder, and the target ``name`` must not be a link either. A link is refused with one line naming it
  (:class:`LinkRefusedError`). Opening by descriptor, not by path, leaves no window between the check
  and the write in which a folder could be swapped for a link.
* Missing folders below ``root`` are created (``mkdir`` makes a folder, never follows a link).
* The data goes to ``.<name>.<random>.tmp`` created in the same folder (``O_EXCL | O_NOFOLLOW``), is
  flushed to the disk (``fsync``, ``durable=True``) and renamed over ``name``; the rename itself is
  made durable by an ``fsync`` of the folder. On any error, or a kill before the rename, the old file
  is untouched; a temporary left by a kill -9 is never at a final name (``imix run`` clears its own).

``root=None`` means the target's grandparent: the file and the folder holding it are never links,
the folders above are trusted. Commands pass their ``results_dir`` (or, for a file the user named,
its folder) to have the whole path below checked.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from pathlib import Path

_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC
_TMP_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC


class LinkRefusedError(OSError):
    """A symbolic link where imix was to write (the target, or a folder below the writer's root)."""

    def __init__(self, path) -> None:
        super().__init__(errno.ELOOP, "is a symbolic link; imix writes through no link inside its results folder: remove it, then re-run", str(path))

    def __str__(self) -> str:
        return f"{self.filename} {self.strerror}"


def _open_folder(root: Path, parts: tuple, create: bool) -> int:
    """A descriptor of ``root/parts...``: ``root`` followed, each part opened without following a link."""
    fd = os.open(root, _DIR_FLAGS)
    try:
        for i, part in enumerate(parts):
            where = root.joinpath(*parts[: i + 1])
            try:
                child = os.open(part, _DIR_FLAGS | os.O_NOFOLLOW, dir_fd=fd)
            except FileNotFoundError:
                if not create:
                    raise
                try:
                    os.mkdir(part, 0o777, dir_fd=fd)
                except FileExistsError:  # made by another writer meanwhile: opened below all the same
                    pass
                except OSError as err:  # a read-only or immutable folder: named by its path, not by `part` alone
                    raise OSError(err.errno, err.strerror, str(where)) from None
                child = _open_child(part, fd, where)
            except OSError as err:
                raise _refusal(part, fd, where, err) from None
            os.close(fd)
            fd = child
        return fd
    except BaseException:
        os.close(fd)
        raise


def _open_child(part: str, fd: int, where: Path) -> int:
    try:
        return os.open(part, _DIR_FLAGS | os.O_NOFOLLOW, dir_fd=fd)
    except OSError as err:
        raise _refusal(part, fd, where, err) from None


def _refusal(part: str, fd: int, where: Path, err: OSError) -> OSError:
    """The error for a folder that could not be opened: a link (ELOOP, or ENOTDIR on a link to a file) is refused by name."""
    with contextlib.suppress(OSError):
        if stat.S_ISLNK(os.lstat(part, dir_fd=fd).st_mode):
            return LinkRefusedError(where)
    return OSError(err.errno, err.strerror, str(where))


def _split(path: Path, root) -> tuple[Path, tuple]:
    """(root, the folders between root and the file); ``root=None``: the file's grandparent (see the module)."""
    if root is None:
        return path.parent.parent, (path.parent.name,) if path.parent.name not in ("", ".", "..") else ()
    root = Path(root)
    try:
        rel = path.parent.relative_to(root)
    except ValueError:
        raise ValueError(f"{path} is not inside {root}") from None
    if ".." in rel.parts:
        raise ValueError(f"{path}: '..' in a path written under {root}")
    return root, rel.parts


@contextlib.contextmanager
def atomic_writer(path, *, root=None, durable: bool = True):
    """``with atomic_writer(path) as fh: fh.write(...)``: a binary file that replaces ``path`` only when the
    block ends without an error (the module says how). For data produced piece by piece (a GIF's frames)."""
    path = Path(path)
    if path.name in ("", ".", ".."):
        raise ValueError(f"{path}: not a file name")
    base, parts = _split(path, root)
    base.mkdir(parents=True, exist_ok=True)  # the root and above are the user's: created, links followed
    folder = _open_folder(base, parts, create=True)
    tmp = None
    names = (path.name,)
    try:
        tmp = f".{path.name[:200]}.{secrets.token_hex(4)}.tmp"
        names = (path.name, tmp)
        fd = os.open(tmp, _TMP_FLAGS, 0o666, dir_fd=folder)  # 0666 less the umask: a file's usual permissions
        with os.fdopen(fd, "wb") as fh:
            yield fh
            fh.flush()
            if durable:
                os.fsync(fh.fileno())
        with contextlib.suppress(FileNotFoundError):
            if stat.S_ISLNK(os.lstat(path.name, dir_fd=folder).st_mode):
                raise LinkRefusedError(path)
        os.replace(tmp, path.name, src_dir_fd=folder, dst_dir_fd=folder)
        tmp = None
        if durable:
            os.fsync(folder)
    except OSError as err:
        # ENOSPC from write/fsync names no file, a refused create or rename names the bare temporary
        # (`.seed_1.partial.csv.3d89911e.tmp`): name the file we were writing, by its path
        if not isinstance(err, LinkRefusedError) and (err.filename is None or err.filename in names):
            raise OSError(err.errno, err.strerror or str(err), str(path)) from None
        raise
    finally:
        if tmp is not None:  # a folder made read-only meanwhile keeps it: the error above is the one to tell (a re-run clears it)
            with contextlib.suppress(OSError):
                os.unlink(tmp, dir_fd=folder)
        os.close(folder)


def atomic_write_bytes(path, data: bytes, *, root=None, durable: bool = True) -> None:
    """Write ``data`` to ``path`` through :func:`atomic_writer`.

    ``durable=False`` skips the two ``fsync`` calls (~5-7 ms a file here): for files that are only a
    shortcut -- a periodic checkpoint, the live ``seed_<k>.partial.csv`` -- a process kill leaves them
    whole all the same, and one damaged by a machine crash is refused by its checksum and costs
    recomputation only (docs/reliability-runs.md). Results stay durable.
    """
    with atomic_writer(path, root=root, durable=durable) as fh:
        fh.write(data)


def atomic_write_text(path, text: str, *, root=None, durable: bool = True) -> None:
    """:func:`atomic_write_bytes` for text (UTF-8)."""
    atomic_write_bytes(path, text.encode("utf-8"), root=root, durable=durable)


def make_folder(path, *, root) -> Path:
    """Create ``path`` (and the folders between ``root`` and it) without following a link below ``root``."""
    path = Path(path)
    base, parts = _split(path / "x", root)
    base.mkdir(parents=True, exist_ok=True)
    os.close(_open_folder(base, parts, create=True))
    return path


#: Characters that make a spreadsheet read a cell as a formula (OWASP's CSV-injection list, with tab and CR).
_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def safe_cell(value):
    """A text cell as a table may hold it: line breaks become spaces (a cell never starts a new line of the
    file), and text a spreadsheet would run as a formula gets a leading ``'`` (OWASP). Numbers, including
    negative ones, pass unchanged: only text is neutralised."""
    if not isinstance(value, str):
        return value
    text = one_line(value)
    if text.startswith(_FORMULA_START) and not _is_number(text):
        text = "'" + text
    return text


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def safe_frame(frame):
    """A copy of a pandas frame with every text cell (and column name) through :func:`safe_cell`; numeric columns untouched."""
    out = frame.copy()
    for column in out.columns:
        if out[column].dtype == object or str(out[column].dtype) in ("string", "str"):
            out[column] = out[column].map(safe_cell)
    out.columns = [safe_cell(str(c)) for c in out.columns]
    return out


def one_line(text: str) -> str:
    """``text`` with its line breaks as spaces: a cell of a Markdown or LaTeX table never starts a new line of the file."""
    return str(text).replace("\r\n", " ").replace("\n", " ").replace("\r", " ")


def csv_text(frame, **to_csv) -> str:
    """A frame as CSV text with its text cells neutralised (:func:`safe_frame`); ``to_csv``: pandas' options."""
    return safe_frame(frame).to_csv(index=False, lineterminator="\n", **to_csv)


def write_figure(fig, path, *, root=None, **savefig) -> None:
    """``fig.savefig`` into the one writer: a figure cut short by a kill never replaces a good one."""
    savefig.setdefault("format", Path(path).suffix.lstrip(".").lower())  # a file object has no name to take it from
    with atomic_writer(path, root=root) as fh:
        fig.savefig(fh, **savefig)
