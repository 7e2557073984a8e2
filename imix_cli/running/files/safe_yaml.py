"""Every YAML file imix reads, through one bounded loader: size, nesting, alias expansion and tags checked first.

A user's ``--config-dir`` file (and whatever Hydra pulls from the config folders through ``defaults``), and a run
folder's ``config.yaml`` read back by run, plot, eval and status, pass :func:`check_yaml_text` before Hydra, OmegaConf
or a reader builds anything from them. The check composes the document with PyYAML's composer -- a graph of nodes in
which an alias is the node it names, shared, never copied -- and measures that graph as its consumers would see it
expanded: OmegaConf copies every alias (a "billion laughs" file of nine anchors of nine aliases each is 9**9 nodes;
Hydra composing one ran for minutes and took gigabytes), and a message showing a value shows it expanded too.

Refused, in one line naming the file (:class:`BadYamlError`), a document that

- is larger than :data:`MAX_YAML_BYTES` (a real config is a few kB),
- is not valid YAML (the line and PyYAML's problem),
- is nested deeper than :data:`MAX_YAML_DEPTH` levels, counting through aliases,
- holds more than :data:`MAX_YAML_NODES` nodes once its aliases are expanded, or an alias inside its own anchor,
- carries a tag no safe loader constructs (``!!python/object/apply:os.system``): imix reads data, never objects.

Counting is linear in the size of the file: each node of the graph is measured once (its expanded size memoised).
"""

from __future__ import annotations

from pathlib import Path

import yaml

from imix_cli.running.files.results import regular_file_size

__all__ = ["MAX_YAML_BYTES", "MAX_YAML_DEPTH", "MAX_YAML_NODES", "BadYamlError", "check_yaml_file", "check_yaml_text", "load_yaml_file"]

#: The largest YAML file imix reads (a config is a few kB; conf/config.yaml is ~5 kB).
MAX_YAML_BYTES = 1 << 20
#: The most nodes (scalars, lists, mappings, keys included) a document may have once its aliases are expanded: a run
#: folder's config.yaml has ~100, Hydra's whole composed config ~600.
MAX_YAML_NODES = 10_000
#: The deepest nesting a document may have (imix's own configs: 4 levels).
MAX_YAML_DEPTH = 64

#: The tags a safe loader constructs (plain data), and the merge key ``<<``.
_SAFE_TAGS = frozenset({*(tag for tag in yaml.SafeLoader.yaml_constructors if tag is not None), "tag:yaml.org,2002:merge"})


class BadYamlError(ValueError):
    """A YAML file imix does not read; ``str(err)`` is one line naming the file and why."""


class _BoundedComposer(yaml.SafeLoader):
    """SafeLoader whose composer refuses nesting deeper than :data:`MAX_YAML_DEPTH` while it composes (PyYAML's
    composer recurses: 100,000 ``[`` would end in a RecursionError)."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise _Refused(f"line {self.peek_event().start_mark.line + 1}: nested more than {MAX_YAML_DEPTH} levels deep")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


class _Refused(Exception):
    """Why a document is refused, without its file's name (added by :func:`check_yaml_text`)."""


def _tag_shown(tag: str) -> str:
    short = "!!" + tag[len("tag:yaml.org,2002:") :] if tag.startswith("tag:yaml.org,2002:") else tag
    return short if len(short) <= 80 and short.isprintable() else repr(short[:80]) + "..."


