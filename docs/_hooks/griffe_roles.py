"""Griffe extension for the API pages: the package's docstrings are written with Sphinx roles
(``:class:`~warp_iisph.scene.Scene```, ``:func:`set_threads```, ``:mod:`.formats```) and
reStructuredText literal blocks (``Example::``); MkDocs renders Markdown, so each role becomes inline
code of the name it shows (the last dotted part after a ``~``, else the name as written) and ``::``
before an indented block becomes ``:``. The docstrings themselves stay as they are.
"""

from __future__ import annotations

import re

import griffe

ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|attr|data|obj|exc|const):`(~?)([^`]+)`")
LITERAL = re.compile(r"::[ \t]*\n(?=[ \t]*\n)")


def _shown(match: re.Match) -> str:
    short, name = match.group(1), match.group(2)
    if short:
        name = name.split(".")[-1]
    return f"`{name}`"


def markdown_of(text: str) -> str:
    return LITERAL.sub(":\n", ROLE.sub(_shown, text))


class SphinxRoles(griffe.Extension):
    def on_instance(self, *, obj, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = markdown_of(obj.docstring.value)
