"""Publishing a benchmark's results: the table printed, the rows as JSON, the table as markdown
and the figure, side by side under one output stem."""

from __future__ import annotations

import argparse
import json
import math
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


def fmt(v: float | None, digits: int = 3, sign: bool = False) -> str:
    """A table cell: ``-`` for a missing value, else ``digits`` decimals (signed with ``sign``)."""
    if v is None:
        return "-"
    return f"{v:+.{digits}f}" if sign else f"{v:.{digits}f}"


def psnr_of_mse(mse: float) -> float:
    """PSNR (dB, peak 1) of a mean squared error, floored at 1e-12 so a perfect match is finite."""
    return -10.0 * math.log10(max(mse, 1e-12))


def mean_or_none(xs: list[float | None] | None) -> float | None:
    """The mean of the values that are there; None where none is."""
    vals = [x for x in xs or [] if x is not None]
    return sum(vals) / len(vals) if vals else None


def diagnose_runs_main(
    doc: str,
    diagnose: Callable[[Path], dict],
    title: str,
    how: str,
    table: Callable[[list[dict]], str],
    plot: Callable[[list[dict], Path], None],
    order: Callable[[dict], object] | None = None,
) -> None:
    """The command line of a diagnosis of trained runs: ``--runs CONFIG.yml ... --output STEM``,
    one row per run from ``diagnose`` (without autograd), sorted by ``order`` when given, then
    :func:`publish`."""
    import torch

    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=Path, nargs="+", required=True, help="config.yml of trained runs")
    ap.add_argument("--output", type=Path, required=True, help="output stem: writes .json, .md, .png")
    args = ap.parse_args()
    torch.set_grad_enabled(False)
    rows = [diagnose(c) for c in args.runs]
    if order is not None:
        rows.sort(key=order)
    publish(args.output, rows, title, how, table(rows), plot)


def grouped_bars(
    path: Path,
    labels: list[str],
    series: list[tuple[str, list[float]]],
    ylabel: str,
    legend_above: bool = False,
    zero_line: bool = False,
) -> None:
    """One group of bars per label (one bar per series, values in label order), written to ``path``;
    ``zero_line`` draws y = 0 (for signed values)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(max(6, 0.8 * len(labels)), 4))
    width = 0.8 / len(series)
    for i, (name, values) in enumerate(series):
        xs = [x + (i - (len(series) - 1) / 2) * width for x in range(len(labels))]
        ax.bar(xs, values, width, label=name, color=f"C{i}")
    if zero_line:
        ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xticks(range(len(labels)), labels, fontsize=6, rotation=60, ha="right")
    ax.set_ylabel(ylabel)
    if legend_above:
        ax.legend(fontsize=7, ncol=len(series), loc="lower center", bbox_to_anchor=(0.5, 1.0))
    else:
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
