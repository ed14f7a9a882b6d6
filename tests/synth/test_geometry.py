"""Ray-primitive intersections against closed forms, and the culled tracer against brute force."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from components.data.cameras import ViewIntrinsics
from components.synth.generate import camera_poses
from components.synth.geometry import Box, Cylinder, Plane, SceneGeometry, Sphere, trace, trace_grid
from components.synth.layouts import LAYOUTS, make_layout
from components.synth.trajectories import camera_rays, look_at, supersampled


def _ray(o, d):
    d = torch.tensor([d], dtype=torch.float32)
    return torch.tensor([o], dtype=torch.float32), d / d.norm(dim=-1, keepdim=True)


def test_primitive_hits():
    o, d = _ray((0, -10, 1), (0, 1, 0))
    t, n = Sphere((0, 0, 1), 2.0, 0).intersect(o, d)
    assert float(t) == pytest.approx(8.0) and n[0].tolist() == pytest.approx([0, -1, 0])
    t, n = Box((-1, -1, 0), (1, 1, 2), 0).intersect(o, d)
    assert float(t) == pytest.approx(9.0) and n[0].abs().tolist() == pytest.approx([0, 1, 0])
    t, _ = Cylinder((0.0, 0.0), 0.5, 0.0, 3.0, 0).intersect(o, d)
    assert float(t) == pytest.approx(9.5)
    t, _ = Cylinder((0.0, 0.0), 0.5, 0.0, 0.5, 0).intersect(o, d)  # passes above the short cylinder
    assert math.isinf(float(t))
    o2, d2 = _ray((0.2, 0, 5), (0, 0, -1))
    t, n = Cylinder((0.0, 0.0), 0.5, 0.0, 3.0, 0).intersect(o2, d2)  # straight down onto the cap
    assert float(t) == pytest.approx(2.0) and n[0].tolist() == pytest.approx([0, 0, 1])
    t, _ = Plane((0.0, 0.0, 1.0), 0.0, 0).intersect(o2, d2)
    assert float(t) == pytest.approx(5.0)
    t, _ = Plane((0.0, 0.0, 1.0), 0.0, 0).intersect(*_ray((0, 0, 5), (0, 1, 0.1)))  # going up: no hit
    assert math.isinf(float(t))


def test_inside_box_hits_the_far_wall_with_inward_normal():
    geo = SceneGeometry(materials=[], boxes=[Box((-5, -4, 0), (5, 4, 3), 0)])
    hit = trace(geo, *_ray((0, 0, 1.5), (1, 0, 0)))
    assert float(hit.t) == pytest.approx(5.0)
    assert hit.normal[0].tolist() == pytest.approx([-1, 0, 0])  # faces the viewer


def test_nearest_of_several():
    geo = SceneGeometry(
        materials=[],
        planes=[Plane((0.0, 0.0, 1.0), 0.0, 0)],
        spheres=[Sphere((0, 6, 1), 1.0, 1)],
        boxes=[Box((-1, 3, 0), (1, 4, 2), 2)],
    )
    hit = trace(geo, *_ray((0, 0, 1), (0, 1, 0)))
    assert int(hit.material) == 2 and float(hit.t) == pytest.approx(3.0)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_culled_grid_trace_equals_brute_force(layout):
    """Per-primitive rectangle culling must never drop a hit (the rectangles are conservative)."""
    lay = make_layout(layout, seed=1)
    K = supersampled(ViewIntrinsics.from_fov(40, 30, 70.0), 2)
    for c2w in camera_poses(lay, "auto", 4)[1]:
        o, d, _ = camera_rays(c2w, K)
        fast = trace_grid(lay.geometry, o, d, c2w, K.fx, K.fy, K.cx, K.cy)
        flat = d.reshape(-1, 3)
        slow = trace(lay.geometry, o.expand_as(flat), flat)
        assert torch.equal(fast.material.reshape(-1), slow.material)
        torch.testing.assert_close(fast.t.reshape(-1), slow.t)


def test_camera_rays_follow_opencv_axes():
    K = ViewIntrinsics.from_fov(41, 31, 60.0)
    c2w = look_at(np.array([0.0, -5.0, 1.0]), np.array([0.0, 0.0, 1.0]))
    o, d, dz = camera_rays(c2w, K)
    assert d[15, 20].tolist() == pytest.approx([0, 1, 0], abs=1e-6)  # centre pixel looks forward
    assert float(d[0, 20, 2]) > 0  # top row looks up (image y down)
    assert float(d[15, 40, 0]) > 0  # right column looks right (+x when facing +y)
    assert float(dz.max()) == pytest.approx(1.0, abs=1e-3) and float(dz.min()) < 1
