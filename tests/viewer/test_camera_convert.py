"""viser camera <-> Cameras: a training view seen through the browser camera renders identically."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from components.data.cameras import Cameras
from pipelines.viewer.camera_convert import camera_to_viser, image_size, up_direction, viser_to_camera
from tests.data.synth import ring_poses
from tests.viewer.helpers import tiny_pipeline


def test_training_camera_through_viser_renders_the_same(tmp_path):
    torch.set_num_threads(1)
    pipeline, dm = tiny_pipeline(tmp_path)
    for idx in dm.train_indices:
        cam = dm.camera(idx)
        wxyz, position, fov, aspect = camera_to_viser(dm.cameras, idx)
        w, h = int(cam.width[0]), int(cam.height[0])
        assert image_size(aspect, max(w, h)) == (w, h)
        back = viser_to_camera(wxyz, position, fov, w, h)
        torch.testing.assert_close(back.camtoworlds, cam.camtoworlds, atol=1e-6, rtol=0)
        torch.testing.assert_close(back.fy, cam.fy.float(), atol=1e-4, rtol=0)
        ours, theirs = pipeline.render(back), pipeline.render(cam)
        for name in pipeline.output_names():
            torch.testing.assert_close(ours[name], theirs[name], atol=1e-4, rtol=0, msg=name)
        assert float(theirs["clean"].std()) > 0.01  # a real image, not a blank frame


def test_pose_convention_is_opencv():
    """viser's wxyz is R_world_camera in OpenCV axes: identity looks along +z with y down."""
    cam = viser_to_camera(np.array([1.0, 0, 0, 0]), np.array([1.0, 2.0, 3.0]), math.radians(60), 64, 48)
    assert cam.camtoworlds[0].tolist() == [[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]]
    # a point straight ahead projects to the image centre; fov_y spans the height
    assert float(cam.cx[0]) == 32 and float(cam.cy[0]) == 24
    assert float(cam.fy[0]) == pytest.approx(24 / math.tan(math.radians(30)))
    assert float(cam.fx[0]) == float(cam.fy[0])


def test_random_rotations_round_trip():
    g = np.random.default_rng(0)
    for _ in range(20):
        q = g.normal(size=4)
        q /= np.linalg.norm(q)
        cam = viser_to_camera(q, g.normal(size=3), 0.9, 80, 60)
        wxyz, pos, fov, aspect = camera_to_viser(cam, 0)
        assert min(np.abs(wxyz - q).max(), np.abs(wxyz + q).max()) < 1e-6  # q and -q: same rotation
        assert fov == pytest.approx(0.9) and aspect == pytest.approx(80 / 60)


@pytest.mark.parametrize(
    ("aspect", "side", "size"),
    [
        (4 / 3, 160, (160, 120)),
        (0.75, 160, (120, 160)),
        (1.0, 7, (7, 7)),
        (1000.0, 64, (64, 1)),
        (float("nan"), 9, (9, 9)),
    ],
)
def test_image_size(aspect, side, size):
    assert image_size(aspect, side) == size


def test_up_direction_of_a_ring_is_world_up():
    poses = torch.tensor(np.stack(ring_poses(8, height=1.0)), dtype=torch.float32)  # z up
    n = len(poses)
    cams = Cameras(
        poses, *(torch.full((n,), 50.0) for _ in range(4)), torch.full((n,), 64), torch.full((n,), 48)
    )
    up = up_direction(cams)
    assert up @ np.array([0.0, 0.0, 1.0]) > 0.95
