"""Griffe extension of the API reference (``mkdocs.yml``: the python handler's ``extensions``).

The docstrings name other objects with Sphinx roles (``:class:`slam.core.rbpf.RBPFSlam```,
``:func:`~agents.evaluate.run_episode```), which Markdown would print as they are. This
extension turns each into inline code (``slam.core.rbpf.RBPFSlam``; with ``~``, the last
name only, as Sphinx shows it), and a paragraph's closing ``::`` (which introduces an
indented literal block, already a code block in Markdown) into ``:``, before the
docstrings are rendered.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

LITERAL = re.compile(r"(?<=\S)::$", re.MULTILINE)  # "Scene::" introducing an indented block
ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|attr|data|obj|exc|const|ref):`(?P<tilde>~?)(?P<target>[^`]+)`")


def plain(text: str) -> str:
    """``text`` with its Sphinx cross-reference roles as inline code and ``::`` as ``:``.

    >>> plain("Runs :func:`~agents.evaluate.run_episode` on :class:`slam.core.rbpf.RBPFSlam`. Input::")
    'Runs `run_episode` on `slam.core.rbpf.RBPFSlam`. Input:'
    """

    def code(m: re.Match) -> str:
        target = m.group("target")
        return f"`{target.rsplit('.', 1)[-1] if m.group('tilde') else target}`"

    return LITERAL.sub(":", ROLE.sub(code, text))


class SphinxRoles(griffe.Extension):
    def on_instance(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = plain(obj.docstring.value)
