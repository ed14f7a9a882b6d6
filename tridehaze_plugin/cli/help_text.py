"""Field docstrings as ``--help`` text, reflowed as PEP 257 docstrings are.

tyro joins a docstring's single line breaks only before lines that start with a letter, and it
reads a dataclass field's docstring with its source indentation, so every continuation line of a
multi-line field docstring kept its break and ``--help`` came out ragged. Dedenting each
description first (``inspect.cleandoc``) lets tyro's own reflow work; lines indented beyond the
rest (examples) and lines that start with a bullet or a parenthesis still break.
"""

from __future__ import annotations

import functools
import inspect

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
        return {name: inspect.cleandoc(text) for name, text in parse(obj).items()}

    parse_dedented.reflowed = True  # type: ignore[attr-defined]
    _docstrings.parse_docstring_from_object = parse_dedented
