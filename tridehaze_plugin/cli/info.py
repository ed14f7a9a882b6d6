"""``td-info``: list registered components by kind, where they came from, and plugins that failed."""

from __future__ import annotations

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from tridehaze_plugin import __version__
from tridehaze_plugin.cli.common import run_cli
from tridehaze_plugin.registry import KINDS, load_all


def main() -> None:
    registry = load_all(warn=lambda _msg: None)
    console = Console()
    table = Table(title=f"tridehaze {__version__}: registered components")
    for col in ("kind", "name", "from", "description"):
        table.add_column(col, overflow="fold")
    for kind in KINDS:
        for e in registry.entries(kind):
            # descriptions are plain text: "[x, sin(...)]" must not be read as rich markup
            table.add_row(kind, escape(e.name), escape(e.origin), escape(e.description))
    console.print(table)
    for failure in registry.failures:
        console.print(f"[red]failed plugin[/]: {escape(failure.message())}")


def entrypoint() -> None:
    run_cli(main)


if __name__ == "__main__":
    entrypoint()
