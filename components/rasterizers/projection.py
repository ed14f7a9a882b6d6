"""EWA projection of 3D Gaussians to screen space, in pure differentiable PyTorch.

Follows gsplat's classic pinhole projection (``fully_fused_projection``, gsplat >= 1.5):
camera-space covariance ``W Sigma W^T``, Jacobian with ``x/z, y/z`` clamped to 1.3x the field of
view (so off-screen Gaussians do not get huge footprints), ``+eps2d`` low-pass, and gsplat's
opacity-aware per-axis radii: the box of the ellipse where ``opacity * exp(-sigma)`` can still
reach 1/255, so every pair that composites lies inside the tiles a Gaussian is binned to. Culled
Gaussians keep finite (meaningless) values so autograd never sees inf/NaN through them.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0
"""Pairs with a smaller alpha are skipped; a Gaussian whose opacity is below it is culled."""
MAX_EXTEND = 3.33
"""gsplat's cap on the box half-extent in standard deviations (never reached for opacity <= 1)."""


@dataclass
class Projected:
    """Screen-space Gaussians for C cameras (all [C, N, ...])."""

    means2d: Tensor  # [C, N, 2] pixels
    conics: Tensor  # [C, N, 3] inverse 2D covariance (a, b, c) of [[a, b], [b, c]]
    depths: Tensor  # [C, N] camera z
    radii: Tensor  # [C, N, 2] int32 box half-extents (x, y) in pixels, 0 = culled
    cov2d_diag: Tensor  # [C, N, 2] detached (var_x, var_y) of the blurred 2D covariance: tight box extents


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices [..., 3, 3] from quaternions [..., 4] in (w, x, y, z) order (normalised here)."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(*quats.shape[:-1], 3, 3)


def covariance_3d(quats: Tensor, scales: Tensor) -> Tensor:
    """World covariances [N, 3, 3] = R S S^T R^T."""
    m = quat_to_rotmat(quats) * scales.unsqueeze(-2)  # [N, 3, 3] = R @ diag(s)
    return m @ m.transpose(-1, -2)


def project_gaussians(
    means: Tensor,  # [N, 3]
    quats: Tensor,  # [N, 4]
    scales: Tensor,  # [N, 3]
    viewmats: Tensor,  # [C, 4, 4]
    Ks: Tensor,  # [C, 3, 3]
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    *,
    opacities: Tensor,  # [N] activated; sizes the boxes and culls those below 1/255
) -> Projected:
    """Project N Gaussians into C pinhole cameras (differentiable w.r.t. every tensor input but
    ``opacities``, which only decides the boxes)."""
    R = viewmats[:, None, :3, :3]  # [C, 1, 3, 3]
    t = viewmats[:, None, :3, 3]  # [C, 1, 3]
    means_c = (R @ means[None, :, :, None]).squeeze(-1) + t  # [C, N, 3]
    covars_c = R @ covariance_3d(quats, scales)[None] @ R.transpose(-1, -2)  # [C, N, 3, 3]

    x, y, z = means_c.unbind(-1)  # [C, N]
    in_depth = (z > near_plane) & (z < far_plane)
    z_safe = torch.where(in_depth, z, torch.ones_like(z))  # keeps culled entries finite
    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]  # [C, 1]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]

    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx
    lim_x_neg = cx / fx + 0.3 * tan_fovx
    lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy
    lim_y_neg = cy / fy + 0.3 * tan_fovy
    tx = z_safe * torch.minimum(torch.maximum(x / z_safe, -lim_x_neg), lim_x_pos)
    ty = z_safe * torch.minimum(torch.maximum(y / z_safe, -lim_y_neg), lim_y_pos)

    zero = torch.zeros_like(z_safe)
    rz = 1.0 / z_safe
    J = torch.stack([fx * rz, zero, -fx * tx * rz * rz, zero, fy * rz, -fy * ty * rz * rz], dim=-1).reshape(
        *z.shape, 2, 3
    )  # [C, N, 2, 3]
    cov2d = J @ covars_c @ J.transpose(-1, -2)  # [C, N, 2, 2]
    # past float32's range (scale * fx / z beyond ~1e19) the 2D covariance overflows: project those
    # with a zero covariance instead, so no inf reaches autograd (they are culled below)
    fits = torch.isfinite(cov2d.detach()).all(dim=-1).all(dim=-1)  # [C, N]
    if not bool(fits.all()):
        covars_c = torch.where(fits[..., None, None], covars_c, torch.zeros_like(covars_c))
        cov2d = J @ covars_c @ J.transpose(-1, -2)
    a = cov2d[..., 0, 0] + eps2d
    b = 0.5 * (cov2d[..., 0, 1] + cov2d[..., 1, 0])
    c = cov2d[..., 1, 1] + eps2d
    det = a * c - b * b
    det_ok = det > 0
    det_safe = torch.where(det_ok, det, torch.ones_like(det))
    conics = torch.stack([c / det_safe, -b / det_safe, a / det_safe], dim=-1)  # [C, N, 3]
    means2d = torch.stack([fx * x * rz + cx, fy * y * rz + cy], dim=-1)  # [C, N, 2]

    with torch.no_grad():
        # opacity-aware box: alpha >= 1/255 needs sigma <= log(255 o); along x that is
        # |dx| <= sqrt(2 log(255 o) var_x) (gsplat computes log(o / (1/255)) the same way)
        op = opacities.detach().to(a.dtype)[None].expand_as(a)  # [C, N]
        reach = torch.log(op / ALPHA_MIN).clamp_min(0.0)
        extend = torch.sqrt(2.0 * reach).clamp_max(MAX_EXTEND)
        radius = torch.ceil(extend[..., None] * torch.sqrt(torch.stack([a, c], dim=-1).clamp_min(0.0)))
        radius = radius.clamp_max(2.0**30)  # [C, N, 2], int32-safe
        rx, ry = radius.unbind(-1)
        mx, my = means2d[..., 0], means2d[..., 1]
        onscreen = (mx + rx > 0) & (mx - rx < width) & (my + ry > 0) & (my - ry < height)
        keep = in_depth & det_ok & fits & (op >= ALPHA_MIN) & (rx > 0) & (ry > 0) & onscreen
        radii = torch.where(keep[..., None], radius, torch.zeros_like(radius)).to(torch.int32)
        diag = torch.stack([a, c], dim=-1).detach()
    return Projected(means2d=means2d, conics=conics, depths=z, radii=radii, cov2d_diag=diag)


def camera_centers(viewmats: Tensor) -> Tensor:
    """World positions [C, 3] of the cameras of world-to-camera matrices [C, 4, 4]."""
    R = viewmats[:, :3, :3]
    t = viewmats[:, :3, 3:]
    return (-R.transpose(-1, -2) @ t).squeeze(-1)
