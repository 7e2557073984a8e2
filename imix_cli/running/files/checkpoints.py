"""Checkpoints: one seed's whole state as data -- arrays in an ``.npz``, the rest in a JSON header.

Why not a pickle: results folders travel (rsync from a cluster, shared file systems, a
colleague's results), and unpickling a file runs whatever code it names. Why a checksum and
an identity: a checkpoint that is damaged, of another seed or of another config must never
turn into a wrong CSV. A checkpoint therefore either loads *exactly* what was saved, or it is
refused with one warning line naming the file and the reason, and the seed restarts from
scratch (that only costs recomputation).

A seed's checkpoint is ``.checkpoints/seed_<k>.npz`` in its run folder (:func:`checkpoint_path`), saved by
the run's writer (:mod:`imix_cli.running.files.run_writer`) and read back, and checked against the run, by
:mod:`imix_cli.running.loop.resume`.

Format (``FORMAT_VERSION`` 2: since each ES saves its state record field by field, ``es/mean`` and so on; a version-1
checkpoint is refused with one line, and its seed restarts), written atomically (:func:`imix_cli.running.files.writing.atomic_write_bytes`):
an uncompressed NumPy ``.npz`` (a zip of ``.npy`` files, read back with
``np.load(allow_pickle=False)``, so no object array can be loaded) holding

* ``header``: a uint8 array, the UTF-8 JSON object ``{"format": "imix-checkpoint",
  "version", "imix_version", "config_hash", "seed", "generation", "state", "checksum"}``;
  ``config_hash`` is the SHA-256 of the run's identity (:meth:`RunSpec.identity`, canonical
  JSON); ``state`` is the state tree (below);
* one array per ndarray of the state, named by its path in the tree (``es/mu``,
  ``archive/0/samples``, ``archive/0/dist/std``, ``archive_returns/1`` ...).

``checksum`` is the SHA-256 over the canonical JSON of the header without it, then, for every
array in name order, its name, dtype, shape and bytes. Any difference between what was saved
and what is read -- a bit flip anywhere, a truncation, an array swapped in -- is caught by it
or by the zip's own structure.

The state tree is a dataclass (``imix_cli.running.loop.lockstep.SeedState``) encoded field by field, by type,
so new fields need no change here: JSON scalars stay as they are (floats round-trip exactly,
NaN included); an ndarray becomes ``{"array": name}``; a list ``{"list": [...]}``; a dict
``{"dict": {...}}``; a numpy Generator ``{"rng": bit_generator.state}`` (PCG64 only); an ES
``{"es": state_dict}`` (loaded into a freshly built ES of the same config); a search
distribution ``{"dist": class name, "state": to_state()}`` (a re-expressed generation's
:class:`~imix_cli.core.distributions.AffinePushforward` too: its base distribution and its
:class:`~imix_cli.core.evaluation.policies.NormalizerChange`, each such a node, rebuilt exactly on load); an archived
:class:`~imix_cli.core.mixing.Generation` ``{"generation": {field: ...}}`` over all its dataclass
fields, whatever they are.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
from pathlib import Path

import numpy as np

from imix_cli import messages
from imix_cli.core.distributions import AffinePushforward, DiagonalGaussian, FullGaussian
from imix_cli.core.evaluation.policies import NormalizerChange, ObsNormalizer
from imix_cli.core.mixing import Generation
from imix_cli.running.files.results import regular_file_size
from imix_cli.running.files.writing import atomic_write_bytes

FORMAT = "imix-checkpoint"
FORMAT_VERSION = 2
_HEADER = "header"
#: Value classes saved through their ``to_state()`` and rebuilt by ``cls.from_state(state)``.
_DISTRIBUTIONS = {cls.__name__: cls for cls in (DiagonalGaussian, FullGaussian, ObsNormalizer, AffinePushforward, NormalizerChange)}


#: The most a checkpoint may hold when the caller gives no bound derived from its run's config.
DEFAULT_MAX_BYTES = 256 << 20


class CheckpointError(ValueError):
    """A checkpoint cannot be trusted; ``str(err)`` says why, in a few words."""


def config_hash(identity: dict) -> str:
    """SHA-256 of a run's identity (the result-determining config), as canonical JSON."""
    return hashlib.sha256(_canonical(identity).encode()).hexdigest()


