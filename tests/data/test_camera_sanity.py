"""Camera-set checks: values each frame passes alone but that together make training meaningless."""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from components.data.cameras import ViewIntrinsics
from components.data.sanity import (
    MIN_IMAGE_SIDE,
    check_camera_spread,
    check_downscaled_size,
    check_principal_points,
    check_seed_visibility,
)
from components.data.scene import DataWarning, Frame
from tridehaze_plugin.errors import DataError


def _frame(i: int, x: float = 0.0, **kw) -> Frame:
    c2w = np.eye(4)
    c2w[0, 3] = x
    k = ViewIntrinsics(fx=50.0, fy=50.0, cx=32.0, cy=24.0, width=64, height=48)
    return Frame(name=f"{i}.png", image_path=Path(f"/d/{i}.png"), c2w=c2w, intrinsics=k, **kw)


def _look(frames: list[Frame], points: np.ndarray) -> None:
    check_seed_visibility(
        points,
        np.stack([f.c2w for f in frames]),
        np.array([[f.intrinsics.fx, f.intrinsics.fy, f.intrinsics.cx, f.intrinsics.cy] for f in frames]),
        np.array([[f.intrinsics.width, f.intrinsics.height] for f in frames], dtype=float),
        [f.name for f in frames],
        Path("/d"),
    )


def test_downscale_message_names_the_largest_that_works():
    frames = [_frame(0)]
    with pytest.raises(DataError, match=f"use --downscale {48 // MIN_IMAGE_SIDE} or less"):
        check_downscaled_size(frames, [(2, 2)], 24)
    check_downscaled_size(frames, [(16, 12)], 4)


def test_a_camera_far_from_the_rest_is_named():
    frames = [_frame(i, x=float(i)) for i in range(5)] + [_frame(5, x=1e9)]
    with pytest.raises(DataError, match="camera of frame 5.png is 1e\\+09 units"):
        check_camera_spread(frames, np.stack([f.c2w[:3, 3] for f in frames]))
    spread = [_frame(i, x=float(10**i)) for i in range(4)]  # a long, uneven track is not refused
    check_camera_spread(spread, np.stack([f.c2w[:3, 3] for f in spread]))


def test_views_that_see_no_point_are_warned_about_and_none_at_all_refused():
    points = np.array([[0.0, 0.0, 5.0], [0.1, 0.1, 4.0]])  # in front of a camera at the origin
    frames = [_frame(0), _frame(1)]
    frames[1].c2w = np.diag([1.0, -1.0, -1.0, 1.0])  # looks the other way
    with pytest.warns(DataWarning, match="1 of 2 view\\(s\\) see none of the seed points \\(1.png"):
        _look(frames, points)
    with pytest.raises(DataError, match="no seed point projects into any of the 1 views"):
        _look([frames[1]], points)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _look([frames[0]], points)


def test_principal_points_outside_the_image_are_warned_about():
    off = _frame(1)
    off.intrinsics = replace(off.intrinsics, cx=-500.0)
    with pytest.warns(
        DataWarning, match="1 view\\(s\\) have their principal point outside the image \\(1.png"
    ):
        check_principal_points([_frame(0), off], Path("/d"))
