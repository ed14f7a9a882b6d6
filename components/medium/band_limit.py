"""A Gaussian low-pass of a feature grid, for a medium that learns coarse before fine.

The extinction field can take up a surface's texture in front of it (a thin slab of haze is a
change of colour to the photometric loss), and it learns faster than the still coarse Gaussians
early in Stage I. Blurring the grid's features in the forward pass, with a width that falls to
zero as the medium learns, lets only smooth haze form first (coarse-to-fine, as BARF or
Neuralangelo anneal their encodings); the gradient reaching the grid is blurred alike.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor
from torch.nn import functional as F

MIN_SIGMA = 1e-3
"""A blur narrower than this (in grid cells) is the identity."""


def gaussian_kernel(sigma: float) -> Tensor:
    """The normalised 1D Gaussian [2 r + 1] of std ``sigma`` cells, r = ceil(3 sigma)."""
    radius = max(1, math.ceil(3.0 * sigma))
    x = torch.arange(-radius, radius + 1, dtype=torch.float32)
    k = torch.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


def blur_grid(grid: Tensor, sigma: float) -> Tensor:
    """``grid`` [B, C, *S] (S: 2 or 3 spatial dims) low-passed along every spatial dim by a
    Gaussian of std ``sigma`` cells, the border replicated (a constant field stays constant).
    ``sigma`` below :data:`MIN_SIGMA` returns ``grid`` itself."""
    if sigma < MIN_SIGMA:
        return grid
    dims = grid.dim() - 2
    if dims not in (2, 3):
        raise ValueError(f"blur_grid takes a [B, C, H, W] or [B, C, D, H, W] grid, got {tuple(grid.shape)}")
    k = gaussian_kernel(sigma).to(grid)
    r = (len(k) - 1) // 2
    out = grid
    for axis in range(dims):  # separable: one 1D pass per spatial axis
        moved = out.movedim(2 + axis, -1)  # [B, C, ..., L]
        shape = moved.shape
        flat = moved.reshape(-1, 1, shape[-1])  # [B C ..., 1, L]
        # replicate padding needs more cells than the radius only for tiny grids: clamp the index
        idx = torch.arange(-r, shape[-1] + r, device=grid.device).clamp(0, shape[-1] - 1)
        padded = flat[..., idx]  # [N, 1, L + 2 r]
        smooth = F.conv1d(padded, k.view(1, 1, -1))  # [N, 1, L]
        out = smooth.reshape(shape).movedim(-1, 2 + axis)
    return out


def coarse_to_fine_sigma(step: int, start: int, end: int, sigma0: float) -> float:
    """The blur (cells) at ``step``: ``sigma0`` until ``start``, linear to 0 at ``end``, 0 after."""
    if sigma0 <= 0 or step >= end:
        return 0.0
    if step <= start:
        return float(sigma0)
    return float(sigma0) * (end - step) / max(end - start, 1)
