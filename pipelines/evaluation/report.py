"""Human-readable forms of an evaluation: a markdown summary and labelled side-by-side images."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from pipelines.engine.evaluate import BINS, ViewRender
from pipelines.engine.image_baselines import LABELS
from pipelines.engine.medium_recovery import T_BINS
from pipelines.evaluation.visualize import to_png

PANEL_LABEL_HEIGHT = 16
"""Pixels of the caption band above each panel."""


def _fmt(value: Any, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def markdown_report(report: dict[str, Any]) -> str:
    """The summary table (both protocols), the binned table and a per-view table."""
    lines = [
        f"# Evaluation: {report.get('method', '?')} on {report.get('scene', '?')} ({report['split']} split, "
        f"{report['views']} views, step {report.get('step', '?')})",
        "",
        "| protocol | PSNR | SSIM | LPIPS | views |",
        "|---|---|---|---|---|",
    ]
    for name in ("restoration", "reconstruction"):
        r = report.get(name)
        if r is None:
            lines.append(f"| {name} | n/a | n/a | n/a | 0 |")
        else:
            lines.append(
                f"| {name} | {_fmt(r['psnr'], 2)} | {_fmt(r['ssim'])} | {_fmt(r['lpips'])} | {r['views']} |"
            )
    for name, r in (report.get("baselines") or {}).items():
        if r is not None:
            lines.append(
                f"| baseline: {LABELS[name]} | {_fmt(r['psnr'], 2)} | {_fmt(r['ssim'])} | {_fmt(r['lpips'])} | "
                f"{r['views']} |"
            )
    lines += _observable_lines(report.get("observable"))
    lp = report.get("lpips", {})
    if not lp.get("available", False):
        lines += ["", f"LPIPS not computed: {lp.get('reason', 'unavailable')}"]
    binned = report.get("binned")
    if binned is not None:
        lines += [
            "",
            f"Restoration by visibility (transmittance from the {binned['source']}):",
            "",
            "| bin | pixels | PSNR | SSIM |",
            "|---|---|---|---|",
        ]
        for name, _, _ in BINS:
            b = binned[name]
            lines.append(
                f"| {name} ({binned['bins'][name]}) | {100 * b['fraction']:.1f} % | {_fmt(b['psnr'], 2)} | "
                f"{_fmt(b['ssim'])} |"
            )
    lines += _medium_lines(report.get("medium"), report["per_view"])
    lines += [
        "",
        "| view | restoration PSNR / SSIM / LPIPS | reconstruction PSNR / SSIM / LPIPS |",
        "|---|---|---|",
    ]
    for row in report["per_view"]:
        cells = []
        for name in ("restoration", "reconstruction"):
            r = row.get(name)
            cells.append(
                "n/a" if r is None else f"{_fmt(r['psnr'], 2)} / {_fmt(r['ssim'])} / {_fmt(r['lpips'])}"
            )
        lines.append(f"| {row['name']} | {cells[0]} | {cells[1]} |")
    return "\n".join(lines) + "\n"


def _observable_lines(obs: dict[str, Any] | None) -> list[str]:
    """The summary row of restoration over observable pixels (only where true T maps exist)."""
    if obs is None:
        return []
    return [
        f"| restoration, observable pixels (true T >= {obs['t_floor']:g}, {100 * obs['share']:.0f} % of "
        f"the image) | {_fmt(obs['psnr'], 2)} | n/a | n/a | {obs['views']} |"
    ]


def _medium_lines(med: dict[str, Any] | None, per_view: list[dict[str, Any]]) -> list[str]:
    """The medium-recovery section (only where the dataset holds the true maps)."""
    if med is None:
        return []
    by_bin = med["t_mae_by_true_t"]
    lines = [
        "",
        "Medium recovery against the dataset's true maps (J inverted from the hazy input with T and S):",
        "",
        "| T MAE | S MAE | T / S MAE, marched to the true depth | T MAE high / mid / low true T "
        "| J PSNR, model T and S | J PSNR, true T and S |",
        "|---|---|---|---|---|---|",
        f"| {_fmt(med['t_mae'])} | {_fmt(med['s_mae'])} | "
        f"{_fmt(med.get('t_mae_true_depth'))} / {_fmt(med.get('s_mae_true_depth'))} | "
        f"{' / '.join(_fmt(by_bin[name]) for name, _, _ in T_BINS)} | {_fmt(med['inverted_psnr'], 2)} | "
        f"{_fmt(med['true_inverted_psnr'], 2)} |",
        "",
        "| view | T MAE | S MAE | J PSNR model / true |",
        "|---|---|---|---|",
    ]
    for row in per_view:
        m = row.get("medium")
        if m is not None:
            lines.append(
                f"| {row['name']} | {_fmt(m['t_mae'])} | {_fmt(m['s_mae'])} | "
                f"{_fmt(m.get('inverted_psnr'), 2)} / {_fmt(m.get('true_inverted_psnr'), 2)} |"
            )
    return lines


def _labelled(img: np.ndarray, label: str) -> np.ndarray:
    band = np.full((PANEL_LABEL_HEIGHT, img.shape[1], 3), 255, np.uint8)
    cv2.putText(
        band, label, (3, PANEL_LABEL_HEIGHT - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA
    )
    return np.concatenate([band, img], axis=0)


def side_by_side(view: ViewRender) -> np.ndarray:
    """hazy | ours clean | reference | transmittance, captioned; [H + 16, 4 W, 3] uint8 RGB.

    The hazy panel is the input photo, or the method's hazy render where the view's input is a clean
    reference; a missing reference is a grey panel.
    """
    out = view.outputs
    clean = to_png(out["clean"])
    if view.hazy_input is not None:
        hazy, hazy_label = to_png(view.hazy_input), "hazy input"
    else:
        hazy, hazy_label = to_png(out["hazy"]), "hazy (render)"
    ref = to_png(view.reference) if view.reference is not None else np.full_like(clean, 128)
    panels = [
        _labelled(hazy, hazy_label),
        _labelled(clean, "ours clean"),
        _labelled(ref, "reference" if view.reference is not None else "no reference"),
        _labelled(to_png(out["transmittance"], (0.0, 1.0)), "transmittance"),
    ]
    return np.concatenate(panels, axis=1)


def medium_panels(view: ViewRender) -> np.ndarray | None:
    """model T | true T | model S | true S, captioned (None where the view has no true T or the
    method no medium); [H + 16, 4 W, 3] uint8 RGB, a missing true S a grey panel."""
    out = view.outputs
    if view.true_transmittance is None or "scattering" not in out:
        return None
    true_s = view.true_scattering
    grey = np.full_like(to_png(out["scattering"]), 128)
    return np.concatenate(
        [
            _labelled(to_png(out["transmittance"], (0.0, 1.0)), "model T"),
            _labelled(to_png(view.true_transmittance, (0.0, 1.0)), "true T"),
            _labelled(to_png(out["scattering"]), "model S"),
            _labelled(
                to_png(true_s) if true_s is not None else grey,
                "true S" if true_s is not None else "no true S",
            ),
        ],
        axis=1,
    )
