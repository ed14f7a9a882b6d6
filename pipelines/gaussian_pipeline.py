"""The Gaussian-splatting pipeline assembled from registered components.

It composes a Gaussian model, a rasterizer and a photometric loss, all chosen by config. The
medium, gradient policy and extra loss terms of Tri-DehazeGS plug in here as further
components; with none of them it is plain 3DGS, whose clean and hazy renders coincide.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from components.data.cameras import Cameras
from components.gaussians.densify import Densifier, DensifyConfig
from components.gaussians.model import GaussianModelConfig
from components.losses.reconstruction import ReconstructionLossConfig
from components.rasterizers.base import RasterizerConfig
from pipelines.base import Pipeline, StepResult
from pipelines.datamanager import DataManager
from pipelines.metrics import psnr
from tridehaze_plugin.errors import ConfigError


@dataclass
class PipelineConfig:
    """Which components make up the method, and how they are combined."""

    model: GaussianModelConfig = field(default_factory=GaussianModelConfig)
    """The clean scene: 3D Gaussians."""
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    """Adaptive density control (clone / split / prune / opacity reset)."""
    rasterizer: RasterizerConfig = field(default_factory=RasterizerConfig)
    """Differentiable rasterizer backend."""
    loss: ReconstructionLossConfig = field(default_factory=ReconstructionLossConfig)
    """Photometric loss against the input views."""
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Background colour behind the Gaussians (RGB in [0, 1])."""
    random_background: bool = False
    """Use a random background colour each step (discourages Gaussians from encoding the background)."""

    def check_values(self) -> None:
        if not all(0.0 <= c <= 1.0 for c in self.background):
            raise ConfigError(f"--pipeline.background must be three values in [0, 1], got {self.background}")
        if not 0.0 <= self.loss.lambda_ssim <= 1.0:
            raise ConfigError(f"--pipeline.loss.lambda-ssim must be in [0, 1], got {self.loss.lambda_ssim}")

    def setup(self, datamanager: DataManager, seed: int = 0, max_steps: int = 30_000) -> GaussianPipeline:
        return GaussianPipeline(self, datamanager, seed, max_steps)


class GaussianPipeline(Pipeline):
    """3D Gaussians + rasterizer + photometric loss on one view per step."""

    def __init__(
        self, config: PipelineConfig, datamanager: DataManager, seed: int = 0, max_steps: int = 30_000
    ) -> None:
        super().__init__()
        self.config = config
        self.datamanager = datamanager
        scene = datamanager.scene
        device = datamanager.device
        torch.manual_seed(seed)
        extent = float(scene.cameras.centers.norm(dim=-1).max()) * 1.1 if len(scene) > 1 else 1.0
        self.scene_extent = max(extent, 1e-6)
        self.model = config.model.setup(
            points=scene.points, colors=scene.point_colors, scene_extent=self.scene_extent
        ).to(device)
        self.densifier = Densifier(config.densify, self.scene_extent, max_steps)
        self.rasterizer = config.rasterizer.setup()
        self.loss_fn = config.loss.setup()
        self.register_buffer(
            "background", torch.tensor(config.background, dtype=torch.float32, device=device)
        )
        self._gen = torch.Generator(device="cpu").manual_seed(seed)

    # ----------------------------------------------------------------------------- training
    def train_loss(self, step: int) -> StepResult:
        dm = self.datamanager
        idx = dm.train_index(step)
        target = dm.image(idx)  # [H, W, 3]
        bg = self.background
        if self.config.random_background:
            bg = torch.rand(3, generator=self._gen).to(bg)
        out = self._rasterize(dm.camera(idx), step, bg)
        rgb = out.rgb[0]  # [H, W, 3]
        loss, terms = self.loss_fn(rgb, target)
        self._last = out
        metrics = {k: float(v) for k, v in terms.items()}
        metrics["psnr"] = float(psnr(rgb.detach(), target))
        return StepResult(loss=loss, metrics=metrics)

    def param_groups(self) -> dict[str, tuple[nn.Parameter, float]]:
        return self.model.param_groups()

    def after_backward(self, step: int) -> None:
        self.densifier.collect(self._last)

    def after_optimizer_step(self, step: int, optimizers: dict[str, torch.optim.Optimizer]) -> None:
        self.last_refine = self.densifier.step(step, self.model, optimizers)

    # ---------------------------------------------------------------------------- rendering
    def _rasterize(self, camera: Cameras, step: int | None, background: Tensor):
        # no step (rendering for eval/view): all SH bands
        return self.model.render(self.rasterizer, camera, 10**9 if step is None else step, background)

    @torch.no_grad()
    def render(self, camera: Cameras, step: int | None = None) -> dict[str, Tensor]:
        out = self._rasterize(camera, step, self.background)
        clean = out.rgb[0].clamp(0, 1)  # [H, W, 3]
        # no medium: the composite equals the clean render
        return {"clean": clean, "hazy": clean, "depth": out.depth[0], "alpha": out.alpha[0]}

    def output_names(self) -> list[str]:
        return ["clean", "hazy", "depth", "alpha"]

    def stats(self) -> dict[str, float | int]:
        return {"gaussians": self.model.num_gaussians}