def _measure(root) -> None:
    """Raise :class:`_Refused` if the node graph under ``root``, aliases expanded, has more than :data:`MAX_YAML_NODES`
    nodes, is deeper than :data:`MAX_YAML_DEPTH`, loops (an alias inside its own anchor) or carries an unsafe tag.
    Each distinct node is measured once; the recursion stops at the depth bound."""
    measured: dict[int, tuple[int, int]] = {}  # node -> (its expanded size, its height: levels below it, itself included)
    open_nodes: set[int] = set()

    def deep(node) -> _Refused:
        line = node.start_mark.line + 1 if node.start_mark is not None else "?"
        return _Refused(f"line {line}: nested more than {MAX_YAML_DEPTH} levels deep once its aliases are expanded")

    def measure(node, depth: int) -> tuple[int, int]:
        key = id(node)
        if key in measured:
            size, height = measured[key]
            if depth + height - 1 > MAX_YAML_DEPTH:  # an alias puts a measured node deeper than where it was met first
                raise deep(node)
            return size, height
        line = node.start_mark.line + 1 if node.start_mark is not None else "?"
        if key in open_nodes:
            raise _Refused(f"line {line}: an alias inside its own anchor (a recursive structure)")
        if depth > MAX_YAML_DEPTH:
            raise deep(node)
        if node.tag not in _SAFE_TAGS:
            raise _Refused(f"line {line}: the tag {_tag_shown(node.tag)} is not allowed (imix reads plain data, never Python objects); remove it")
        open_nodes.add(key)
        if isinstance(node, yaml.MappingNode):
            children = [child for pair in node.value for child in pair]
        elif isinstance(node, yaml.SequenceNode):
            children = node.value
        else:
            children = []
        size, height = 1, 1
        for child in children:
            child_size, child_height = measure(child, depth + 1)
            size, height = size + child_size, max(height, child_height + 1)
            if size > MAX_YAML_NODES:
                raise _Refused(f"line {line}: more than {MAX_YAML_NODES:,} values once its aliases are expanded (an alias bomb?); a config has a few hundred")
        open_nodes.discard(key)
        measured[key] = size, height
        return size, height

    measure(root, 1)


def _dispose(loader) -> None:
    if loader is not None:
        loader.dispose()


def _compose(text: str, where: str):
    """The loader (positioned after the document) and the document's root node (None for an empty document)."""
    loader = None
    try:
        loader = _BoundedComposer(text)
        node = loader.get_single_node()
        if node is not None:
            _measure(node)
        return loader, node
    except _Refused as why:
        _dispose(loader)
        raise BadYamlError(f"{where}: {why}") from None
    except yaml.MarkedYAMLError as err:
        _dispose(loader)
        mark = err.problem_mark or err.context_mark
        at = f"line {mark.line + 1}: " if mark is not None else ""
        problem = " ".join(str(err.problem or err.context or type(err).__name__).split())[:200]
        raise BadYamlError(f"{where}: not valid YAML ({at}{problem})") from None
    except (yaml.YAMLError, RecursionError, ValueError) as err:  # a reader error (a NUL, a non-printable character)
        _dispose(loader)
        problem = " ".join(str(err).split())[:200] or type(err).__name__
        raise BadYamlError(f"{where}: not valid YAML ({problem})") from None


def check_yaml_text(text: str, where) -> None:
    """Raise :class:`BadYamlError` (one line starting with ``where``, the file's name) unless ``text`` is a YAML document
    within the bounds above; build nothing."""
    if len(text) > MAX_YAML_BYTES:
        raise BadYamlError(f"{where}: more than the {MAX_YAML_BYTES:,} bytes a config may have")
    loader, _ = _compose(text, where)
    loader.dispose()


def _text_of(path, limit: int) -> str:
    size = regular_file_size(path)
    if size > limit:
        raise BadYamlError(f"{path}: {size:,} bytes, more than the {limit:,} bytes a config may have")
    try:
        return Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise BadYamlError(f"{path}: not UTF-8 text (byte {err.start})") from None


def check_yaml_file(path, limit: int = MAX_YAML_BYTES) -> None:
    """:func:`check_yaml_text` of the file ``path``, a regular file of at most ``limit`` bytes of UTF-8:
    :class:`BadYamlError` naming the file, OSError if it cannot be read at all."""
    check_yaml_text(_text_of(path, limit), path)


def load_yaml_file(path, limit: int = MAX_YAML_BYTES):
    """The data of the YAML file ``path`` (plain dicts, lists, strings, numbers; aliases shared), read through the
    bounded loader: :class:`BadYamlError` naming the file if it is refused (see the module), OSError if unreadable."""
    loader, node = _compose(_text_of(path, limit), path)
    try:
        return None if node is None else loader.construct_document(node)
    except yaml.YAMLError as err:  # a value of a safe tag that does not construct (a bad timestamp, say)
        raise BadYamlError(f"{path}: not valid YAML ({' '.join(str(err).split())[:200]})") from None
    finally:
        loader.dispose()
