"""Pseudo-depth from a short haze-agnostic warm-up: fit plain 3DGS to the hazy views, render depth.

Haze changes colours but hardly the geometry 3DGS recovers early on, so a few hundred steps of the
baseline give a dense, multi-view-consistent depth for every training view, with no network. The
warm-up model is thrown away; the real run starts from the same seed cloud.
"""

from __future__ import annotations

import torch
from torch import Tensor

from components.gaussians.model import GaussianModelConfig
from components.losses.reconstruction import ReconstructionLossConfig
from components.rasterizers.base import Rasterizer
from pipelines.engine.datamanager import DataManager


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
    opts = [torch.optim.Adam([p], lr=lr, eps=1e-15) for p, lr in model.param_groups().values()]
    loss_fn = ReconstructionLossConfig().setup()
    bg = torch.zeros(3, device=dm.device)
    for step in range(steps):
        idx = dm.train_index(step)
        out = model.render(rasterizer, dm.camera(idx), 0, bg)
        loss, _ = loss_fn(out.rgb[0], dm.image(idx))
        for o in opts:
            o.zero_grad(set_to_none=True)
        loss.backward()
        for o in opts:
            o.step()
    depths = {}
    with torch.no_grad():
        for i in dm.train_indices:
            out = model.render(rasterizer, dm.camera(i), 0, bg)
            d = out.depth[0, ..., 0]
            depths[i] = torch.where(out.alpha[0, ..., 0] > 0.5, d, torch.zeros_like(d))  # [H, W]
    torch.set_rng_state(gen_state)
    return depths
