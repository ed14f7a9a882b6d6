"""Camera paths: travel order, a smooth interpolation through the cameras, an orbit around the scene."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from components.data.cameras import Cameras
from pipelines.evaluation.camera_paths import (
    interpolate_path,
    look_at,
    make_path,
    orbit_path,
    order_cameras,
    scene_focus,
    scene_up,
)

UP = np.array([0.0, 0.0, 1.0])


def arc(n: int, start: float = 0.0, span: float = math.pi, radius: float = 4.0, height: float = 1.0):
    """[n, 4, 4] cameras on an arc around the origin (z up), looking at it."""
    out = []
    for a in np.linspace(start, start + span, n):
        out.append(look_at(np.array([radius * math.cos(a), radius * math.sin(a), height]), np.zeros(3), UP))
    return np.stack(out)


def _is_rotation(R: np.ndarray) -> bool:
    return np.allclose(R.T @ R, np.eye(3), atol=1e-9) and abs(np.linalg.det(R) - 1) < 1e-9


def test_look_at_opencv_axes():
    m = look_at(np.array([4.0, 0, 1]), np.zeros(3), UP)
    assert _is_rotation(m[:3, :3])
    z = m[:3, 2]
    np.testing.assert_allclose(z, -m[:3, 3] / np.linalg.norm(m[:3, 3]))  # forward: at the target
    assert m[:3, 1] @ UP < 0  # image y points down


def test_order_recovers_a_shuffled_arc():
    c2w = arc(11)
    perm = np.random.default_rng(0).permutation(11)
    order = order_cameras(c2w[perm][:, :3, 3])
    walked = list(perm[order])
    assert walked in (list(range(11)), list(range(10, -1, -1)))


def test_interpolation_passes_through_cameras_smoothly():
    c2w = arc(7, span=2.0)
    path = interpolate_path(c2w, 241)
    assert path.shape == (241, 4, 4)
    assert all(_is_rotation(m[:3, :3]) for m in path)
    ends = {tuple(np.round(path[0, :3, 3], 9)), tuple(np.round(path[-1, :3, 3], 9))}
    assert ends == {tuple(np.round(c2w[0, :3, 3], 9)), tuple(np.round(c2w[-1, :3, 3], 9))}
    for cam in c2w:  # every key camera is (nearly) on the path, position and orientation
        d = np.linalg.norm(path[:, :3, 3] - cam[:3, 3], axis=1)
        i = int(np.argmin(d))
        assert d[i] < 0.03
        assert np.abs(path[i, :3, :3] - cam[:3, :3]).max() < 0.02
    steps = np.linalg.norm(np.diff(path[:, :3, 3], axis=0), axis=1)
    assert steps.max() < 1.5 * np.median(steps)  # evenly spaced, no jumps
    # on an arc around the origin the cameras keep looking (nearly) at it
    fwd = path[:, :3, 2]
    to_c = -path[:, :3, 3] / np.linalg.norm(path[:, :3, 3], axis=1, keepdims=True)
    assert (fwd * to_c).sum(1).min() > 0.99


def test_orbit_circles_the_focus_at_the_cameras_radius_and_height():
    c2w = arc(9, start=0.3, span=1.5, radius=3.0, height=0.8)
    np.testing.assert_allclose(scene_focus(c2w), np.zeros(3), atol=1e-9)
    up = scene_up(c2w)
    np.testing.assert_allclose(up, UP, atol=1e-9)  # the arc's plane normal, not the cameras' tilted up
    path = orbit_path(c2w, 36)
    pos = path[:, :3, 3]
    np.testing.assert_allclose(pos @ up, np.full(36, pos[0] @ up), atol=1e-9)  # one height
    horiz = pos - (pos @ up)[:, None] * up
    r = np.linalg.norm(horiz, axis=1)
    np.testing.assert_allclose(r, r[0], atol=1e-9)
    cams_rel = c2w[:, :3, 3]
    cam_r = np.linalg.norm(cams_rel - (cams_rel @ up)[:, None] * up, axis=1).mean()
    assert abs(r[0] - cam_r) < 1e-9
    start = order_cameras(c2w[:, :3, 3])[0]  # the orbit starts above/below the first camera in travel order
    assert start in (0, 8)
    cam_h = c2w[start, :3, 3] - (c2w[start, :3, 3] @ up) * up
    np.testing.assert_allclose(horiz[0] / r[0], cam_h / np.linalg.norm(cam_h), atol=1e-9)
    fwd = path[:, :3, 2]
    np.testing.assert_allclose(
        (fwd * (-pos / np.linalg.norm(pos, axis=1, keepdims=True))).sum(1), 1, atol=1e-9
    )
    # a full turn, in the direction the capture moves (away from its first camera towards the others)
    ang = np.unwrap(np.arctan2(pos[:, 1], pos[:, 0]))
    assert abs(ang[-1] - ang[0]) == pytest.approx(2 * math.pi * 35 / 36)
    cam_ang = math.atan2(c2w[4, 1, 3], c2w[4, 0, 3])  # the middle camera
    assert abs(np.angle(np.exp(1j * (ang[4] - cam_ang)))) < abs(np.angle(np.exp(1j * (ang[0] - cam_ang))))


def test_make_path_uses_the_most_common_image_size():
    c2w = torch.from_numpy(arc(5)).float()
    n = 5
    cams = Cameras(
        c2w, torch.full((n,), 50.0), torch.full((n,), 50.0), torch.full((n,), 20.0), torch.full((n,), 15.0),
        torch.tensor([40, 40, 42, 40, 42]), torch.tensor([30, 30, 31, 30, 31]),
    )  # fmt: skip
    path = make_path("orbit", cams, [0, 1, 2, 3, 4], 8)
    assert (path.intrinsics.width, path.intrinsics.height) == (40, 30) and len(path) == 8
    cam = path.camera(3)
    assert cam.camtoworlds.shape == (1, 4, 4) and int(cam.width[0]) == 40
