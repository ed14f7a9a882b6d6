"""Command-line entry points (``td-*``)."""
