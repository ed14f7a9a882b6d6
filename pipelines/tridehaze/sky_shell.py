"""Seed Gaussians on a sphere around the scene, for the sky and the far background.

Structure from motion finds no point in the sky or on a background too far for parallax, so no
Gaussian starts there; with a random training background every pixel must still be covered, and the
optimiser covers those pixels with whatever is nearest: large Gaussians close to the cameras, which
other views then see as floaters, and which end the medium's march far too early (on the generated
fields the sky is rendered at 0.1-0.4 of its depth). Seeding a shell just outside the medium's box
gives those pixels a surface at a depth every view agrees on, the way 3DGS users add a sky sphere.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from components.losses.depth_priors import in_image, project_points
from components.medium.base import FieldBounds
from pipelines.engine.datamanager import DataManager


def fibonacci_sphere(n: int) -> Tensor:
    """[n, 3] unit vectors spread evenly over the sphere (golden-angle spiral)."""
    k = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1.0 - 2.0 * k / n
    r = (1.0 - z * z).clamp_min(0.0).sqrt()
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    return torch.stack([r * phi.cos(), r * phi.sin(), z], dim=-1).float()


def sky_shell(dm: DataManager, bounds: FieldBounds, count: int) -> tuple[Tensor, Tensor]:
    """Points [M, 3] on the sphere circumscribing the medium's box (``count`` over the whole sphere)
    and their colours [M, 3] in [0, 1]: the mean input colour where the training views see them.
    Only points some training view sees are kept (M <= count; M = 0 is possible)."""
    center = bounds.center.detach().float().cpu()
    radius = float(bounds.half_size.detach().float().cpu().norm())
    pts = center + radius * fibonacci_sphere(count)  # [count, 3]
    total = torch.zeros(count, 3)
    seen = torch.zeros(count)
    for i in dm.train_indices:
        cam = dm.camera(i).to("cpu")
        W, H = int(cam.width[0]), int(cam.height[0])
        pc, uv = project_points(pts, cam.viewmats()[0].float(), cam.Ks()[0].float())
        ok = in_image(pc, uv, W, H, near=1e-3)
        px = uv[ok].long()
        total[ok] += dm.image(i).detach().float().cpu()[px[:, 1], px[:, 0]]  # [m, 3]
        seen[ok] += 1.0
    keep = seen > 0
    return pts[keep], total[keep] / seen[keep, None]
