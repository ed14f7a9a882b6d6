"""Command-line entry points (``td-*``)."""

from tridehaze_plugin.cli.help_text import reflow_field_docstrings

reflow_field_docstrings()
