"""Publishing a benchmark's results: the table printed, the rows as JSON, the table as markdown
and the figure, side by side under one output stem."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path


def publish(
    stem: Path, rows: list[dict], title: str, how: str, table: str, plot: Callable[[list[dict], Path], None]
) -> None:
    """Print ``table``; write ``stem``.json (the rows), ``stem``.md (``# title``, the command line
    ``how``, the table) and ``stem``.png (``plot(rows, path)``)."""
    print(table)
    stem.parent.mkdir(parents=True, exist_ok=True)
    stem.with_suffix(".json").write_text(json.dumps(rows, indent=2))
    stem.with_suffix(".md").write_text(f"# {title}\n\n{how}\n\n{table}")
    plot(rows, stem.with_suffix(".png"))
