"""Depth rendered from a trained run, for ``td-synth haze --depth-from-run`` (which lives in the
components layer and receives this renderer from the tools that call it)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from components.data.cameras import Cameras
from components.data.scene import SceneData
from components.synth.haze_existing import fill_invalid_depth
from pipelines.engine.run_loader import load_run
from tridehaze_plugin.errors import UserError


def run_depths(scene: SceneData, config_path: Path, min_alpha: float) -> list[np.ndarray]:
    """Depth [H, W] (dataset units, z-depth) rendered from a trained run for every view of ``scene``."""
    config_path = Path(config_path)
    if not config_path.is_file():
        raise UserError("run config not found", where=str(config_path), fix="pass a run's config.yml")
    run = load_run(config_path)
    run_root = run.datamanager.scene.root.resolve()
    if run_root != scene.root.resolve():
        raise UserError(
            f"the run was trained on {run_root}, not on this dataset",
            where=str(config_path),
            fix="pass a run trained on --data",
        )
    tr = run.datamanager.scene.transform
    c2w_n = tr.apply_c2w(scene.cameras.camtoworlds.double()).float()  # into the run's normalised world
    out = []
    for i in range(len(scene)):
        cam = Cameras(
            c2w_n[i : i + 1],
            *(getattr(scene.cameras, k)[i : i + 1] for k in ("fx", "fy", "cx", "cy", "width", "height")),
        )
        with torch.no_grad():
            res = run.pipeline.render(cam)
        depth = res["depth"][..., 0].double().numpy() / tr.scale  # normalised -> dataset units
        alpha = res["alpha"][..., 0].numpy() if "alpha" in res else np.ones_like(depth)
        valid = (alpha >= min_alpha) & np.isfinite(depth) & (depth > 0)
        out.append(
            fill_invalid_depth(depth, valid, f"{config_path} view {scene.names()[i]}").astype(np.float32)
        )
    return out
