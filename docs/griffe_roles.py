"""A griffe extension for the API page (mkdocs.yml: mkdocstrings' ``extensions``): imix's docstrings name
other objects with Sphinx roles (``:class:`~imix_cli.core.generation.MixingSettings```), as its numerical core
is written; mkdocstrings renders Markdown, where a role would show raw. Each role becomes inline code
with the name as Sphinx would print it (``~`` keeps the last component), before the docstring is parsed.
"""

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
