"""Pinhole cameras in the framework's single convention.

Convention (documented in docs/data.md): **OpenCV** camera axes, x right, y down, z forward
(the camera looks along +z), and ``camtoworlds`` map camera coordinates to world
coordinates. This matches COLMAP and gsplat's ``viewmats`` (world-to-camera). Parsers convert
OpenGL/Blender poses (y up, z backward) on load with :func:`opengl_to_opencv`.

All images are pinhole by the time they reach a ``Cameras``: distorted inputs are undistorted
once by the data layer, so no distortion parameters live here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import Tensor

# flips the y and z camera axes: OpenGL (x right, y up, z back) <-> OpenCV (x right, y down, z fwd)
_GL_CV_FLIP = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))


def opengl_to_opencv(c2w: Tensor) -> Tensor:
    """Convert camera-to-world matrices [..., 4, 4] from OpenGL to OpenCV camera axes."""
    return c2w @ _GL_CV_FLIP.to(c2w)


@dataclass(frozen=True)
class ViewIntrinsics:
    """Pinhole intrinsics of one view (or of views sharing them), in pixels."""

    fx: float
    """Focal length along x (pixels)."""
    fy: float
    """Focal length along y (pixels)."""
    cx: float
    """Principal point x (pixels; pixel centres at +0.5, so the image centre is ``width / 2``)."""
    cy: float
    """Principal point y (pixels; pixel centres at +0.5, so the image centre is ``height / 2``)."""
    width: int
    """Image width (pixels)."""
    height: int
    """Image height (pixels)."""

    @staticmethod
    def from_fov(width: int, height: int, fov_x_deg: float) -> ViewIntrinsics:
        """Square pixels, principal point at the image centre, horizontal field of view ``fov_x_deg``."""
        f = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2)
        return ViewIntrinsics(fx=f, fy=f, cx=width / 2, cy=height / 2, width=width, height=height)


@dataclass
class Cameras:
    """A batch of N pinhole cameras (each may have its own size and intrinsics)."""

    camtoworlds: Tensor  # [N, 4, 4] float, OpenCV axes
    fx: Tensor  # [N] pixels
    fy: Tensor  # [N]
    cx: Tensor  # [N] principal point, pixels (pixel centres at +0.5)
    cy: Tensor  # [N]
    width: Tensor  # [N] int64
    height: Tensor  # [N] int64

    def __post_init__(self) -> None:
        n = self.camtoworlds.shape[0]
        if self.camtoworlds.shape != (n, 4, 4):
            raise ValueError(f"camtoworlds must be [N, 4, 4], got {tuple(self.camtoworlds.shape)}")
        for name in ("fx", "fy", "cx", "cy", "width", "height"):
            t = getattr(self, name)
            if t.shape != (n,):
                raise ValueError(f"{name} must be [{n}], got {tuple(t.shape)}")

    def __len__(self) -> int:
        return self.camtoworlds.shape[0]

    def __getitem__(self, idx: int | slice | list[int] | Tensor) -> Cameras:
        if isinstance(idx, int):
            idx = [idx]
        return Cameras(
            camtoworlds=self.camtoworlds[idx],
            fx=self.fx[idx],
            fy=self.fy[idx],
            cx=self.cx[idx],
            cy=self.cy[idx],
            width=self.width[idx],
            height=self.height[idx],
        )

    @property
    def device(self) -> torch.device:
        return self.camtoworlds.device

    def to(self, device: torch.device | str) -> Cameras:
        return Cameras(*(getattr(self, f).to(device) for f in _FIELDS))

    def Ks(self) -> Tensor:  # noqa: N802 - conventional name
        """Intrinsic matrices [N, 3, 3]."""
        K = torch.zeros(len(self), 3, 3, dtype=self.fx.dtype, device=self.device)
        K[:, 0, 0], K[:, 1, 1] = self.fx, self.fy
        K[:, 0, 2], K[:, 1, 2] = self.cx, self.cy
        K[:, 2, 2] = 1.0
        return K

    def viewmats(self) -> Tensor:
        """World-to-camera matrices [N, 4, 4] (gsplat's ``viewmats``), computed exactly for rigid poses."""
        R = self.camtoworlds[:, :3, :3]  # [N, 3, 3]
        t = self.camtoworlds[:, :3, 3:]  # [N, 3, 1]
        out = torch.zeros_like(self.camtoworlds)
        out[:, :3, :3] = R.transpose(1, 2)
        out[:, :3, 3:] = -R.transpose(1, 2) @ t
        out[:, 3, 3] = 1.0
        return out

    @property
    def centers(self) -> Tensor:
        """Camera centres in world coordinates [N, 3]."""
        return self.camtoworlds[:, :3, 3]

    def rescaled(
        self, scale_x: Tensor | float, scale_y: Tensor | float, width: Tensor, height: Tensor
    ) -> Cameras:
        """Cameras for images resized by (scale_x, scale_y) to the given integer sizes."""
        return replace(
            self,
            fx=self.fx * scale_x,
            fy=self.fy * scale_y,
            cx=self.cx * scale_x,
            cy=self.cy * scale_y,
            width=width.to(torch.int64),
            height=height.to(torch.int64),
        )

    @staticmethod
    def cat(cams: list[Cameras]) -> Cameras:
        return Cameras(*(torch.cat([getattr(c, f) for c in cams]) for f in _FIELDS))


_FIELDS = ("camtoworlds", "fx", "fy", "cx", "cy", "width", "height")


def scene_up(c2w: np.ndarray) -> np.ndarray:
    """The scene's up direction, unit length.

    The cameras' mean up (minus their image y axis) is biased towards the scene when they look
    down at it from one side; when the centres spread in a plane (an arc or ring around the scene),
    that plane's normal, signed like the mean up, is used instead (it is exact for a ring).
    """
    up = -c2w[:, :3, 1].mean(axis=0)
    n = np.linalg.norm(up)
    up = up / n if n > 1e-9 else np.array([0.0, 0.0, 1.0])
    centers = c2w[:, :3, 3]
    if len(centers) >= 3:
        _, sv, vt = np.linalg.svd(centers - centers.mean(0), full_matrices=False)
        normal = vt[2]
        planar = sv[1] > 1e-9 and sv[2] < 0.3 * sv[1]
        if planar and abs(normal @ up) > math.cos(math.radians(45)):
            return normal if normal @ up > 0 else -normal
    return up
