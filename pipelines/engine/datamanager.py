"""Serves training views and their images to a pipeline, deterministically from (seed, step)."""

from __future__ import annotations

import torch
from torch import Tensor

from components.data.cameras import Cameras
from components.data.dataset import ImageSet
from components.data.scene import SceneData


class DataManager:
    """Holds a scene's cameras and lazily loaded images (decoded once, float on demand).

    The training view order is a fresh permutation of the train split per epoch, derived from
    ``(seed, epoch)`` alone, so a resumed run sees exactly the views an uninterrupted one would.
    """

    def __init__(self, scene: SceneData, device: torch.device, seed: int = 0) -> None:
        self.scene = scene
        self.device = device
        self.seed = seed
        self._images = ImageSet.from_scene(scene, "image", device)
        self._clean = ImageSet.from_scene(scene, "clean", device)
        self.cameras = scene.cameras.to(device)

    @property
    def train_indices(self) -> list[int]:
        return self.scene.train_indices

    @property
    def test_indices(self) -> list[int]:
        return self.scene.test_indices

    def train_index(self, step: int) -> int:
        """The training view used at ``step``."""
        n = len(self.train_indices)
        epoch, pos = divmod(step, n)
        gen = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
        return self.train_indices[int(torch.randperm(n, generator=gen)[pos])]

    def camera(self, idx: int) -> Cameras:  # [1]
        return self.cameras[idx]

    def image(self, idx: int) -> Tensor:
        """The (hazy) input image of view ``idx``: [H, W, 3] float in [0, 1] on the device."""
        return self._images[idx]

    def hazy_image(self, idx: int) -> Tensor | None:
        """The hazy input of view ``idx``, or None where the view's image is itself the clean
        reference (Blender/RealX3D-style test views)."""
        sc = self.scene
        if sc.test_is_clean and sc.clean_paths[idx] == sc.image_paths[idx]:
            return None
        return self.image(idx)

    def clean_image(self, idx: int) -> Tensor | None:
        """The haze-free reference of view ``idx`` ([H, W, 3]) or None when the dataset has none."""
        return self._clean[idx] if self._clean.has(idx) else None
