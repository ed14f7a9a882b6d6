"""The test views of a generated scene with its true transmittance and depth, for the diagnoses
that compare a trained run's medium or depth with the truth (medium_start, depth_diagnosis)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from torch import Tensor

from components.data.cameras import Cameras
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


def reference_views(dm: DataManager) -> Iterator[ReferenceView]:
    """The test views that have both a true T map and a true depth map."""
    for idx in dm.test_indices:
        cam = dm.camera(idx)
        size = (int(cam.height[0]), int(cam.width[0]))
        true_t = reference_map(dm, REFERENCE_T_KEY, idx, size)
        true_z = reference_depth(dm, idx, size)
        if true_t is None or true_z is None:
            continue
        yield ReferenceView(idx, cam, size[0], size[1], true_t, true_z)
