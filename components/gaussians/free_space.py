"""Which Gaussians float in free space in front of the surfaces the views see.

In hazy captures the Gaussians can take part of the haze as half-transparent grey splats in front
of the far surfaces, where the medium should be (measured on the default's runs: 24-55 % of the
alpha of the farthest surfaces' pixels comes from Gaussians 15 % or more in front of the true
surface; docs/results/medium_recovery.md, session 57). A Gaussian whose centre lies well in front
of the surface in most views that see its centre is such a floater.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch
from torch import Tensor


def in_front_counts(
    means: Tensor, views: Iterable[tuple[Tensor, Tensor, Tensor]], margin: float
) -> tuple[Tensor, Tensor]:
    """Per Gaussian, in how many views its centre lies more than ``margin`` (relative) in front of
    the view's surface depth at the pixel it projects to, and in how many views it projects onto a
    surface pixel at all.

    means: [N, 3] world; each view: (viewmat [4, 4] world -> camera, K [3, 3], depth [H, W] camera
    z of the surface, non-finite or <= 0 where the pixel has none (sky, no data)).
    Returns (in_front [N], seen [N]), both int64."""
    n = means.shape[0]
    in_front = torch.zeros(n, dtype=torch.int64, device=means.device)
    seen = torch.zeros_like(in_front)
    for viewmat, K, depth in views:
        viewmat, K, depth = viewmat.to(means), K.to(means), depth.to(means)
        pc = means @ viewmat[:3, :3].T + viewmat[:3, 3]  # [N, 3] camera frame
        z = pc[:, 2]
        z_safe = z.clamp_min(1e-9)
        u = torch.floor(K[0, 0] * pc[:, 0] / z_safe + K[0, 2]).long()  # [N] pixel column
        v = torch.floor(K[1, 1] * pc[:, 1] / z_safe + K[1, 2]).long()  # [N] pixel row
        h, w = depth.shape
        inside = (z > 1e-6) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        surface = torch.zeros_like(z)
        surface[inside] = depth[v[inside], u[inside]]
        on_surface = inside & torch.isfinite(surface) & (surface > 0)
        seen += on_surface.long()
        in_front += (on_surface & (z < (1.0 - margin) * surface)).long()
    return in_front, seen


def floaters(in_front: Tensor, seen: Tensor, share: float, min_views: int = 2) -> Tensor:
    """[N] bool: Gaussians seen on a surface pixel in at least ``min_views`` views and in front of
    the surface in more than ``share`` of them."""
    return (seen >= min_views) & (in_front.double() > share * seen.double())
