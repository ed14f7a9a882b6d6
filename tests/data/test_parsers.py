"""Each format parses with the right counts, sizes, intrinsics and camera axes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from components.data.loader import load_scene
from components.data.parsers.base import c2w_from_opengl
from components.data.ply import write_ply_points

from .synth import make_image, project, write_blender, write_colmap, write_nerfstudio, write_rgb


def _project_loaded(scene, i, X):
    cams = scene.cameras
    return project(
        cams.camtoworlds[i].double().numpy(),
        float(cams.fx[i]),
        float(cams.fy[i]),
        float(cams.cx[i]),
        float(cams.cy[i]),
        X,
    )


def test_opengl_pose_written_by_hand_projects_as_expected():
    # Blender-style camera at (0, -4, 0) looking at the origin with world +z up, in OpenGL axes:
    # camera x = world x, camera y (up) = world z, camera z (backwards) = world -y.
    gl = [[1, 0, 0, 0], [0, 0, -1, -4], [0, 1, 0, 0], [0, 0, 0, 1]]  # Blender rotation (90, 0, 0)
    c2w = c2w_from_opengl(gl, "test")
    f, cx, cy = 100.0, 50.0, 40.0
    np.testing.assert_allclose(project(c2w, f, f, cx, cy, [0, 0, 0]), [cx, cy])
    # world right -> image right; world up -> image up (smaller v, since OpenCV's y points down)
    np.testing.assert_allclose(project(c2w, f, f, cx, cy, [0.4, 0, 0]), [cx + 10, cy])
    np.testing.assert_allclose(project(c2w, f, f, cx, cy, [0, 0, 0.4]), [cx, cy - 10])


def test_nerfstudio(tmp_path, make_cfg):
    root = tmp_path / "ns"
    poses = write_nerfstudio(
        root,
        n=6,
        frame_extra=lambda i: {
            "gt_depth_file_path": f"gt/{i}.npy",
            "depth_file_path": f"depth/{i}.npy",
        },
        extra_global={"ply_file_path": "points.ply"},
    )
    for i in range(6):
        (root / "gt").mkdir(exist_ok=True)
        (root / "depth").mkdir(exist_ok=True)
        np.save(root / "gt" / f"{i}.npy", np.ones((30, 40), np.float32))
        np.save(root / "depth" / f"{i}.npy", np.ones((30, 40), np.float32))
    write_ply_points(
        root / "points.ply", np.array([[0.0, 0.0, 0.0], [0.2, 0.1, -0.1]]), np.array([[255, 0, 0]] * 2)
    )
    scene = load_scene(make_cfg(root, center_poses=False, scale_poses=False, test_every=3))
    assert scene.parser == "nerfstudio" and len(scene) == 6
    assert scene.cameras.width.tolist() == [40] * 6 and scene.cameras.height.tolist() == [30] * 6
    assert scene.cameras.fx.tolist() == [35.0] * 6 and scene.cameras.cx.tolist() == [20.0] * 6
    assert scene.image_paths[0] == root / "images" / "frame_000.png"  # pinhole, no downscale: no copy
    assert scene.names()[0] == "images/frame_000.png"
    assert scene.test_indices == [0, 3] and scene.train_indices == [1, 2, 4, 5]
    assert scene.depth_paths[2] == root / "depth" / "2.npy"
    assert scene.extra_paths == {"gt_depth_file_path": [root / "gt" / f"{i}.npy" for i in range(6)]}
    assert scene.points.shape == (2, 3) and scene.point_colors[0].tolist() == [1.0, 0.0, 0.0]
    for i in range(6):  # every camera looks at the origin, so the origin lands on the principal point
        np.testing.assert_allclose(_project_loaded(scene, i, [0, 0, 0]), [20.0, 15.0], atol=1e-4)
        np.testing.assert_allclose(scene.cameras.camtoworlds[i].double().numpy(), poses[i], atol=1e-6)


def test_nerfstudio_per_frame_intrinsics_angle_and_header_size(tmp_path, make_cfg):
    root = tmp_path / "ns"
    write_rgb(root / "a.png", make_image(40, 20))
    write_rgb(root / "b.jpg", make_image(50, 30))
    eye = np.eye(4).tolist()
    meta = {
        "camera_angle_x": 2 * np.arctan(0.5),  # fx = w / 2 / tan(angle / 2) = w
        "frames": [
            {"file_path": "a.png", "transform_matrix": eye},
            {
                "file_path": "b.jpg",
                "transform_matrix": eye,
                "fl_x": 70.0,
                "fl_y": 71.0,
                "cx": 24.0,
                "cy": 14.0,
            },
        ],
        "train_filenames": ["a.png"],
        "test_filenames": ["./b.jpg"],
    }
    (root / "transforms.json").write_text(json.dumps(meta))
    scene = load_scene(make_cfg(root))
    assert scene.cameras.width.tolist() == [40, 50] and scene.cameras.height.tolist() == [20, 30]
    np.testing.assert_allclose(scene.cameras.fx.numpy(), [40.0, 70.0], rtol=1e-6)
    np.testing.assert_allclose(scene.cameras.fy.numpy(), [40.0, 71.0], rtol=1e-6)
    assert scene.cameras.cx.tolist() == [20.0, 24.0] and scene.cameras.cy.tolist() == [10.0, 14.0]
    assert scene.train_indices == [0] and scene.test_indices == [1]


def test_blender(tmp_path, make_cfg):
    root = tmp_path / "lego"
    write_blender(root, n_train=4, n_test=2, size=32, angle=0.69)
    scene = load_scene(make_cfg(root, center_poses=False, scale_poses=False))
    assert scene.parser == "blender" and len(scene) == 6 and scene.test_is_clean
    assert scene.train_indices == [0, 1, 2, 3] and scene.test_indices == [4, 5]
    assert scene.names()[4] == "test/r_0.png"  # extension found on disk
    assert scene.clean_paths[:4] == [None] * 4 and scene.clean_paths[4] == scene.image_paths[4]
    np.testing.assert_allclose(scene.cameras.fx.numpy(), 16.0 / np.tan(0.345), rtol=1e-6)
    for i in range(6):
        np.testing.assert_allclose(_project_loaded(scene, i, [0, 0, 0]), [16.0, 16.0], atol=1e-4)


def test_colmap_text_model(tmp_path, make_cfg):
    root = tmp_path / "cm"
    pts = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [-0.1, 0.2, 0.3]])
    poses = write_colmap(root, n=5, points=pts)
    (root / "clean").mkdir()
    for i in range(5):  # clean pairs may use another extension
        write_rgb(root / "clean" / f"{i:04d}.jpg", make_image(40, 30, 50 + i))
    (root / "depths").mkdir()
    np.save(root / "depths" / "0002.npy", np.ones((30, 40), np.float32))
    scene = load_scene(make_cfg(root, center_poses=False, scale_poses=False))
    assert scene.parser == "colmap" and len(scene) == 5
    assert scene.names() == [f"images/{i:04d}.png" for i in range(5)]  # sorted although listed reversed
    assert scene.cameras.fx.tolist() == [30.0] * 5 and scene.cameras.fy.tolist() == [31.0] * 5
    assert scene.clean_paths[3] == root / "clean" / "0003.jpg"
    assert scene.depth_paths[2] == root / "depths" / "0002.npy" and scene.depth_paths[0] is None
    np.testing.assert_allclose(scene.points.numpy(), pts, atol=1e-6)
    np.testing.assert_allclose(scene.point_colors[0].numpy(), [200 / 255, 100 / 255, 50 / 255], atol=1e-6)
    for i in range(5):
        np.testing.assert_allclose(scene.cameras.camtoworlds[i].double().numpy(), poses[i], atol=1e-5)
        expected = project(poses[i], 30.0, 31.0, 20.0, 15.0, pts[1])
        np.testing.assert_allclose(_project_loaded(scene, i, pts[1]), expected, atol=1e-3)


def test_colmap_sparse_without_subfolder_and_split_lists(tmp_path, make_cfg):
    root = tmp_path / "cm"
    write_colmap(root, n=5, sparse="sparse", model="SIMPLE_PINHOLE", params=[30.0, 20.0, 15.0])
    (root / "train_list.txt").write_text("0000.png\n0001.png\n# comment\n0003.png\n")
    (root / "test_list.txt").write_text("0002.png\n0004.png\n")
    scene = load_scene(make_cfg(root))
    assert scene.parser == "colmap"
    assert scene.train_indices == [0, 1, 3] and scene.test_indices == [2, 4]
    assert scene.cameras.fy.tolist() == [30.0] * 5


@pytest.mark.parametrize(
    ("model", "params", "dist"),
    [
        ("SIMPLE_RADIAL", [30.0, 20.0, 15.0, 0.05], (0.05, 0.0, 0.0, 0.0)),
        ("RADIAL", [30.0, 20.0, 15.0, 0.05, -0.01], (0.05, -0.01, 0.0, 0.0)),
        ("OPENCV", [30.0, 31.0, 20.0, 15.0, 0.05, -0.01, 0.001, 0.002], (0.05, -0.01, 0.001, 0.002)),
    ],
)
def test_colmap_distortion_models_map_to_opencv(tmp_path, model, params, dist):
    from components.data.parsers.colmap import ColmapParser

    root = tmp_path / "cm"
    write_colmap(root, n=2, model=model, params=params)
    frame = ColmapParser.parse(root, None).frames[0]
    assert frame.camera_model == model and frame.distortion == pytest.approx(dist)
    assert (frame.intrinsics.fx, frame.intrinsics.cx, frame.intrinsics.cy) == (30.0, 20.0, 15.0)
