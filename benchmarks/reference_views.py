"""The test views of a generated scene with its true transmittance and depth, for the diagnoses
that compare a trained run's medium or depth with the truth (medium_start, depth_diagnosis), and
the generator's own medium beside the trained one (medium_along_rays, medium_capacity)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import torch
from torch import Tensor

from components.data.cameras import Cameras
from components.medium.base import MediumField
from components.medium.reference import true_medium
from pipelines.engine.datamanager import DataManager
from pipelines.engine.medium_recovery import REFERENCE_T_KEY, reference_depth, reference_map

TRUE_T_BINS = ((0.0, 0.2), (0.2, 0.4), (0.4, 0.7), (0.7, 1.0))
"""True-T bins [lo, hi) of the diagnoses' tables (the last one includes 1)."""


@dataclass
class ReferenceView:
    index: int
    camera: Cameras
    height: int
    width: int
    true_t: Tensor  # [H, W, 1]
    true_z: Tensor  # [H, W, 1] camera z-depth in the normalised frame (the run's units)


def reference_views(dm: DataManager, indices: Iterable[int] | None = None) -> Iterator[ReferenceView]:
    """The views (``indices``; default the test views) that have both a true T map and a true depth
    map."""
    for idx in dm.test_indices if indices is None else indices:
        cam = dm.camera(idx)
        size = (int(cam.height[0]), int(cam.width[0]))
        true_t = reference_map(dm, REFERENCE_T_KEY, idx, size)
        true_z = reference_depth(dm, idx, size)
        if true_t is None or true_z is None:
            continue
        yield ReferenceView(idx, cam, size[0], size[1], true_t, true_z)


def true_medium_field(pipe, dm: DataManager) -> MediumField:
    """The generator's own medium (extinction and light at scale 1) in the run's frame and in its
    trained field's box, for comparing the two at the same points."""
    return true_medium(pipe.config.medium, pipe.medium_field().bounds, dm.scene.root, dm.scene.transform)


def march_samples(field, origin: Tensor, dirs: Tensor, z: Tensor, samples: int) -> tuple[Tensor, Tensor]:
    """Optical depth [P, K] and light [P, K, 3] of ``field`` at ``samples`` midpoints of the rays
    origin + t * dirs (origin [3] or [P, 3]; dirs [P, 3] with unit camera z) to camera z-depths z [P]."""
    u = (torch.arange(samples, dtype=z.dtype, device=z.device) + 0.5) / samples  # [K]
    pts = origin.reshape(-1, 1, 3) + dirs[:, None, :] * (z[:, None] * u)[..., None]  # [P, K, 3]
    unit = (dirs / dirs.norm(dim=-1, keepdim=True))[:, None, :].expand(-1, samples, -1)  # [P, K, 3]
    sample = field(pts.reshape(-1, 3), unit.reshape(-1, 3))
    step = (z * dirs.norm(dim=-1) / samples)[:, None]  # [P, 1] path length per sample
    return sample.beta.reshape(-1, samples) * step, sample.light.reshape(-1, samples, 3)
