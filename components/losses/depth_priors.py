"""Pseudo-depth sources for the Pearson depth loss, computable without a depth network.

Every source returns ``(prior [H, W] float32, valid [H, W] bool)`` in camera z-depth-like units.
Only the per-view ordering matters (the loss is a Pearson correlation, invariant to scale and
shift), so priors need not be metric; invalid pixels hold 0 and must be masked out.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

from components.data.images import check_map_fits, read_depth
from components.losses.dcp import DCPResult, estimate_dcp, min_filter

DCP_T_MAX = 0.99
"""Above this the DCP transmittance carries no depth: the pixel is dark or haze-free (t ~ 1 is
clamped there by the prior), so -ln t ~ 0 regardless of distance."""
DCP_T_MIN_FACTOR = 2.0
"""Pixels with t <= factor * t0 are excluded: the sky, bright white objects and any other
airlight-coloured pixel sit at the t0 clamp (the prior fails there and the true t is unknown), and
the guided filter smears that clamp up to ~2 t0. On synthetic street scenes this drops 2/3 of the
sky while keeping >= 94% of the other pixels even in dense haze."""


def depth_from_file(path: Path, height: int, width: int, disparity: bool = False) -> tuple[Tensor, Tensor]:
    """A user depth map (``.npy`` / ``.png``, see ``read_depth``) resized to [height, width].

    ``disparity``: the file stores inverse depth (most monocular networks' output), so it is
    inverted; a correlation with disparity instead of depth would have the wrong sign.
    Downscaling averages the valid pixels only (no blending with holes); upscaling is nearest.
    """
    arr = read_depth(Path(path))  # [h, w] float32
    check_map_fits(arr.shape, width, height, Path(path))
    valid = np.isfinite(arr) & (arr > 0)
    arr = np.where(valid, arr, 0.0).astype(np.float32)
    if disparity:
        arr = np.where(valid, 1.0 / np.maximum(arr, 1e-12), 0.0).astype(np.float32)
    if arr.shape != (height, width):
        if height * width < arr.size:
            num = cv2.resize(arr * valid, (width, height), interpolation=cv2.INTER_AREA)
            den = cv2.resize(valid.astype(np.float32), (width, height), interpolation=cv2.INTER_AREA)
            valid = den > 0.5
            arr = np.where(valid, num / np.maximum(den, 1e-6), 0.0).astype(np.float32)
        else:
            arr = cv2.resize(arr, (width, height), interpolation=cv2.INTER_NEAREST_EXACT)
            valid = cv2.resize(valid.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST_EXACT)
            valid = valid.astype(bool)
    return torch.from_numpy(np.ascontiguousarray(arr)), torch.from_numpy(np.ascontiguousarray(valid))


def depth_from_dcp(
    image: np.ndarray,
    result: DCPResult | None = None,
    t0: float = 0.05,
    t_min: float | None = None,
    t_max: float = DCP_T_MAX,
    **dcp_kwargs,
) -> tuple[Tensor, Tensor]:
    """-ln(t_dcp) of a hazy image [H, W, 3]: optical depth, proportional to depth in uniform haze.

    Pass ``result`` to reuse an ``estimate_dcp`` already computed for the transmittance loss.
    Valid where t_min < t < t_max (``t_min`` default ``DCP_T_MIN_FACTOR * t0``; see ``DCP_T_MAX``).
    In non-uniform haze -ln t is the optical depth, only monotone in depth along similar paths.
    """
    if result is None:
        result = estimate_dcp(image, t0=t0, **dcp_kwargs)
    t_min = DCP_T_MIN_FACTOR * t0 if t_min is None else t_min
    t = result.transmittance.astype(np.float32)  # [H, W]
    valid = (t > t_min) & (t < t_max)
    prior = np.where(valid, -np.log(np.clip(t, 1e-6, 1.0)), 0.0).astype(np.float32)
    return torch.from_numpy(prior), torch.from_numpy(valid)


def project_points(points: Tensor, viewmat: Tensor, K: Tensor) -> tuple[Tensor, Tensor]:  # noqa: N803
    """World points [M, 3] -> camera coordinates [M, 3] and pixel coordinates [M, 2] (OpenCV axes;
    z <= 0 gives meaningless pixels, callers mask by z)."""
    vm, k = viewmat.to(points), K.to(points)
    pc = points @ vm[:3, :3].T + vm[:3, 3]  # [M, 3]
    z = pc[:, 2:3].clamp_min(torch.finfo(points.dtype).tiny)
    uv = pc[:, :2] / z * torch.stack([k[0, 0], k[1, 1]]) + torch.stack([k[0, 2], k[1, 2]])  # [M, 2]
    return pc, uv


def in_image(pc: Tensor, uv: Tensor, width: int, height: int, near: float) -> Tensor:
    """[M] bool: points in front of the camera (camera z > ``near``) that project inside the image
    (``pc``, ``uv`` from :func:`project_points`)."""
    return (pc[:, 2] > near) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < width) & (uv[:, 1] < height)


def depth_from_sfm(
    points: Tensor,
    viewmat: Tensor,
    K: Tensor,  # noqa: N803
    height: int,
    width: int,
    splat_radius: int = 1,
    near: float = 1e-6,
    occlusion_window: int = 5,
    occlusion_tol: float = 0.1,
) -> tuple[Tensor, Tensor]:
    """Sparse z-depth of world points [M, 3] in one camera (viewmat [4, 4] world-to-camera, OpenCV).

    Each point covers the (2r+1)^2 pixels around its projection (``splat_radius`` r) and a z-buffer
    keeps the nearest. A pixel centre is at +0.5, so a point projecting to u lands in pixel floor(u).
    ``occlusion_window`` > 1 drops pixels farther than (1 + tol) x the nearest depth within that
    window: sparse clouds let points on hidden surfaces show through gaps in the foreground (on
    synthetic scenes window 5 halved the pixels off by > 20%, at the cost of ~25% of the coverage;
    0 turns it off).
    """
    dtype = points.dtype if points.is_floating_point() else torch.float32
    pts = points.to(dtype)
    pc, uv = project_points(pts, viewmat, K)  # [M, 3], [M, 2]
    front = pc[:, 2] > near
    z = pc[front, 2]  # [M']
    iu = torch.floor(uv[front, 0]).long()
    iv = torch.floor(uv[front, 1]).long()
    r = max(int(splat_radius), 0)
    off = torch.arange(-r, r + 1, device=pts.device)
    du, dv = torch.meshgrid(off, off, indexing="xy")  # [S, S]
    iu = (iu[:, None] + du.reshape(1, -1)).reshape(-1)  # [M' * S^2]
    iv = (iv[:, None] + dv.reshape(1, -1)).reshape(-1)
    zz = z[:, None].expand(-1, du.numel()).reshape(-1)
    inside = (iu >= 0) & (iu < width) & (iv >= 0) & (iv < height)
    lin = iv[inside] * width + iu[inside]
    zbuf = torch.full((height * width,), float("inf"), dtype=dtype, device=pts.device)
    zbuf = zbuf.scatter_reduce(0, lin, zz[inside], reduce="amin", include_self=True)
    zbuf = zbuf.view(height, width)  # [H, W]
    valid = torch.isfinite(zbuf)
    if occlusion_window > 1 and valid.any():
        big = torch.where(valid, zbuf, torch.full_like(zbuf, torch.finfo(dtype).max))
        w = int(occlusion_window) | 1
        local_min = min_filter(big, w)  # [H, W]
        valid = valid & (zbuf <= local_min * (1.0 + occlusion_tol))
    prior = torch.where(valid, zbuf, torch.zeros_like(zbuf)).float()
    return prior, valid
