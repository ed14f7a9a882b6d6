"""Pseudo-depth from a short haze-agnostic warm-up: fit plain 3DGS to the hazy views, render depth.

Haze changes colours but hardly the geometry 3DGS recovers early on, so a few hundred steps of the
baseline give a dense, multi-view-consistent depth for every training view, with no network. The
warm-up model is thrown away; the real run starts from the same seed cloud.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from components.data.cameras import Cameras
from components.gaussians.model import GaussianModel, GaussianModelConfig
from components.losses.reconstruction import ReconstructionLossConfig
from components.rasterizers.base import Rasterizer
from pipelines.engine.contract import Pipeline, StepResult
from pipelines.engine.datamanager import DataManager
from pipelines.engine.optimizers import OptimizerConfig, Optimizers
from pipelines.engine.trainer import optimization_step


class WarmupPipeline(Pipeline):
    """Plain 3DGS at SH degree 0 with a black background and no densification: the warm-up's
    model, trained by the engine's own optimisation step."""

    def __init__(self, dm: DataManager, model: GaussianModel, rasterizer: Rasterizer) -> None:
        super().__init__()
        self.dm, self.model, self.rasterizer = dm, model, rasterizer
        self.loss_fn = ReconstructionLossConfig().setup()
        self.register_buffer("background", torch.zeros(3, device=dm.device))

    def train_loss(self, step: int) -> StepResult:
        idx = self.dm.train_index(step)
        out = self.model.render(self.rasterizer, self.dm.camera(idx), 0, self.background)
        loss, _ = self.loss_fn(out.rgb[0], self.dm.image(idx))
        return StepResult(loss=loss)

    def param_groups(self) -> dict[str, tuple[nn.Parameter, float]]:
        return self.model.param_groups()

    @torch.no_grad()
    def render(self, camera: Cameras, step: int | None = None) -> dict[str, Tensor]:
        out = self.model.render(self.rasterizer, camera, 0, self.background)
        return {"clean": out.rgb[0], "depth": out.depth[0], "alpha": out.alpha[0]}

    def output_names(self) -> list[str]:
        return ["clean", "depth", "alpha"]


def warmup_depths(
    dm: DataManager,
    model_config: GaussianModelConfig,
    rasterizer: Rasterizer,
    points: Tensor | None,
    colors: Tensor | None,
    scene_extent: float,
    steps: int,
    seed: int = 0,
) -> dict[int, Tensor]:
    """Train a throwaway Gaussian model for ``steps`` steps and return {view: depth [H, W]}."""
    gen_state = torch.get_rng_state()
    torch.manual_seed(seed + 7919)
    model = model_config.setup(points=points, colors=colors, scene_extent=scene_extent).to(dm.device)
    pipe = WarmupPipeline(dm, model, rasterizer)
    # constant learning rates: plain Adam, as 3DGS's first steps
    opts = Optimizers(pipe.param_groups(), OptimizerConfig(means_lr_final_ratio=1.0), max(steps, 1))
    for step in range(steps):
        optimization_step(pipe, opts, step)
    depths = {}
    for i in dm.train_indices:
        out = pipe.render(dm.camera(i))
        d = out["depth"][..., 0]
        depths[i] = torch.where(out["alpha"][..., 0] > 0.5, d, torch.zeros_like(d))  # [H, W]
    torch.set_rng_state(gen_state)
    return depths
