"""Image metrics shared by training readouts and evaluation."""

from __future__ import annotations

import torch
from torch import Tensor

from components.metrics.ssim import ssim_bchw


def psnr(pred: Tensor, target: Tensor) -> Tensor:
    """PSNR in dB for images in [0, 1] (any matching shape); 100 dB caps a perfect match."""
    mse = torch.mean((pred.clamp(0, 1) - target) ** 2)
    return torch.where(mse > 1e-10, -10.0 * torch.log10(mse.clamp_min(1e-10)), torch.full_like(mse, 100.0))


def ssim_map(pred: Tensor, target: Tensor) -> Tensor:
    """Per-pixel SSIM [H, W] (11x11 Gaussian window, smaller on tiny images; channel mean) of
    [H, W, 3] images in [0, 1]."""
    a = pred.clamp(0, 1).permute(2, 0, 1)[None]  # [1, 3, H, W]
    b = target.permute(2, 0, 1)[None]
    return ssim_bchw(a, b, 11)[0].mean(0)


def ssim(pred: Tensor, target: Tensor) -> Tensor:
    """Mean SSIM (11x11 Gaussian window, as in 3DGS evaluation) of [H, W, 3] images in [0, 1]."""
    return ssim_map(pred, target).mean()
