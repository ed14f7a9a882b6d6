"""Start from, and hold, the Gaussians of another run's checkpoint (``--pipeline.scene-from``).

A diagnosis: with the scene of a haze-free capture held (``vanilla-gs`` trained on a generated
scene's clean photos, same cameras and seed cloud), only the medium learns from the hazy photos,
so what is left of its error is its own and its priors', not what the joint fit let the Gaussians
absorb (docs/results/medium_recovery.md, session 70)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from torch import nn

from pipelines.engine.checkpoint import load_checkpoint, load_part_strictly, state_part
from tridehaze_plugin.errors import ConfigError

PREFIX = "model."
"""The Gaussians' keys in a pipeline's state dict."""


def load_gaussians(model: nn.Module, path: Path, frame: dict[str, Any]) -> tuple[int, int]:
    """Load the Gaussians of the checkpoint at ``path`` into ``model`` (resized to the stored
    count); returns the checkpoint's step and the number of Gaussians. The checkpoint must hold
    Gaussians of this model's shape (the SH degree) from a run whose normalised frame is ``frame``
    (this run's ``SceneTransform.to_dict()``), checked against the run folder's
    ``dataparser_transforms.json`` where it has one."""
    _check_frame(Path(path), frame)
    payload = load_checkpoint(path, map_location="cpu")
    state = state_part(payload, PREFIX)
    if not state:
        raise ConfigError(
            "--pipeline.scene-from: the checkpoint holds no Gaussians",
            where=str(path),
            fix="give a checkpoint of a Gaussian-splatting run (vanilla-gs, tri-dehaze, ...)",
        )
    # the model resizes itself to the stored count and copies onto its device
    load_part_strictly(
        model, state, "--pipeline.scene-from: the checkpoint's Gaussians do not fit this model", path,
        fix="give a checkpoint whose run used the same --pipeline.model settings (SH degree)",
    )  # fmt: skip
    count = int(next(iter(state.values())).shape[0])
    return int(payload["step"]), count


def _check_frame(path: Path, frame: dict[str, Any]) -> None:
    """Refuse a checkpoint whose run normalised the world differently (other cameras or points)."""
    saved = path.parent.parent / "dataparser_transforms.json"
    if not saved.is_file():
        return
    theirs = json.loads(saved.read_text())
    ours = json.loads(json.dumps(frame))  # the same float rounding as the saved file
    if theirs != ours:
        raise ConfigError(
            "--pipeline.scene-from: the checkpoint's run normalised the world differently",
            where=str(saved),
            fix="give a checkpoint trained on this dataset's cameras and seed points",
        )
