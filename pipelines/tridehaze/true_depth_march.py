"""The training medium under two diagnoses that read td-synth's true depth (never methods):
``--pipeline.march-to true-depth`` ends each training ray's march at the true surface, and
``--pipeline.medium-learns-from true-depth`` lets the medium learn only from pixels whose rendered
end depth is right (docs/results/medium_recovery.md, sessions 55-56)."""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor

from components.data.cameras import Cameras
from components.gaussians.model import GaussianModel
from components.medium.base import MediumField
from components.medium.compositing import MediumCompositor, MediumRender
from components.rasterizers.base import Rasterizer


def march_to_depth(
    medium: MediumField,
    compositor: MediumCompositor,
    camera: Cameras,
    z: Tensor,
    model: GaussianModel,
    rasterizer: Rasterizer,
) -> MediumRender:
    """T and S of ``camera``'s rays marched to the z-depth ``z`` [H, W, 1] (full coverage), with
    the medium's gradient (``medium_at_depth`` renders the same without it)."""
    return medium.render_view(compositor, camera, z, torch.ones_like(z), model, rasterizer)


def trusted_medium(med: MediumRender, z: Tensor, tolerance: float) -> tuple[MediumRender, Tensor]:
    """``med`` with its T and S detached wherever the rendered end depth is off the true z-depth
    ``z`` [H, W, 1] by more than ``tolerance`` of it (the forward pass unchanged), and the share of
    pixels trusted."""
    ok = ((med.end_depth.detach() - z).abs() <= tolerance * z).to(z)  # [H, W, 1]
    T, S = med.transmittance, med.scattering
    trusted = replace(
        med, transmittance=ok * T + (1 - ok) * T.detach(), scattering=ok * S + (1 - ok) * S.detach()
    )
    return trusted, ok.mean()