def checkpoint_path(run_dir, seed: int) -> Path:
    """``.checkpoints/seed_<k>.npz`` of run folder ``run_dir``: where seed ``seed``'s state waits between processes."""
    return Path(run_dir) / ".checkpoints" / f"seed_{seed}.npz"


def save_checkpoint(run_dir, st, identity: dict, tables: dict | None = None, *, durable: bool = True) -> None:
    """Seed state ``st`` (:class:`imix_cli.running.loop.lockstep.SeedState`) as its seed's checkpoint in ``run_dir``;
    ``tables``: kept by the caller between the checkpoints of that seed (:func:`write_checkpoint`)."""
    write_checkpoint(checkpoint_path(run_dir, st.seed), st, identity=identity, seed=st.seed, generation=st.generation, tables=tables, durable=durable)


def remove_checkpoint(run_dir, seed: int) -> None:
    checkpoint_path(run_dir, seed).unlink(missing_ok=True)


def write_checkpoint(path, state, *, identity: dict, seed: int, generation: int, tables: dict | None = None, durable: bool = True) -> None:
    """Write dataclass ``state`` (a seed's state at ``generation``) to ``path`` atomically (``durable``:
    flushed to the disk too, :func:`imix_cli.running.files.writing.atomic_write_bytes`).

    ``tables``: a dict the caller keeps between the checkpoints of one seed (empty at first), where
    the encoding of the state's tables (its rows) is kept for the next checkpoint to reuse
    (:class:`TableCache`); the file is the same with or without it."""
    from imix_cli import __version__

    arrays: dict[str, np.ndarray] = {}
    tree = _encode(state, "", arrays, tables)
    header = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "imix_version": __version__,
        "config_hash": config_hash(identity),
        "seed": int(seed),
        "generation": int(generation),
        "state": tree,
    }
    header["checksum"] = _checksum(header, arrays)
    buffer = io.BytesIO()
    np.savez(buffer, **{_HEADER: np.frombuffer(_canonical(header).encode(), dtype=np.uint8)}, **arrays)
    atomic_write_bytes(path, buffer.getvalue(), durable=durable)


def read_checkpoint(path, template, *, identity: dict, seed: int, max_bytes: int = DEFAULT_MAX_BYTES):
    """The state saved at ``path``, built on ``template`` (a fresh state of the same run and seed).

    Returns a new object of ``template``'s dataclass type, whose ES is ``template``'s ES with the
    saved state loaded. Raises FileNotFoundError if there is no file, :class:`CheckpointError`
    if it is damaged, of another format/version/seed/config, does not fit ``template``, or
    declares more than ``max_bytes`` of arrays (checked before inflating them: a zip bomb costs
    nothing). A checksum only proves the file is what *some* writer wrote: what the state's values
    may be is checked by the caller (:func:`imix_cli.running.loop.resume.validate_seed_state`).
    """
    from imix_cli import __version__

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(path)
    try:
        regular_file_size(path)
        header, arrays = _read_npz(path, max_bytes)
    except CheckpointError:
        raise
    except OSError as err:
        raise CheckpointError(f"unreadable ({err.strerror or err})") from None
    except Exception as err:  # np.load/zipfile raise many types for a damaged file
        raise CheckpointError(f"unreadable ({type(err).__name__}: {_first_line(err)})") from None
    if header.get("format") != FORMAT:
        raise CheckpointError("not an imix checkpoint")
    if header.get("version") != FORMAT_VERSION:
        raise CheckpointError(f"checkpoint format version {header.get('version')!r}, this imix reads {FORMAT_VERSION}")
    checksum = header.pop("checksum", None)
    if checksum != _checksum(header, arrays):
        raise CheckpointError("checksum mismatch (damaged file)")
    if header.get("imix_version") != __version__:
        raise CheckpointError(f"written by imix {header.get('imix_version')}, this is imix {__version__}")
    if header.get("seed") != seed:
        raise CheckpointError(f"holds seed {header.get('seed')!r}, not seed {seed}")
    if header.get("config_hash") != config_hash(identity):
        raise CheckpointError("written by a run of another config")
    try:
        state = _decode(header["state"], template, arrays)
    except Exception as err:  # a tree that does not fit this version's state: refuse it
        raise CheckpointError(f"does not fit this run's state ({type(err).__name__}: {_first_line(err)})") from None
    if type(state) is not type(template):
        raise CheckpointError("does not hold a seed's state")
    if header.get("generation") != getattr(state, "generation", header.get("generation")):
        raise CheckpointError(f"header says generation {header.get('generation')!r}, its rows {state.generation}")
    return state


