"""Real spherical harmonics up to degree 3, in the convention of 3DGS and gsplat.

One copy only: the rasterizers import :func:`eval_sh` from here. Coefficients are laid out
``[..., K, 3]`` with ``K = (degree + 1) ** 2`` in the usual order (band 0, then band 1 as
``y, z, x``, ...). The sign convention (``-C1 * y``, ...) is the one used by 3DGS, so colours
stored by 3DGS / gsplat checkpoints render identically.
"""

from __future__ import annotations

import torch
from torch import Tensor

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
MAX_SH_DEGREE = 3


def num_sh_bases(degree: int) -> int:
    """Number of coefficients per channel for a given degree: ``(degree + 1) ** 2``."""
    if not 0 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"SH degree must be in [0, {MAX_SH_DEGREE}], got {degree}")
    return (degree + 1) ** 2


def sh_degree_from_bases(k: int) -> int:
    """Inverse of :func:`num_sh_bases` (``K`` must be a perfect square)."""
    for d in range(MAX_SH_DEGREE + 1):
        if (d + 1) ** 2 == k:
            return d
    raise ValueError(f"{k} is not a valid number of SH coefficients (1, 4, 9 or 16)")


def eval_sh_bases(degree: int, dirs: Tensor) -> Tensor:
    """SH basis values ``[..., (degree+1)**2]`` at directions ``dirs [..., 3]`` (normalised here)."""
    num_sh_bases(degree)
    if degree == 0:
        return torch.full((*dirs.shape[:-1], 1), C0, dtype=dirs.dtype, device=dirs.device)
    # guarded normalisation: a zero direction gives zero higher bands instead of NaN
    d = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    x, y, z = d.unbind(-1)
    out = [torch.full_like(x, C0), -C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        xy, yz, xz = x * y, y * z, x * z
        out += [
            C2[0] * xy,
            C2[1] * yz,
            C2[2] * (2.0 * zz - xx - yy),
            C2[3] * xz,
            C2[4] * (xx - yy),
        ]
        if degree >= 3:
            out += [
                C3[0] * y * (3.0 * xx - yy),
                C3[1] * xy * z,
                C3[2] * y * (4.0 * zz - xx - yy),
                C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
                C3[4] * x * (4.0 * zz - xx - yy),
                C3[5] * z * (xx - yy),
                C3[6] * x * (xx - 3.0 * yy),
            ]
    return torch.stack(out, dim=-1)


def eval_sh(degree: int, coeffs: Tensor, dirs: Tensor) -> Tensor:
    """Evaluate SH ``coeffs [..., K, C]`` along ``dirs [..., 3]`` -> ``[..., C]`` (no +0.5 offset).

    Only the first ``(degree+1)**2`` coefficients are used, so a model can hold degree-3
    coefficients while its active degree grows during training. Leading dims broadcast.
    """
    k = num_sh_bases(degree)
    if coeffs.shape[-2] < k:
        raise ValueError(f"degree {degree} needs {k} SH coefficients, got {coeffs.shape[-2]}")
    bases = eval_sh_bases(degree, dirs)  # [..., k]
    return (bases.unsqueeze(-1) * coeffs[..., :k, :]).sum(dim=-2)


def sh_to_colors(degree: int, coeffs: Tensor, dirs: Tensor) -> Tensor:
    """Renderable colour from SH, as gsplat does it: ``clamp_min(eval_sh + 0.5, 0)``."""
    return torch.clamp_min(eval_sh(degree, coeffs, dirs) + 0.5, 0.0)


def rgb_to_sh(rgb: Tensor) -> Tensor:
    """DC coefficient that renders as ``rgb`` (in [0, 1]) from every direction."""
    return (rgb - 0.5) / C0


def sh_to_rgb(sh0: Tensor) -> Tensor:
    """Inverse of :func:`rgb_to_sh` (colour of the DC band alone, unclamped)."""
    return sh0 * C0 + 0.5
