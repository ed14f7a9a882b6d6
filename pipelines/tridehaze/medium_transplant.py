"""Start from, and hold, the medium of another run's checkpoint (``--pipeline.medium-from``).

A diagnosis first: the scene is fitted again, from its seed points, through the medium a first run
settled on, so what the medium's own error costs is told apart from what the joint fit did to the
Gaussians while the medium moved (docs/results/medium_recovery.md, session 56)."""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from pipelines.engine.checkpoint import load_checkpoint, load_part_strictly, state_part
from tridehaze_plugin.errors import ConfigError

PREFIX = "medium."
"""The medium's keys in a pipeline's state dict."""
VERDICT_PREFIX = "light_isotropy."
"""The one-light verdict's keys in a pipeline's state dict."""


def load_medium(field: nn.Module, path: Path) -> int:
    """Load the medium's parameters and buffers from the checkpoint at ``path`` into ``field``;
    returns the checkpoint's step. The two must be the same backend and shape (the same method
    and dataset, so the same box)."""
    payload = load_checkpoint(path, map_location="cpu")
    state = state_part(payload, PREFIX)
    own = field.state_dict()
    for k in ("bounds_center", "bounds_half"):
        if k in own and k in state and not torch.equal(state[k], own[k].cpu()):
            raise ConfigError(
                "--pipeline.medium-from: the checkpoint's medium box differs from this run's",
                where=str(path),
                fix="give a checkpoint trained on the same dataset (the box comes from its cameras and points)",
            )
    # the field fills in buffers that older checkpoints lack; copies onto its device
    load_part_strictly(
        field, state, "--pipeline.medium-from: the checkpoint's medium is not this run's medium", path,
        fix="give a checkpoint of the same method and medium backend on the same dataset",
    )  # fmt: skip
    return int(payload["step"])


def load_verdict(verdict: nn.Module, path: Path) -> bool:
    """Load the one-light verdict the checkpoint's run took into ``verdict``, so a run through a
    held medium renders with the fill its source chose, not one re-read from the held medium (its
    spread differs from the one the source read while learning: session 56's street-homogeneous
    flipped). Returns whether the checkpoint carried a decision (older ones or runs stopped before
    the decision step do not; the verdict is then taken as usual)."""
    payload = load_checkpoint(path, map_location="cpu")
    state = state_part(payload, VERDICT_PREFIX)
    if float(state.get("decided", torch.tensor(-1.0))) == -1.0:
        return False
    verdict.load_state_dict(state)
    return True
