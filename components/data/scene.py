"""What data parsers produce: raw frames (``ParsedScene``) and the trainer-ready ``SceneData``.

A parser only reads its format into :class:`ParsedScene` (OpenCV camera axes, original
intrinsics and distortion). The shared loader (``components.data.loader``) then validates,
undistorts, downscales, normalises poses and splits, so every format ends up identical.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from components.data.cameras import Cameras, ViewIntrinsics
from tridehaze_plugin.errors import InputWarning


class DataWarning(InputWarning):
    """Something in the dataset was skipped or adjusted; loading went on."""


@dataclass
class Frame:
    """One view as read from disk, before any processing."""

    name: str
    """Image file name relative to the dataset root (used for splits and messages)."""
    image_path: Path
    c2w: np.ndarray  # [4, 4] float64, OpenCV axes
    intrinsics: ViewIntrinsics
    """As in the file: before undistortion and downscaling."""
    camera_model: str = "PINHOLE"
    """COLMAP model name; anything but PINHOLE is undistorted by the loader."""
    distortion: tuple[float, ...] = ()
    """OpenCV-order coefficients (k1, k2, p1, p2[, k3, ...]); empty for pinhole."""
    clean_path: Path | None = None
    """Paired haze-free image (evaluation only)."""
    depth_path: Path | None = None
    """User-supplied depth estimate (a prior the trainer may use)."""
    extras: dict[str, Path] = field(default_factory=dict)
    """Other per-frame files by key, e.g. ``gt_depth_file_path``; never used as training priors."""


@dataclass
class PointTracks:
    """Which views observed each seed point (an SfM track): pairs of a point and a view.

    SfM knows where it matched each point; reprojecting every point into every view instead lets
    points on hidden surfaces show through sparse foregrounds, which a depth prior then reads as
    the visible surface (docs/data.md).
    """

    point: np.ndarray  # [K] int64, index into the seed points
    view: np.ndarray  # [K] int64, index into ``names`` (parsed) or the scene's views (loaded)
    names: list[str] | None = None
    """Parsed tracks: the frame names (:attr:`Frame.name`) that ``view`` indexes; None once loaded."""

    def __post_init__(self) -> None:
        self.point = np.asarray(self.point, np.int64).reshape(-1)
        self.view = np.asarray(self.view, np.int64).reshape(-1)
        if self.point.shape != self.view.shape:
            raise ValueError(f"track pairs disagree: {self.point.shape} points, {self.view.shape} views")

    def points_in(self, view: int) -> np.ndarray:
        """[m] indices of the points observed in ``view`` (loaded tracks)."""
        return np.unique(self.point[self.view == view])


@dataclass
class ParsedScene:
    """A parser's raw output."""

    frames: list[Frame]
    points: np.ndarray | None = None  # [M, 3] float64 world points (seed cloud)
    point_colors: np.ndarray | None = None  # [M, 3] uint8
    point_tracks: PointTracks | None = None
    """The views each seed point was observed in, where the format records it (COLMAP tracks)."""
    train_names: list[str] | None = None
    """Explicit split, when the format has one (names as in :attr:`Frame.name`)."""
    test_names: list[str] | None = None
    test_is_clean: bool = False
    """True when test images are themselves haze-free references (Blender/RealX3D style)."""


@dataclass
class SceneTransform:
    """Similarity applied to the original world: ``x_new = scale * (R @ x + t)``."""

    rotation: Tensor  # [3, 3]
    translation: Tensor  # [3]
    scale: float

    @staticmethod
    def identity() -> SceneTransform:
        return SceneTransform(torch.eye(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64), 1.0)

    def apply_points(self, pts: Tensor) -> Tensor:  # [M, 3] -> [M, 3]
        return self.scale * (pts @ self.rotation.T.to(pts) + self.translation.to(pts))

    def apply_c2w(self, c2w: Tensor) -> Tensor:  # [N, 4, 4] -> [N, 4, 4]
        out = c2w.clone()
        R = self.rotation.to(c2w)
        out[:, :3, :3] = R @ c2w[:, :3, :3]
        out[:, :3, 3] = self.scale * (c2w[:, :3, 3] @ R.T + self.translation.to(c2w))
        return out

    def to_dict(self) -> dict[str, Any]:
        return {
            "rotation": self.rotation.tolist(),
            "translation": self.translation.tolist(),
            "scale": float(self.scale),
            "convention": "x_new = scale * (rotation @ x + translation)",
        }


@dataclass
class SceneData:
    """A dataset ready for training: pinhole cameras, image files and splits."""

    name: str
    """Scene name (the dataset folder's name); used in the run path."""
    root: Path
    parser: str
    image_paths: list[Path]
    """[N] images the trainer reads (undistorted / downscaled copies from the cache when needed)."""
    cameras: Cameras  # [N], normalised world
    train_indices: list[int]
    test_indices: list[int]
    clean_paths: list[Path | None]
    """[N] haze-free references (None where absent)."""
    depth_paths: list[Path | None]
    """[N] user depth priors (None where absent)."""
    extra_paths: dict[str, list[Path | None]]
    """Other per-frame files by key, [N] each; evaluation/analysis only."""
    points: Tensor | None  # [M, 3] float32, normalised world
    point_colors: Tensor | None  # [M, 3] float32 in [0, 1]
    transform: SceneTransform
    downscale: int = 1
    test_is_clean: bool = False
    frame_names: list[str] = field(default_factory=list)
    """[N] each view's :attr:`Frame.name` (path relative to the dataset root, unique); image_paths may
    point into the cache, whose file names carry a hash."""
    point_tracks: PointTracks | None = None
    """Which of these views observed each of :attr:`points` (None: not recorded by the dataset)."""

    def __len__(self) -> int:
        return len(self.image_paths)

    def indices(self, split: str) -> list[int]:
        if split == "train":
            return list(self.train_indices)
        if split == "test":
            return list(self.test_indices)
        if split == "all":
            return list(range(len(self)))
        raise ValueError(f"unknown split {split!r}; use train, test or all")

    def names(self) -> list[str]:
        """[N] view names: the dataset-relative names when known, else the image file names."""
        if len(self.frame_names) == len(self.image_paths):
            return list(self.frame_names)
        return [p.name for p in self.image_paths]
