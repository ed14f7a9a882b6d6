"""Images of a scene as float tensors, decoded on first use and kept in memory."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

import torch
from torch import Tensor

from components.data.images import read_image
from components.data.scene import SceneData
from tridehaze_plugin.errors import DataError


class ImageSet:
    """Lazily loaded images, indexed like the scene's views (``paths[i]`` is view ``i``).

    Decoding is the slow part of reading a dataset, so each image is decoded once; the cache holds
    uint8 (4x smaller than float) and converts on access.
    """

    def __init__(self, paths: Sequence[Path | None], device: torch.device | str = "cpu") -> None:
        self.paths = list(paths)
        self.device = torch.device(device)
        self._cache: dict[int, Tensor] = {}  # idx -> [H, W, 3] uint8 on self.device

    @classmethod
    def from_scene(
        cls, scene: SceneData, which: str = "image", device: torch.device | str = "cpu"
    ) -> ImageSet:
        """``which``: ``image`` (the hazy inputs) or ``clean`` (haze-free references, None where absent)."""
        if which not in ("image", "clean"):
            raise ValueError(f"which must be 'image' or 'clean', got {which!r}")
        return cls(scene.image_paths if which == "image" else scene.clean_paths, device)

    def __len__(self) -> int:
        return len(self.paths)

    def has(self, idx: int) -> bool:
        return self.paths[idx] is not None

    def __getitem__(self, idx: int) -> Tensor:
        """View ``idx`` as float32 [H, W, 3] in [0, 1]."""
        img = self._cache.get(idx)
        if img is None:
            path = self.paths[idx]
            if path is None:
                raise DataError(f"view {idx} has no image of this kind (e.g. no clean reference)")
            img = torch.from_numpy(read_image(path)).to(self.device)  # [H, W, 3] uint8
            self._cache[idx] = img
        return img.float() / 255.0

    def preload(self, indices: Iterable[int]) -> None:
        for i in indices:
            self[i]

    def clear(self) -> None:
        self._cache.clear()
