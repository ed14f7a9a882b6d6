"""``gaussian-bound``: the medium carried by the Gaussians themselves (the paper's coupled baseline).

Each Gaussian holds a raw extinction and an RGB medium light; they are alpha-blended like colours
into per-pixel values (a second rasterizer pass with the same geometry), and the haze along the
pixel's ray is taken as homogeneous with those values: T = exp(-beta d), S = L (1 - T). Where no
Gaussian covers a pixel a learnable background medium is used. Scene and medium share one set of
primitives, which is exactly the coupling Tri-DehazeGS removes.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from components.data.cameras import Cameras
from components.gaussians.model import GaussianModel
from components.medium.base import FieldBounds, GaussianMediumValues, MediumConfig, MediumField, MediumSample
from components.medium.compositing import MediumCompositor, MediumRender, homogeneous_along_rays
from components.rasterizers.base import Rasterizer
from tridehaze_plugin.registry import register

ATTRIBUTE = "medium"
"""Name of the per-Gaussian attribute ([N, 4]: raw beta, light logits) on the Gaussian model."""


class GaussianBoundMedium(MediumField):
    """Medium carried by the Gaussians (per-Gaussian extinction and light, homogeneous per ray): the coupled baseline."""

    is_field = False
    renders_with_gaussians = True

    def __init__(self, config: MediumConfig, bounds: FieldBounds) -> None:
        super().__init__(config, bounds)
        self.log_kappa = nn.Parameter(torch.zeros(()))
        self.background = nn.Parameter(torch.zeros(4))  # raw beta, light logits where no Gaussian is
        self._init = (config.init_beta, torch.tensor(config.init_light, dtype=torch.float32))
        self.initialize(*self._init)

    @torch.no_grad()
    def initialize(self, beta: float, light: Tensor) -> None:
        self.log_kappa.fill_(math.log(max(beta, 1e-8) / math.log(2.0)))  # softplus(0) = ln 2
        self._init = (beta, light.float().cpu())
        self.background.copy_(self._raw_init())

    def _raw_init(self) -> Tensor:  # [4]
        light = torch.logit(self._init[1].clamp(0.02, 0.98))
        return torch.cat([torch.zeros(1), light])

    def attach(self, model: GaussianModel) -> None:
        """Give every Gaussian its medium attribute (cloned / pruned with it from then on)."""
        values = self._raw_init().to(model.means).expand(model.num_gaussians, 4).clone()
        model.add_attribute(ATTRIBUTE, values, self.config.lr)

    def set_trainable(self, on: bool, model: GaussianModel) -> None:
        super().set_trainable(on, model)
        model.attribute(ATTRIBUTE).requires_grad_(on)

    @torch.no_grad()
    def gaussian_values(self, model: GaussianModel) -> GaussianMediumValues:
        raw = model.attribute(ATTRIBUTE).detach().float().cpu()  # [N, 4]
        kappa = float(self.log_kappa.detach().exp())
        bg = self.background.detach().float().cpu()
        return GaussianMediumValues(
            beta=kappa * F.softplus(raw[:, 0]),
            light=torch.sigmoid(raw[:, 1:]),
            background_beta=kappa * float(F.softplus(bg[0])),
            background_light=torch.sigmoid(bg[1:]),
        )

    def render_view(
        self,
        compositor: MediumCompositor,
        camera: Cameras,
        depth: Tensor,
        alpha: Tensor,
        model: GaussianModel,
        rasterizer: Rasterizer,
    ) -> MediumRender:
        """The Gaussians' alpha-blended medium values per pixel, homogeneous along each pixel's ray."""
        blended = model.render_attribute(rasterizer, camera, ATTRIBUTE)[0]  # [H, W, 4]
        beta, light = self.pixel_medium(blended, alpha)
        far = compositor.far_bound(self)
        if compositor.config.background == "infinite":
            end = compositor.surface_depth(depth, far)
        else:
            end = compositor.end_depth(depth, alpha, far)
        surface = homogeneous_along_rays(beta, light, camera, end, compositor.config.t_floor)
        return compositor.with_sky(surface, alpha, light)  # homogeneous to infinity: the sky is L

    def param_groups(self) -> dict[str, tuple[nn.Parameter, float]]:
        return {
            "medium.kappa": (self.log_kappa, self.config.kappa_lr),
            "medium.background": (self.background, self.config.lr),
        }

    def pixel_medium(self, blended: Tensor, alpha: Tensor) -> tuple[Tensor, Tensor]:
        """blended [H, W, 4] alpha-weighted raw values, alpha [H, W, 1] -> beta [H, W], light [H, W, 3]."""
        # over-compositing: the Gaussians' alpha-weighted values, the background medium behind them
        raw = blended + (1 - alpha) * self.background  # [H, W, 4]
        beta = self.log_kappa.exp() * F.softplus(raw[..., 0])
        return beta, torch.sigmoid(raw[..., 1:])

    def forward(self, x: Tensor, dirs: Tensor) -> MediumSample:
        """Only the background medium is defined away from the Gaussians."""
        raw = self.background.expand(x.shape[0], 4)
        return MediumSample(self.log_kappa.exp() * F.softplus(raw[:, 0]), torch.sigmoid(raw[:, 1:]))


register("medium", "gaussian-bound", GaussianBoundMedium)
