"""Griffe extensions for the API page (mkdocs.yml: mkdocstrings' ``extensions``).

:class:`SphinxRoles`: imix's docstrings name other objects with Sphinx roles
(``:class:`~imix_cli.core.mixing.generation.MixingSettings```), as its numerical core is written; mkdocstrings renders
Markdown, where a role would show raw. Each role becomes inline code with the name as Sphinx would print it (``~``
keeps the last component), before the docstring is parsed.

:class:`NamedDefaults`: a parameter whose default is a field of a declared record
(``min_fresh=MIXING_DEFAULTS.min_fresh``: each mixing default is declared once) shows the field's value, as
``help()`` does, not the expression griffe reads from the source.
"""

import functools
import importlib
import re

import griffe

ROLE = re.compile(r":(?:py:)?(?:class|func|data|mod|meth|attr|obj|exc|const|type):`(~?)([^`<]+?)(?:\s*<([^>]+)>)?`")


def plain(docstring: str) -> str:
    """Each role as inline code: ``:func:`~imix_cli.core.mixing.mix``` -> ```mix```, ``:class:`Params``` -> ```Params```."""

    def name(match: re.Match) -> str:
        tilde, target, _ = match.groups()
        target = target.strip()
        return f"`{target.rsplit('.', 1)[-1] if tilde else target}`"

    return ROLE.sub(name, docstring)


class SphinxRoles(griffe.Extension):
    def on_instance(self, *, obj, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = plain(obj.docstring.value)


#: A default that names a field of a module-level record: ``MIXING_DEFAULTS.min_fresh``.
NAMED_DEFAULT = re.compile(r"[A-Z][A-Z0-9_]*(?:\.[A-Za-z_]\w*)+")


class NamedDefaults(griffe.Extension):
    def on_function_instance(self, *, func, **kwargs) -> None:
        for parameter in func.parameters:
            text = "" if parameter.default is None else str(parameter.default)
            if NAMED_DEFAULT.fullmatch(text):
                record, *path = text.split(".")
                value = functools.reduce(getattr, path, vars(importlib.import_module(func.module.path))[record])
                parameter.default = repr(value)
