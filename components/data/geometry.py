"""From a raw camera to the trainer's pinhole image: undistortion and integer downscaling.

Choices (see docs/data.md):

* **Undistortion** uses ``cv2.getOptimalNewCameraMatrix`` with ``alpha=0`` at the original size:
  the new pinhole K is chosen so that every output pixel sees real image content, i.e. there
  are *no black borders* (a few edge pixels of the original are cropped away instead). The
  frame's intrinsics become that new K.
* **Downscale** by K gives ``floor(W / K + 0.5)`` x ``floor(H / K + 0.5)`` pixels (halves round
  up), and intrinsics are scaled by exactly ``new_w / W`` and ``new_h / H``, so projections stay
  exact even when K does not divide the size.
* Principal points use the framework's convention (pixel centres at +0.5, like COLMAP); OpenCV
  puts centres at integer coordinates, so 0.5 is subtracted around every OpenCV call.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from components.data.scene import Frame
from tridehaze_plugin.errors import DataError


@dataclass(frozen=True)
class Intrinsics:
    fx: float
    fy: float
    cx: float
    cy: float

    def K_cv(self) -> np.ndarray:  # noqa: N802 - conventional name; [3, 3], OpenCV pixel-centre convention
        return np.array([[self.fx, 0.0, self.cx - 0.5], [0.0, self.fy, self.cy - 0.5], [0.0, 0.0, 1.0]])

    @staticmethod
    def from_K_cv(K: np.ndarray) -> Intrinsics:  # noqa: N802
        return Intrinsics(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]) + 0.5, float(K[1, 2]) + 0.5)

    def scaled(self, sx: float, sy: float) -> Intrinsics:
        return Intrinsics(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy)


@dataclass(frozen=True)
class Geometry:
    """How one raw image (size, K, distortion) maps to the output pinhole image."""

    src_size: tuple[int, int]  # (W, H) of the file on disk
    src: Intrinsics
    distortion: tuple[float, ...]  # OpenCV order; empty when pinhole
    pinhole: Intrinsics  # after undistortion, still at the source size
    out_size: tuple[int, int]  # (W, H) after downscaling
    out: Intrinsics  # what the trainer sees
    downscale: int

    @property
    def is_identity(self) -> bool:
        """True when the file on disk can be used as is."""
        return not self.distortion and self.downscale == 1

    def key(self) -> dict:
        """Everything that determines the processed pixels (part of the cache key)."""
        return {
            "src_size": list(self.src_size),
            "src": [self.src.fx, self.src.fy, self.src.cx, self.src.cy],
            "distortion": list(self.distortion),
            "downscale": self.downscale,
        }


def scaled_size(width: int, height: int, downscale: int) -> tuple[int, int]:
    """Output size for an integer downscale: round half up, at least one pixel."""
    return max(1, math.floor(width / downscale + 0.5)), max(1, math.floor(height / downscale + 0.5))


def frame_geometry(frame: Frame, downscale: int) -> Geometry:
    k = frame.intrinsics
    src = Intrinsics(k.fx, k.fy, k.cx, k.cy)
    size = (int(k.width), int(k.height))
    dist = tuple(float(d) for d in frame.distortion) if any(d != 0.0 for d in frame.distortion) else ()
    pinhole = _undistorted_intrinsics(src, dist, size, frame) if dist else src
    out_size = scaled_size(*size, downscale)
    out = pinhole.scaled(out_size[0] / size[0], out_size[1] / size[1])
    return Geometry(size, src, dist, pinhole, out_size, out, downscale)


MAX_ZOOM = 4.0
"""Largest factor by which undistortion may change the focal length: real lenses (even wide
fisheyes cropped to the valid area) stay well inside it; beyond it the coefficients are absurd
(the whole image would map to a sliver of the view or fold over itself)."""


def _radial_folds(src: Intrinsics, dist: tuple[float, ...], size: tuple[int, int]) -> bool:
    """True when the radial distortion is not one-to-one out to the image's farthest corner: the
    distorted radius stops growing before it gets there (strong negative k1 folds the image), so
    no undistortion exists. Tangential terms are small by construction and left out."""
    k = [*dist, *[0.0] * 8]  # (k1, k2, p1, p2, k3, k4, k5, k6, ...) padded
    k1, k2, k3, k4, k5, k6 = k[0], k[1], k[4], k[5], k[6], k[7]
    w, h = size
    corner = max(math.hypot((x - src.cx) / src.fx, (y - src.cy) / src.fy) for x in (0, w) for y in (0, h))
    r = np.linspace(0.0, 4.0 * corner, 4001)[1:]  # [R] undistorted radii
    r2 = r * r
    num = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
    rd = r * num / den  # [R] distorted radii
    reach = np.nonzero(rd >= corner)[0]
    if len(reach) == 0 or not np.all(np.isfinite(rd[: reach[0] + 1])):
        return True
    return bool(np.any(np.diff(rd[: reach[0] + 1]) <= 0))


def _undistorted_intrinsics(
    src: Intrinsics, dist: tuple[float, ...], size: tuple[int, int], frame: Frame
) -> Intrinsics:
    if _radial_folds(src, dist, size):
        raise DataError(
            f"cannot undistort frame {frame.name}: distortion {dist} folds the image over itself before "
            "its corners (no one-to-one undistortion exists)",
            where=str(frame.image_path),
            fix="check the distortion coefficients and the camera model they belong to",
        )
    K, _roi = cv2.getOptimalNewCameraMatrix(src.K_cv(), _dist_array(dist), size, 0.0, size)
    new = Intrinsics.from_K_cv(K)
    vals = (new.fx, new.fy, new.cx, new.cy)
    zoom = new.fx / src.fx if math.isfinite(new.fx) else math.inf
    if (
        not all(math.isfinite(v) for v in vals)
        or new.fx <= 0
        or new.fy <= 0
        or not 1 / MAX_ZOOM <= zoom <= MAX_ZOOM
    ):
        raise DataError(
            f"cannot undistort frame {frame.name}: distortion {dist} gives an invalid pinhole camera",
            where=str(frame.image_path),
            fix="check the distortion coefficients (they look far too large)",
        )
    return new


def _dist_array(dist: tuple[float, ...]) -> np.ndarray:
    """OpenCV accepts 4, 5, 8, 12 or 14 coefficients; pad to the next valid length."""
    n = next(k for k in (4, 5, 8, 12, 14) if k >= len(dist))
    return np.array(list(dist) + [0.0] * (n - len(dist)), dtype=np.float64)


@lru_cache(maxsize=8)
def _maps(geom: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """Undistortion lookup maps [H, W] float32 (x, y) for ``cv2.remap``."""
    return cv2.initUndistortRectifyMap(
        geom.src.K_cv(), _dist_array(geom.distortion), None, geom.pinhole.K_cv(), geom.src_size, cv2.CV_32FC1
    )


def apply_geometry(arr: np.ndarray, geom: Geometry, *, nearest: bool = False) -> np.ndarray:
    """Resample an image or map [H, W(, C)] from the source grid to the output grid.

    Colour images use bilinear undistortion + area downscaling (anti-aliased); depth maps and other
    per-pixel maps use nearest neighbour (``nearest=True``) so no value is ever invented by mixing a
    foreground and a background pixel.
    """
    if arr.shape[1] != geom.src_size[0] or arr.shape[0] != geom.src_size[1]:
        # e.g. a depth map stored at another resolution: bring it to the image grid first
        arr = cv2.resize(arr, geom.src_size, interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)
    if geom.distortion:
        mx, my = _maps(geom)
        interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        arr = cv2.remap(arr, mx, my, interp, borderMode=cv2.BORDER_REPLICATE)
    if geom.out_size != geom.src_size:
        arr = cv2.resize(arr, geom.out_size, interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)
    return arr
