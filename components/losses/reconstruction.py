"""Photometric reconstruction loss: (1 - lambda) * L1 + lambda * (1 - SSIM), as in 3DGS."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from torch import Tensor

from components.metrics.ssim import ssim_bchw
from tridehaze_plugin.config import ComponentConfig, Range, RegistryChoice
from tridehaze_plugin.errors import ConfigError
from tridehaze_plugin.registry import REGISTRY, register


@dataclass
class ReconstructionLossConfig(ComponentConfig):
    """Photometric loss between a render and its target image."""

    backend: Annotated[str, RegistryChoice("loss")] = "l1-ssim"
    """Registered photometric loss."""
    lambda_ssim: Annotated[float, Range(0.0, 1.0)] = 0.2
    """Weight of the (1 - SSIM) term; the L1 term gets (1 - lambda_ssim)."""
    ssim_window: Annotated[int, Range(3, 63, odd=True)] = 11
    """Gaussian window size of SSIM (odd; shrunk to fit images with a side of 5 pixels or less)."""

    def check_values(self, prefix: str = "--pipeline.loss.") -> None:
        if not 0.0 <= self.lambda_ssim <= 1.0:
            raise ConfigError(f"{prefix}lambda-ssim must be in [0, 1], got {self.lambda_ssim}")

    def setup(self, **kwargs) -> L1SSIMLoss:
        return REGISTRY.get("loss", self.backend)(self)


class L1SSIMLoss:
    """(1 - lambda) * L1 + lambda * (1 - SSIM); SSIM from kornia (11x11 Gaussian window)."""

    def __init__(self, config: ReconstructionLossConfig) -> None:
        self.config = config

    def __call__(self, pred: Tensor, target: Tensor) -> tuple[Tensor, dict[str, Tensor]]:
        """pred, target: [H, W, 3] or [B, H, W, 3] in [0, 1]."""
        if pred.dim() == 3:
            pred, target = pred[None], target[None]
        l1 = (pred - target).abs().mean()
        lam = self.config.lambda_ssim
        if lam <= 0:
            return l1, {"l1": l1.detach()}
        # kornia wants [B, C, H, W]
        ssim = ssim_bchw(pred.permute(0, 3, 1, 2), target.permute(0, 3, 1, 2), self.config.ssim_window).mean()
        loss = (1 - lam) * l1 + lam * (1 - ssim)
        return loss, {"l1": l1.detach(), "ssim": ssim.detach()}


register("loss", "l1-ssim", L1SSIMLoss)
