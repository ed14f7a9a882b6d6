"""Pipeline outputs as 8-bit images: turbo colour maps for one-channel outputs.

Shared by td-render, td-eval's side-by-side images and the viewer, so a transmittance map looks the
same everywhere.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

UNIT_RANGE = ("transmittance", "alpha")
"""One-channel outputs colour-mapped over the fixed range [0, 1] (comparable across views)."""


def colormap(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """[H, W] -> uint8 RGB [H, W, 3], turbo over [lo, hi]."""
    norm = ((x - lo) / max(hi - lo, 1e-12)).clip(0, 1)
    bgr = cv2.applyColorMap((np.nan_to_num(norm) * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    return bgr[..., ::-1].copy()


def value_range(x: np.ndarray) -> tuple[float, float]:
    """1-99 % range of the finite (and, if any, positive) values of a one-channel map."""
    finite = x[np.isfinite(x) & (x > 0)] if (x > 0).any() else x[np.isfinite(x)]
    if not finite.size:
        return 0.0, 1.0
    lo, hi = np.percentile(finite, [1, 99])
    return float(lo), float(hi)


def to_png(value: torch.Tensor, vrange: tuple[float, float] | None = None) -> np.ndarray:
    """[H, W, 3] in [0, 1] -> uint8 RGB; [H, W, 1] -> turbo colour map over ``vrange`` (default:
    its own 1-99 % range)."""
    arr = value.detach().float().cpu().numpy()
    if arr.shape[-1] == 3:
        return (arr.clip(0, 1) * 255 + 0.5).astype(np.uint8)
    x = arr[..., 0]
    lo, hi = value_range(x) if vrange is None else vrange
    return colormap(x, lo, hi)