def load_or_warn(path, template, *, identity: dict, seed: int, warn=None, max_bytes: int = DEFAULT_MAX_BYTES):
    """:func:`read_checkpoint`, or None: no file, or -- after one warning line -- a checkpoint refused."""
    try:
        return read_checkpoint(path, template, identity=identity, seed=seed, max_bytes=max_bytes)
    except FileNotFoundError:
        return None
    except CheckpointError as err:
        (warn or messages.warn)(f"{path}: checkpoint ignored: {err}; seed {seed} restarts from scratch")
        return None


# ----------------------------------------------------------------------------- file level
def _read_npz(path: Path, max_bytes: int) -> tuple[dict, dict]:
    """The header (a dict) and the arrays of a checkpoint, memory bounded (:func:`imix_cli.running.files.safe_npz.read_npz`)."""
    from imix_cli.running.files.safe_npz import NpzLimitError, read_npz

    def check(name, shape, dtype):
        if name == _HEADER and (dtype != np.uint8 or len(shape) != 1):
            raise CheckpointError("malformed header")

    try:
        arrays = read_npz(path, max_bytes, check)
    except NpzLimitError as err:
        raise CheckpointError(str(err)) from None
    if _HEADER not in arrays:
        raise CheckpointError("no header")
    raw = arrays.pop(_HEADER)
    try:
        header = json.loads(raw.tobytes().decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise CheckpointError("malformed header (not JSON)") from None
    if not isinstance(header, dict):
        raise CheckpointError("malformed header (not a JSON object)")
    return header, arrays


def _checksum(header: dict, arrays: dict) -> str:
    digest = hashlib.sha256(_canonical(header).encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        digest.update(f"\0{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        digest.update(a.tobytes())
    return digest.hexdigest()


def _canonical(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=True)


def _first_line(err: Exception) -> str:
    text = str(err).strip()
    return text.splitlines()[0][:200] if text else type(err).__name__


# ----------------------------------------------------------------------------- the state tree
def _encode(value, name: str, arrays: dict, tables: dict | None = None):
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        if value.dtype.hasobject:
            raise TypeError(f"{name}: object arrays cannot be checkpointed")
        arrays[name] = value
        return {"array": name}
    if isinstance(value, np.random.Generator):
        if type(value.bit_generator) is not np.random.PCG64:
            raise TypeError(f"{name}: only PCG64 generators can be checkpointed")
        return {"rng": value.bit_generator.state}
    if isinstance(value, Generation):
        return {"generation": {f.name: _encode(getattr(value, f.name), f"{name}/{f.name}", arrays, tables) for f in dataclasses.fields(value)}}
    if type(value).__name__ in _DISTRIBUTIONS and type(value) is _DISTRIBUTIONS[type(value).__name__]:
        return {"dist": type(value).__name__, "state": _encode(value.to_state(), name, arrays, tables)}
    if hasattr(value, "state_dict") and hasattr(value, "load_state_dict"):
        return {"es": _encode(value.state_dict(), name, arrays, tables)}
    if dataclasses.is_dataclass(value):
        return {"state": {f.name: _encode(getattr(value, f.name), f"{name}/{f.name}".lstrip("/"), arrays, tables) for f in dataclasses.fields(value)}}
    if isinstance(value, (list, tuple)):
        table = _encode_table(value, name, arrays, tables)
        if table is not None:
            return table
        return {"list": [_encode(v, f"{name}/{i}", arrays, tables) for i, v in enumerate(value)]}
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise TypeError(f"{name}: only dicts with string keys can be checkpointed")
        return {"dict": {k: _encode(v, f"{name}/{k}", arrays, tables) for k, v in value.items()}}
    raise TypeError(f"{name}: cannot checkpoint a {type(value).__name__}")


def _encode_table(rows, name: str, arrays: dict, tables: dict | None = None):
    """A list of dicts with the same keys in the same order (a seed's CSV rows), column by column:
    the int columns as one int64 array, the float columns as one float64 array, the string columns
    as JSON lists, any other column value by value. None if ``rows`` is not such a list.

    Why: a seed's rows are the bulk of its checkpoint, and they grow with every generation; one
    JSON node per value made a checkpoint of a 1000-generation seed cost ~30 ms (encoding, hashing
    and writing the JSON tree), more than the generations between two checkpoints took to compute.
    ``tables`` (:func:`write_checkpoint`): the rows' encoding at an earlier checkpoint, whose
    unchanged rows are not encoded again."""
    if len(rows) < 2 or not all(type(r) is dict for r in rows):
        return None
    keys = tuple(rows[0])
    if not all(type(k) is str for k in keys):
        return None
    cache = tables.get(name) if tables is not None else None
    done = cache.unchanged_rows(rows, keys) if cache is not None else 0
    if any(tuple(r) != keys for r in rows[done:]):
        return None
    kinds, values = _table_columns(rows[done:], keys) if done < len(rows) else (cache.kinds, [()] * len(keys))
    if done and kinds != cache.kinds:  # a column whose kind the new rows change: the whole table anew
        done, (kinds, values) = 0, _table_columns(rows, keys)
    ints = [v for kind, v in zip(kinds, values) if kind == "int"]
    floats = [v for kind, v in zip(kinds, values) if kind == "float"]
    ints = np.array(ints, dtype=np.int64).reshape(len(ints), len(rows) - done)
    floats = np.array(floats, dtype=np.float64).reshape(len(floats), len(rows) - done)
    strings = [list(v) for kind, v in zip(kinds, values) if kind == "str"]
    if done:
        ints, floats = np.concatenate([cache.ints, ints], axis=1), np.concatenate([cache.floats, floats], axis=1)
        strings = [old + new for old, new in zip(cache.strings, strings)]
    columns, numbers, string_columns = [], {"int": 0, "float": 0}, iter(strings)
    for k, kind, column in zip(keys, kinds, values):
        if kind is None:
            columns.append({"list": [_encode(v, f"{name}/{k}/{i}", arrays, tables) for i, v in enumerate(column)]})
        elif kind == "str":
            columns.append({"str": next(string_columns)})
        else:
            columns.append({kind: numbers[kind]})
            numbers[kind] += 1
    arrays[f"{name}/int"], arrays[f"{name}/float"] = ints, floats
    if tables is not None:
        if None in kinds:  # a column of mixed values is encoded whole every time (none of the rows')
            tables.pop(name, None)
        else:
            seen = (cache.seen if done else []) + [tuple(r.values()) for r in rows[done:]]
            tables[name] = TableCache(rows, seen, keys, kinds, ints, floats, strings)
    return {"table": {"keys": list(keys), "columns": columns, "int": f"{name}/int", "float": f"{name}/float"}}


def _table_columns(rows: list, keys: tuple) -> tuple[list, list]:
    """Each column of ``rows``: its kind ("int": int64 ints, "float", "str", None: anything else) and its values."""
    kinds, values = [], []
    for column in zip(*(r.values() for r in rows)):
        found = set(map(type, column))
        if found == {int} and -(2**63) <= min(column) and max(column) < 2**63:
            kinds.append("int")
        elif found in ({float}, {str}):
            kinds.append(found.pop().__name__)
        else:
            kinds.append(None)
        values.append(column)
    return kinds, values


class TableCache:
    """The encoding of a table (a seed's rows) at a checkpoint, for the next checkpoint of the same
    seed to encode only the rows added since.

    Why: the rows only grow, and re-encoding all of them at every checkpoint cost a 1000-generation
    seed a quarter of its checkpoints' time. Trusted only as far as it is checked: rows are reused
    while the list is the same object and each of its first rows the same keys and values as when
    encoded (compared by value), so rows replaced (a resumed seed's), removed or changed are encoded
    anew."""

    def __init__(self, rows: list, seen: list, keys: tuple, kinds: list, ints, floats, strings: list):
        self.rows, self.seen = rows, seen  # the list encoded, and each row's values then
        self.keys, self.kinds = keys, kinds
        self.ints, self.floats, self.strings = ints, floats, strings

    def unchanged_rows(self, rows: list, keys: tuple) -> int:
        """How many first rows of ``rows`` are still what was encoded: all of them, or none."""
        if rows is not self.rows or keys != self.keys or len(rows) < len(self.seen):
            return 0
        same = all(tuple(r) == keys and tuple(r.values()) == values for r, values in zip(rows, self.seen))
        return len(self.seen) if same else 0


def _decode_table(body, arrays: dict, field: str) -> list:
    keys, columns, ints, floats = body["keys"], body["columns"], arrays[body["int"]], arrays[body["float"]]
    if not isinstance(keys, list) or not isinstance(columns, list) or len(keys) != len(columns) or not all(isinstance(k, str) for k in keys):
        raise ValueError(f"{field}: malformed table")
    if ints.dtype != np.int64 or floats.dtype != np.float64 or ints.ndim != 2 or floats.ndim != 2:
        raise ValueError(f"{field}: malformed table arrays")
    values = []
    for column in columns:
        if not isinstance(column, dict) or len(column) != 1:
            raise ValueError(f"{field}: malformed table column")
        ((kind, body_),) = column.items()
        if kind in ("int", "float"):
            matrix = ints if kind == "int" else floats
            if type(body_) is not int or not 0 <= body_ < matrix.shape[0]:
                raise ValueError(f"{field}: malformed table column")
            values.append(matrix[body_].tolist())  # Python ints and floats, as the rows held them
        elif kind == "str":
            if not isinstance(body_, list) or not all(isinstance(v, str) for v in body_):
                raise ValueError(f"{field}: malformed table column")
            values.append(body_)
        else:
            values.append(_decode(column, None, arrays, field))
    if len({len(v) for v in values}) > 1:
        raise ValueError(f"{field}: table columns of different lengths")
    return [dict(zip(keys, row)) for row in zip(*values)]


def _decode(node, template, arrays: dict, field: str = ""):
    """Rebuild a value; ``template`` is the fresh value of the same place (its ES, its dataclass type)."""
    if node is None or isinstance(node, (bool, int, float, str)):
        return node
    if not isinstance(node, dict) or not node:
        raise ValueError(f"{field or 'state'}: malformed node")
    if "dist" in node:
        cls = _DISTRIBUTIONS[node["dist"]]  # KeyError for an unknown class name: refused by the caller
        return cls.from_state(_decode(node["state"], None, arrays, field))
    if len(node) != 1:
        raise ValueError(f"{field or 'state'}: malformed node")
    ((tag, body),) = node.items()
    if tag == "array":
        return arrays[body]
    if tag == "rng":
        rng = np.random.Generator(np.random.PCG64())
        if not isinstance(body, dict) or body.get("bit_generator") != "PCG64":
            raise ValueError(f"{field}: not a PCG64 state")
        rng.bit_generator.state = body
        return rng
    if tag == "list":
        return [_decode(v, None, arrays, field) for v in body]
    if tag == "table":
        if not isinstance(body, dict) or sorted(body) != ["columns", "float", "int", "keys"]:
            raise ValueError(f"{field}: malformed table")
        return _decode_table(body, arrays, field)
    if tag == "dict":
        return {k: _decode(v, None, arrays, field) for k, v in body.items()}
    if tag == "generation":
        names = [f.name for f in dataclasses.fields(Generation)]
        if sorted(body) != sorted(names):
            raise ValueError(f"archived generation fields {sorted(body)}, expected {sorted(names)}")
        return Generation(**{k: _decode(v, None, arrays, k) for k, v in body.items()})
    if tag == "es":
        if template is None or not hasattr(template, "load_state_dict"):
            raise ValueError(f"{field}: an ES where none is expected")
        template.load_state_dict(_decode(body, None, arrays, field))
        return template
    if tag == "state":
        if template is None or not dataclasses.is_dataclass(template):
            raise ValueError(f"{field}: a state where none is expected")
        names = [f.name for f in dataclasses.fields(template)]
        if sorted(body) != sorted(names):
            raise ValueError(f"state fields {sorted(body)}, expected {sorted(names)}")
        values = {k: _decode(v, getattr(template, k), arrays, k) for k, v in body.items()}
        return type(template)(**values)
    raise ValueError(f"{field}: unknown node {tag!r}")
