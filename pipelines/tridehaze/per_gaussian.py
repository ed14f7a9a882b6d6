"""The haze applied per Gaussian at its own depth (``--pipeline.composite.per-gaussian``).

Per pixel, the medium is marched to the pixel's blended depth D = sum_i w_i z_i and I = J T(D) +
S(D). Where the Gaussians of a pixel spread in depth (a floater or a half-transparent layer in
front of a surface) D is short, so the surface behind gets too little haze and the floater's own
colour has to supply it: the scene absorbs haze and the medium is fitted to the wrong depth
(docs/results/medium_recovery.md, sessions 16 and 23). Here each Gaussian's view colour c_i is
attenuated by the medium up to its own centre, and I = sum_i w_i (c_i T_i + S_i) is alpha-blended
like any colour; the uncovered share sees the background through the whole path. For one opaque
Gaussian per pixel both forms agree.

The medium is read from the compositor's coarse rays at each Gaussian's projected centre and
camera z, so its cost does not grow with the Gaussians beyond one read each. The rays are marched
to the depth of a one-channel pre-pass without gradient, rendered at up to half the coarse rays'
spacing (``MediumCompositor.depth_factor``); the per-pixel T and S at the colour pass's blended
depth, read from the same rays, serve the priors, the evaluation and the clean render's fade, as
in the per-pixel form.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from components.data.cameras import Cameras
from components.gaussians.model import GaussianModel
from components.gaussians.sh import sh_to_colors
from components.gradients.policies import GradientPolicy
from components.medium.base import MediumField
from components.medium.compositing import CoarseMarch, MediumCompositor, MediumRender
from components.rasterizers.base import RasterizeOutput, Rasterizer


@dataclass
class PerGaussianRender:
    """One view composited per Gaussian."""

    out: RasterizeOutput  # the colour pass; its screen-space gradients drive densification
    hazy: Tensor  # [H, W, 3]
    clean: Tensor | None  # [H, W, 3] background included; None unless asked for
    medium: MediumRender  # per-pixel T and S at the colour pass's blended depth
    march: CoarseMarch  # the coarse rays everything was read from


def render_per_gaussian(
    model: GaussianModel,
    rasterizer: Rasterizer,
    compositor: MediumCompositor,
    field: MediumField,
    camera: Cameras,
    sh_degree_step: int,
    background: Tensor,
    policy: GradientPolicy,
    stage: int,
    with_clean: bool = False,
) -> PerGaussianRender:
    """camera: [1]; background [3]; ``field`` has a medium. The gradient policy rescales the gradient reaching each
    Gaussian's clean colour by its own 1 / clamp(T_i, t_min) (the pixel form: the pixel's T).
    Training needs the hazy view only; ``with_clean`` blends the clean colours in the same pass."""
    means = model.means  # [N, 3]
    H, W = int(camera.height[0]), int(camera.width[0])
    f = compositor.depth_factor(H, W)
    coarse = camera.rescaled(
        1.0 / f, 1.0 / f, camera.width.new_tensor([-(-W // f)]), camera.height.new_tensor([-(-H // f)])
    )
    with torch.no_grad():  # where the coarse rays end: one channel, at the coarse rays' resolution
        pre = model.render_colors(rasterizer, coarse, means.new_ones(means.shape[0], 1))
    march = compositor.march_view(field, camera, pre.depth[0], pre.alpha[0], (H, W))
    viewmat = camera.viewmats()[0].to(means)  # [4, 4] world -> camera
    cam_pts = means @ viewmat[:3, :3].T + viewmat[:3, 3]  # [N, 3]
    z = cam_pts[:, 2] if compositor.config.depth_gradient else cam_pts[:, 2].detach()  # [N] camera z
    K = camera.Ks()[0].to(means)  # [3, 3]
    uv = (cam_pts.detach()[:, :2] / cam_pts.detach()[:, 2:].clamp_min(1e-6)) * K.diagonal()[:2] + K[
        :2, 2
    ]  # [N, 2]
    centre = camera.camtoworlds[0, :3, 3].to(means)  # [3]
    colors = sh_to_colors(model.active_sh_degree(sh_degree_step), model.sh_coeffs, means - centre)  # [N, 3]
    T_g, S_g = compositor.read_points(march, camera, uv, z, (H, W))  # [N], [N, 3]
    T = T_g[:, None]  # [N, 1]
    hazy_colors = policy.apply(colors, T, stage) * T + S_g  # [N, 3]
    out = model.render_colors(
        rasterizer, camera, torch.cat([hazy_colors, colors], -1) if with_clean else hazy_colors
    )
    med, T_far, S_far = compositor.read_view(march, field, camera, out.depth[0], out.alpha[0])
    rgb, uncovered = out.rgb[0], 1.0 - out.alpha[0]  # [H, W, 3 or 6], [H, W, 1]
    hazy = rgb[..., :3] + uncovered * (background * T_far + S_far)
    clean = rgb[..., 3:] + uncovered * background if with_clean else None
    return PerGaussianRender(out, hazy, clean, med, march)
