"""The docstrings of a dataclass's fields (the string literal under each field), read from its source once: one
help text per field, for the configs' own documentation and for the command-line flags generated from them."""

from __future__ import annotations

import ast
import inspect
import textwrap
from functools import lru_cache


@lru_cache(maxsize=None)
def field_docs(cls: type) -> dict[str, str]:
    """{field name: its docstring, whitespace collapsed} for the fields of ``cls`` that have one."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError):  # no source (a frozen build): no help texts, nothing else lost
        return {}
    body = tree.body[0].body
    docs = {}
    for node, after in zip(body, body[1:]):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)):
            docs[node.target.id] = " ".join(after.value.value.split())
    return docs


ABBREVIATIONS = ("e.g", "i.e", "vs", "cf", "etc")


def first_sentence(text: str, limit: int = 200) -> str:
    """The text up to its first full stop followed by a space (or the end; not the stop of an abbreviation such as
    'e.g.'), at most ``limit`` characters."""
    cut = text.find(". ")
    while cut >= 0 and text[:cut].lower().endswith(ABBREVIATIONS):
        cut = text.find(". ", cut + 2)
    sentence = text if cut < 0 else text[:cut + 1]
    return sentence if len(sentence) <= limit else sentence[:limit - 3].rstrip() + "..."
