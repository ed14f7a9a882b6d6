"""Reload a finished (or interrupted) run for rendering, evaluation or export.

Used by every tool that takes ``--load-config RUN/config.yml``: the config is read safely,
the dataset re-loaded with the run's own data options, and the newest checkpoint restored.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from components.data.loader import load_scene
from pipelines.engine.checkpoint import latest_checkpoint, load_checkpoint, load_pipeline_state
from pipelines.engine.config import TrainerConfig
from pipelines.engine.contract import Pipeline
from pipelines.engine.datamanager import DataManager
from pipelines.engine.run_config import load_config
from tridehaze_plugin.errors import UserError


@dataclass
class LoadedRun:
    config: TrainerConfig
    run_dir: Path
    datamanager: DataManager
    pipeline: Pipeline
    step: int
    """Training step of the restored checkpoint."""


def load_run(
    config_path: Path, device: str | torch.device = "cpu", checkpoint: Path | None = None
) -> LoadedRun:
    """Rebuild the pipeline of the run whose ``config.yml`` is given, with its newest checkpoint."""
    config_path = Path(config_path)
    cfg = load_config(config_path)
    run_dir = config_path.parent
    ckpt = checkpoint or latest_checkpoint(run_dir)
    if ckpt is None:
        raise UserError(
            "run has no checkpoint yet",
            where=str(run_dir / "checkpoints"),
            fix="let training reach its first save (--steps-per-save) or pass another run",
        )
    payload = load_checkpoint(ckpt, map_location=device)
    scene = load_scene(cfg.dataset)
    dm = DataManager(scene, torch.device(device), seed=cfg.seed)
    pipeline = cfg.pipeline.setup(dm, seed=cfg.seed, max_steps=cfg.max_steps, training=False)
    load_pipeline_state(pipeline, payload, ckpt)
    pipeline.eval()
    return LoadedRun(cfg, run_dir, dm, pipeline, int(payload["step"]))
