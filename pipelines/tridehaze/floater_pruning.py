"""Remove the Gaussians that float in front of the surfaces during training (``--pipeline.prune-floaters``).

Every ``densify.refine-every`` steps from ``densify.refine-start`` to the end of the run, each
training view gives a surface depth map; the Gaussians well in front of it in most views that see
them (components/gaussians/free_space.py) are pruned, so the haze they carried goes back to the
medium. ``true-depth`` takes td-synth's true depth (a diagnosis, never a method: how much removing
the floaters could give); ``rendered`` the model's own depth where its coverage is solid.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import torch
from torch import Tensor

from components.data.cameras import Cameras
from components.gaussians.free_space import floaters, in_front_counts

SKY_SHARE = 0.9
"""True depths beyond this share of the far bound are sky, not a surface."""
SOLID = 0.5
"""Rendered coverage from which a pixel's rendered depth counts as a surface."""


class FloaterPruning:
    """Decides when to prune and which Gaussians; the pipeline supplies each view's surface depth."""

    def __init__(self, mode: str, margin: float, share: float, start: int, every: int) -> None:
        self.mode, self.margin, self.share = mode, margin, share
        self.start, self.every = start, every

    @classmethod
    def from_config(cls, config) -> FloaterPruning:
        """From a pipeline config's ``prune_floaters`` / ``floater_*`` fields and its densify schedule."""
        dens = config.densify
        return cls(
            config.prune_floaters,
            config.floater_margin,
            config.floater_share,
            dens.refine_start,
            dens.refine_every,
        )

    def due(self, step: int) -> bool:
        done = step + 1
        return self.mode != "off" and done >= self.start and done % self.every == 0

    @torch.no_grad()
    def select(self, means: Tensor, views: Iterator[tuple[Cameras, Tensor]]) -> Tensor:
        """[N] bool floaters among ``means`` [N, 3], given (camera, surface depth [H, W], NaN where
        none) per training view."""
        per_view = ((cam.viewmats()[0], cam.Ks()[0], depth) for cam, depth in views)
        in_front, seen = in_front_counts(means, per_view, self.margin)
        return floaters(in_front, seen, self.share)


def true_surface(true_z: Tensor, far: float) -> Tensor:
    """[H, W] a true depth map [H, W, 1] with the sky (beyond SKY_SHARE of ``far``) set to NaN."""
    z = true_z[..., 0].clone()
    z[~(z < SKY_SHARE * far)] = float("nan")
    return z


def rendered_surface(depth: Tensor, alpha: Tensor) -> Tensor:
    """[H, W] a rendered depth [H, W, 1] with NaN where the coverage [H, W, 1] is under SOLID."""
    z = depth[..., 0].clone()
    z[alpha[..., 0] < SOLID] = float("nan")
    return z


def surface_views(
    indices: list[int], camera_of: Callable[[int], Cameras], surface_of: Callable[[int, Cameras], Tensor]
) -> Iterator[tuple[Cameras, Tensor]]:
    for idx in indices:
        cam = camera_of(idx)
        yield cam, surface_of(idx, cam)
