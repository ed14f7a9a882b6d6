"""Checks on the camera set as a whole: values that each pass their own frame's checks but
together make training meaningless (a downscale that leaves a few pixels, a camera far from all
others, intrinsics or poses under which no seed point lands in any image).

Each refuses with one :class:`DataError` when nothing sensible can come of the data, and warns
(:class:`DataWarning`) where a strange value can still be legitimate.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from components.data.cameras import ViewIntrinsics
from components.data.scene import DataWarning, Frame
from tridehaze_plugin.errors import DataError, first_few

MIN_IMAGE_SIDE = 8
"""Smallest image side (pixels) training accepts after ``--downscale``: below it the image holds too
little for SSIM's window, the dark-channel patch and the medium's ray grid to mean much (they
shrink to fit, so photos that small on disk still train)."""
FAR_CAMERA = 1e4
"""A camera farther from the cameras' median centre than this many times their median distance
from it is a broken pose, not part of the capture."""
VISIBILITY_SAMPLE = 4096
"""Seed points projected per view when checking that the cameras see the scene."""


def check_downscaled_size(frames: list[Frame], out_sizes: list[tuple[int, int]], downscale: int) -> None:
    """DataError when ``--downscale`` takes an image side below :data:`MIN_IMAGE_SIDE` (images
    that are that small on disk are the data, not the flag's doing)."""
    short = [
        i for i, (f, size) in enumerate(zip(frames, out_sizes, strict=True))
        if min(size) < min(MIN_IMAGE_SIDE, f.intrinsics.width, f.intrinsics.height)
    ]  # fmt: skip
    if not short:
        return
    i = short[0]
    f = frames[i]
    largest = max(1, min(f.intrinsics.width, f.intrinsics.height) // MIN_IMAGE_SIDE)
    raise DataError(
        f"--downscale {downscale} makes frame {f.name} {out_sizes[i][0]}x{out_sizes[i][1]} pixels "
        f"(at least {MIN_IMAGE_SIDE} per side are needed)",
        where=str(f.image_path),
        fix=f"use --downscale {largest} or less",
    )


def check_camera_spread(frames: list[Frame], centres: np.ndarray) -> None:
    """DataError naming a camera absurdly far from the others (``centres`` [N, 3]): normalising the
    scene by the cameras' extent would shrink everything else to a point."""
    if len(frames) < 3:
        return
    median = np.median(centres, axis=0)  # [3]
    dist = np.linalg.norm(centres - median, axis=1)  # [N]
    typical = float(np.median(dist))
    far = int(np.argmax(dist))
    if typical > 0 and dist[far] > FAR_CAMERA * typical:
        raise DataError(
            f"camera of frame {frames[far].name} is {dist[far]:.3g} units from the others' centre, "
            f"{dist[far] / typical:.3g}x their typical distance",
            where=str(frames[far].image_path),
            fix="fix or remove this frame's pose",
        )


def check_principal_points(frames: list[Frame], root: Path) -> None:
    """Warn about principal points outside their image (possible for crops, usually a unit mix-up)."""
    off = [f.name for f in frames if not _principal_point_inside(f.intrinsics)]
    if off:
        warnings.warn(
            f"{len(off)} view(s) have their principal point outside the image ({first_few(off)}; {root})",
            DataWarning,
            stacklevel=3,
        )


def _principal_point_inside(k: ViewIntrinsics) -> bool:
    return 0.0 <= k.cx <= k.width and 0.0 <= k.cy <= k.height


def check_seed_visibility(
    points: np.ndarray,
    c2w: np.ndarray,
    intrinsics: np.ndarray,
    sizes: np.ndarray,
    names: list[str],
    root: Path,
) -> None:
    """DataError when no seed point lands inside any view; a warning naming the views that see none.

    ``points`` [M, 3] and ``c2w`` [N, 4, 4] (OpenCV axes) in one frame, ``intrinsics`` [N, 4]
    (fx, fy, cx, cy), ``sizes`` [N, 2] (W, H). With wrong intrinsics or poses every point falls off
    screen and training fits Gaussians no view can see.
    """
    if len(points) == 0:
        return
    step = max(1, len(points) // VISIBILITY_SAMPLE)
    pts = points[::step]  # [S, 3]
    w2c = np.linalg.inv(c2w)  # [N, 4, 4]
    cam = np.einsum("nij,sj->nsi", w2c[:, :3, :3], pts) + w2c[:, None, :3, 3]  # [N, S, 3]
    z = cam[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intrinsics[:, None, 0] * cam[..., 0] / z + intrinsics[:, None, 2]  # [N, S]
        v = intrinsics[:, None, 1] * cam[..., 1] / z + intrinsics[:, None, 3]
    inside = (z > 0) & (u >= 0) & (u <= sizes[:, None, 0]) & (v >= 0) & (v <= sizes[:, None, 1])
    seen = inside.any(axis=1)  # [N]
    if not seen.any():
        raise DataError(
            f"no seed point projects into any of the {len(names)} views: the intrinsics (focal length, "
            "principal point) or the poses do not match the point cloud",
            where=str(root),
            fix="check the camera model's units and the poses' convention (OpenCV vs OpenGL axes)",
        )
    blind = [n for n, s in zip(names, seen, strict=True) if not s]
    if blind:
        warnings.warn(
            f"{len(blind)} of {len(names)} view(s) see none of the seed points ({first_few(blind)}; {root})",
            DataWarning,
            stacklevel=3,
        )
