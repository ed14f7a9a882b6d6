"""Differentiable image filters used inside losses."""

from __future__ import annotations

import math

import kornia
from torch import Tensor


def low_pass(image: Tensor, sigma: float) -> Tensor:
    """Gaussian blur of ``image`` [H, W, C] with standard deviation ``sigma`` pixels (reflected
    borders; the kernel shrinks to fit images smaller than it)."""
    H, W = image.shape[:2]
    radius = min(math.ceil(3.0 * sigma), (min(H, W) - 1) // 2)
    if radius < 1:
        return image
    size = 2 * radius + 1
    x = image.permute(2, 0, 1)[None]  # [1, C, H, W]
    y = kornia.filters.gaussian_blur2d(x, (size, size), (sigma, sigma), border_type="reflect")
    return y[0].permute(1, 2, 0)  # [H, W, C]
