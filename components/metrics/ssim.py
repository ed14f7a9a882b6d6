"""SSIM (kornia) that also works on images smaller than its window.

kornia pads by half the window with reflection, which needs every side longer than that half: an
11x11 window fails on a 5-pixel side (tiny native images are accepted by the data layer). The
window shrinks to the largest odd size the image allows; on images at least 6 pixels a side the
result is kornia's own, unchanged.
"""

from __future__ import annotations

import kornia
from torch import Tensor


def fitted_window(window: int, height: int, width: int) -> int:
    """The largest odd window <= ``window`` whose half is shorter than both sides (>= 1)."""
    limit = 2 * min(height, width) - 1
    w = min(window, limit)
    return max(1, w if w % 2 else w - 1)


def ssim_bchw(pred: Tensor, target: Tensor, window: int) -> Tensor:
    """Per-pixel SSIM [B, C, H, W] of [B, C, H, W] images in [0, 1], Gaussian ``window``."""
    w = fitted_window(window, pred.shape[-2], pred.shape[-1])
    if w < 3:  # a 1-2 pixel side has no neighbourhood: SSIM degenerates to comparing the pixels
        return 1.0 - (pred - target).abs()
    return kornia.metrics.ssim(pred, target, w)
