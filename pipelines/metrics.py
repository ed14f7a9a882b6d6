"""Image metrics shared by training readouts and evaluation."""

from __future__ import annotations

import torch
from torch import Tensor


def psnr(pred: Tensor, target: Tensor) -> Tensor:
    """PSNR in dB for images in [0, 1] (any matching shape); 100 dB caps a perfect match."""
    mse = torch.mean((pred.clamp(0, 1) - target) ** 2)
    return torch.where(mse > 1e-10, -10.0 * torch.log10(mse.clamp_min(1e-10)), torch.full_like(mse, 100.0))
