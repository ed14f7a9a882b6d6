"""Field docstrings as ``--help`` text, reflowed as PEP 257 docstrings are.

tyro joins a docstring's single line breaks only before lines that start with a letter, and it
reads a dataclass field's docstring with its source indentation, so every continuation line of a
multi-line field docstring kept its break and ``--help`` came out ragged. Each description is
dedented first (``inspect.cleandoc``), then a continuation line that starts with something other
than a letter ("(only once ...", "-1.3 to ...") is joined too; lines indented beyond the rest
(examples), bullets ("- ", "* ", "1. ") and blank lines still break.
"""

from __future__ import annotations

import functools
import inspect
import re

try:  # private: the patch below leaves tyro alone where its shape changes
    from tyro import _docstrings
except ImportError:  # pragma: no cover - depends on the installed tyro
    _docstrings = None


def reflow_field_docstrings() -> None:
    """Dedent the field descriptions tyro reads (idempotent; a no-op on a tyro without the hook)."""
    parse = getattr(_docstrings, "parse_docstring_from_object", None)
    if parse is None or getattr(parse, "reflowed", False):
        return

    @functools.wraps(parse)
    def parse_dedented(obj: object) -> dict[str, str]:
        return {name: join_continuations(inspect.cleandoc(text)) for name, text in parse(obj).items()}

    parse_dedented.reflowed = True  # type: ignore[attr-defined]
    _docstrings.parse_docstring_from_object = parse_dedented


_BULLET = re.compile(r"(?:[-*+]|\d+[.)])\s")
"""A line that starts a list item keeps its break."""


def join_continuations(text: str) -> str:
    """Join each line of a dedented paragraph onto the one before (not bullets, indented lines,
    blank lines, or the lines after them)."""
    out: list[str] = []
    for line in text.split("\n"):
        prev = out[-1] if out else ""
        joins = prev.strip() and line.strip() and not prev[:1].isspace() and not line[:1].isspace()
        if joins and not _BULLET.match(line):
            out[-1] = f"{prev} {line}"
        else:
            out.append(line)
    return "\n".join(out)
