"""Writing a benchmark's results: the rows as JSON and the printed table as markdown, side by side."""

from __future__ import annotations

import json
from pathlib import Path


def write_rows_and_table(stem: Path, rows: list[dict], title: str, how: str, table: str) -> None:
    """``stem``.json (the rows) and ``stem``.md (``# title``, the command line ``how``, the table)."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    stem.with_suffix(".json").write_text(json.dumps(rows, indent=2))
    stem.with_suffix(".md").write_text(f"# {title}\n\n{how}\n\n{table}")
