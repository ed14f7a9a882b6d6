"""End-of-training evaluation on a split: the quick numbers ``td-train`` prints.

Restoration (the clean render against haze-free references) is reported only where the
dataset has such references; reconstruction compares the composite render with the inputs.
"""

from __future__ import annotations

import torch

from pipelines.base import Pipeline
from pipelines.datamanager import DataManager
from pipelines.metrics import psnr, ssim


@torch.no_grad()
def evaluate_split(pipeline: Pipeline, dm: DataManager, split: str = "test") -> dict[str, float | int]:
    indices = dm.scene.indices(split)
    recon: list[tuple[float, float]] = []
    restore: list[tuple[float, float]] = []
    for idx in indices:
        out = pipeline.render(dm.camera(idx))
        target = dm.image(idx)
        recon.append((float(psnr(out["hazy"], target)), float(ssim(out["hazy"], target))))
        clean = dm.clean_image(idx)
        if clean is not None:
            restore.append((float(psnr(out["clean"], clean)), float(ssim(out["clean"], clean))))
    result: dict[str, float | int] = {"split_views": len(indices)}
    for name, rows in (("reconstruction", recon), ("restoration", restore)):
        if rows:
            result[f"{name}_psnr"] = sum(r[0] for r in rows) / len(rows)
            result[f"{name}_ssim"] = sum(r[1] for r in rows) / len(rows)
    return result
