"""Render one view: clean radiance J (traced and shaded), then the medium (T, S) and hazy = J*T + S.

Colour is anti-aliased with ``ss x ss`` sub-pixel rays (textures are fine-grained); depth,
transmittance and scattering come from the pixel-centre ray. So the stored maps satisfy
``hazy = clean * T + S`` exactly per pixel, which is the model the method inverts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from components.data.cameras import ViewIntrinsics
from components.synth.geometry import Hit, SceneGeometry, occluded, trace_grid
from components.synth.layouts import Layout, Sky
from components.synth.march import march
from components.synth.medium import Medium
from components.synth.textures import albedo
from components.synth.trajectories import camera_rays, supersampled


@dataclass
class CleanView:
    """The haze-free render of one view and its per-pixel geometry (pixel-centre rays)."""

    clean: Tensor  # [H, W, 3] float32 in [0, 1]
    origins: Tensor  # [H*W, 3]
    dirs: Tensor  # [H*W, 3] unit
    dz: Tensor  # [H*W] camera-z per unit distance
    t_end: Tensor  # [H*W] distance to the surface, or the far bound for sky
    hit: Tensor  # [H*W] bool, False for sky

    @property
    def depth_z(self) -> Tensor:  # [H, W] z-depth (m)
        H, W = self.clean.shape[:2]
        return (self.t_end * self.dz).reshape(H, W)


@dataclass
class HazyView:
    hazy: Tensor  # [H, W, 3] = clean * T + S
    transmittance: Tensor  # [H, W]
    scattering: Tensor  # [H, W, 3]


def sky_radiance(sky: Sky, sun: tuple[float, float, float], d: Tensor) -> Tensor:  # [R, 3] -> [R, 3]
    """Vertical gradient, a soft glow around the sun and a bright disc."""
    up = d[:, 2].clamp(0, 1)[:, None] ** 0.6
    hz, zn = torch.tensor(sky.horizon), torch.tensor(sky.zenith)
    base = hz + (zn - hz) * up
    cos = (d * torch.tensor(sun)).sum(-1).clamp_min(0)[:, None]
    glow = 0.35 * cos**16 + (cos > 0.9995).float()
    return (base + glow * torch.tensor(sky.sun_color)).clamp(0, 1)


def shade(layout: Layout, o: Tensor, d: Tensor, hit: Hit) -> Tensor:
    """Radiance [R, 3] of rays ``o`` [3] + t ``d`` [R, 3]: Lambert + ambient (+ hard shadows) on hits,
    sky elsewhere (hits beyond the far bound count as sky)."""
    R = d.shape[0]
    surf = hit.mask & (hit.t <= layout.far)
    out = torch.zeros(R, 3)
    if layout.sky is not None:
        out[~surf] = sky_radiance(layout.sky, layout.sun, d[~surf])
    if not bool(surf.any()):
        return out
    idx = surf.nonzero().squeeze(1)
    p = o + hit.t[idx, None] * d[idx]  # [M, 3]
    n = hit.normal[idx]
    mats = hit.material[idx]
    col = torch.zeros(len(idx), 3)
    for m in torch.unique(mats).tolist():
        sel = mats == m
        col[sel] = albedo(layout.geometry.materials[m], p[sel], n[sel])
    lambert = (n * torch.tensor(layout.sun)).sum(-1).clamp_min(0)  # [M]
    if layout.shadows:
        li = (lambert > 0).nonzero().squeeze(1)
        if len(li):
            blocked = occluded(layout.geometry, p[li] + 2e-3 * n[li], layout.sun)
            lambert[li] = torch.where(blocked, torch.zeros_like(lambert[li]), lambert[li])
    ambient = layout.ambient * (0.8 + 0.2 * n[:, 2])
    out[idx] = (col * (ambient + layout.diffuse * lambert)[:, None]).clamp(0, 1)
    return out


def _trace(geo: SceneGeometry, c2w: np.ndarray, K: ViewIntrinsics) -> tuple[Tensor, Tensor, Tensor, Hit]:
    o, d, dz = camera_rays(c2w, K)
    return o, d, dz, trace_grid(geo, o, d, c2w, K.fx, K.fy, K.cx, K.cy)


def render_clean(layout: Layout, c2w: np.ndarray, K: ViewIntrinsics, ss: int = 2) -> CleanView:
    """Trace and shade one view; ``ss x ss`` sub-pixel rays per pixel for the colour."""
    H, W = K.height, K.width
    o, d, dz, hit = _trace(layout.geometry, c2w, K)
    surf = hit.mask & (hit.t <= layout.far)
    t_end = torch.where(surf, hit.t, torch.full_like(hit.t, layout.far)).reshape(-1)
    if ss == 1:
        color = shade(layout, o, d.reshape(-1, 3), hit.flatten())
    else:
        so, sd, _, shit = _trace(layout.geometry, c2w, supersampled(K, ss))
        color = shade(layout, so, sd.reshape(-1, 3), shit.flatten())
        color = color.reshape(H, ss, W, ss, 3).mean(dim=(1, 3))
    dirs = d.reshape(-1, 3)
    return CleanView(color.reshape(H, W, 3), o.expand_as(dirs), dirs, dz.reshape(-1), t_end, surf.reshape(-1))


def apply_medium(view: CleanView, medium: Medium, samples: int) -> HazyView:
    """March the medium along the pixel-centre rays and composite: hazy = clean * T + S."""
    H, W = view.clean.shape[:2]
    res = march(medium, view.origins, view.dirs, view.t_end, samples)
    T = res.transmittance.float().reshape(H, W)
    S = res.scattering.float().reshape(H, W, 3)
    hazy = view.clean * T[..., None] + S
    return HazyView(hazy.clamp(0, 1), T, S)
