"""End-of-training evaluation on a split: the quick numbers ``td-train`` prints.

Restoration (the clean render against haze-free references) is reported only where the
dataset has such references; reconstruction compares the composite render with the inputs.
"""

from __future__ import annotations

import torch

from pipelines.base import Pipeline
from pipelines.datamanager import DataManager
from pipelines.metrics import psnr


@torch.no_grad()
def evaluate_split(pipeline: Pipeline, dm: DataManager, split: str = "test") -> dict[str, float | int]:
    indices = dm.scene.indices(split)
    recon, restore = [], []
    for idx in indices:
        out = pipeline.render(dm.camera(idx))
        recon.append(float(psnr(out["hazy"], dm.image(idx))))
        clean = dm.clean_image(idx)
        if clean is not None:
            restore.append(float(psnr(out["clean"], clean)))
    result: dict[str, float | int] = {"split_views": len(indices)}
    if recon:
        result["reconstruction_psnr"] = sum(recon) / len(recon)
    if restore:
        result["restoration_psnr"] = sum(restore) / len(restore)
    return result
