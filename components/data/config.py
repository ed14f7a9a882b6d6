"""Where the training data comes from and how it is prepared."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from tridehaze_plugin.config import RegistryChoice


@dataclass
class DataConfig:
    """Dataset location and preparation (exposed at the top level of ``td-train``: ``--data``, ``--downscale``, ...)."""

    data: Path | None = None
    """Dataset folder: nerfstudio ``transforms.json``, Blender-style ``transforms_train.json`` +
    ``transforms_test.json``, or COLMAP (``images/`` + ``sparse/0/``). The format is detected.
    ``td-train`` without it trains on the built-in hazy demo scene (generated once into the cache)."""
    parser: Annotated[str, RegistryChoice("dataparser", allow=("auto",))] = "auto"
    """Data parser to use; ``auto`` picks one from what the folder holds."""
    downscale: int = 1
    """Integer image downscale factor (resized copies are cached, intrinsics scaled to match)."""
    test_every: int = 8
    """When the dataset has no explicit split, every N-th view (0, N, 2N, ...) is held out for testing
    (``0``: no test split; ``1`` is rejected since it would leave nothing to train on)."""
    skip_missing_images: bool = False
    """Skip (with a warning) views whose image file is missing instead of stopping with an error."""
    center_poses: bool = True
    """Translate the world so the cameras' mean centre is the origin."""
    scale_poses: bool = True
    """Scale the world so the farthest camera centre is at distance 1 from the origin."""
    cache_dir: Path | None = None
    """Where undistorted / downscaled copies go (default: ``$TRIDEHAZE_CACHE`` or ``~/.cache/tridehaze``)."""
