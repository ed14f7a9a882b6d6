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
to the depth of a pre-pass without gradient; the per-pixel T and S at that depth serve the priors,
the evaluation and the clean render's fade, as in the per-pixel form.
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
from components.medium.compositing import MediumCompositor, MediumRender
from components.rasterizers.base import RasterizeOutput, Rasterizer


@dataclass
class PerGaussianRender:
    """One view composited per Gaussian."""

    out: RasterizeOutput  # the colour pass; its screen-space gradients drive densification
    hazy: Tensor  # [H, W, 3]
    clean: Tensor | None  # [H, W, 3] background included; None unless asked for
    medium: MediumRender  # per-pixel T and S at the pre-pass's blended depth


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
    """camera: [1]; background [3]. The gradient policy rescales the gradient reaching each
    Gaussian's clean colour by its own 1 / clamp(T_i, t_min) (the pixel form: the pixel's T).
    Training needs the hazy view only; ``with_clean`` blends the clean colours in the same pass."""
    means = model.means  # [N, 3]
    with torch.no_grad():  # where the coarse rays end, and each centre's pixel position: one channel
        pre = model.render_colors(rasterizer, camera, means.new_ones(means.shape[0], 1))
    viewmat = camera.viewmats()[0].to(means)  # [4, 4] world -> camera
    z = means @ viewmat[2, :3] + viewmat[2, 3]  # [N] camera z of each centre
    if not compositor.config.depth_gradient:
        z = z.detach()
    med, T_g, S_g, T_far, S_far = compositor.at_points(
        field, camera, pre.depth[0], pre.alpha[0], pre.means2d[0].detach(), z
    )  # [N], [N, 3], [H, W, 1], [H, W, 3]
    centre = camera.camtoworlds[0, :3, 3].to(means)  # [3]
    colors = sh_to_colors(model.active_sh_degree(sh_degree_step), model.sh_coeffs, means - centre)  # [N, 3]
    T = T_g[:, None]  # [N, 1]
    hazy_colors = policy.apply(colors, T, stage) * T + S_g  # [N, 3]
    out = model.render_colors(
        rasterizer, camera, torch.cat([hazy_colors, colors], -1) if with_clean else hazy_colors
    )
    rgb, uncovered = out.rgb[0], 1.0 - out.alpha[0]  # [H, W, 3 or 6], [H, W, 1]
    hazy = rgb[..., :3] + uncovered * (background * T_far + S_far)
    clean = rgb[..., 3:] + uncovered * background if with_clean else None
    return PerGaussianRender(out, hazy, clean, med)
