"""A prior on the Gaussians' opacities."""

from __future__ import annotations

import torch
from torch import Tensor

EPS = 1e-6
"""Opacities are clamped this far from 0 and 1, where the entropy's gradient is infinite."""


def opacity_entropy(opacities: Tensor) -> Tensor:
    """Mean binary entropy (nats) of opacities [N]: 0 where every Gaussian is opaque or empty, ln 2
    where all are half transparent. Its gradient pushes each opacity away from 1/2."""
    o = opacities.clamp(EPS, 1.0 - EPS)
    if o.numel() == 0:
        return o.sum()
    return -(o * torch.log(o) + (1.0 - o) * torch.log1p(-o)).mean()
