"""The shared loader: downscale + cache, undistortion, normalisation, splits, parser choice."""

from __future__ import annotations

import json
import os

import numpy as np
import pycolmap
import pytest
import torch

from components.data.dataset import ImageSet
from components.data.images import read_depth, read_image
from components.data.loader import load_scene
from components.data.ply import write_ply_points

from .synth import make_image, project, write_colmap, write_nerfstudio, write_rgb


def _tree(root):
    return sorted((str(p.relative_to(root)), p.stat().st_mtime_ns) for p in root.rglob("*"))


def test_downscale_resizes_scales_intrinsics_and_reuses_cache(tmp_path, make_cfg):
    root = tmp_path / "ns"
    write_nerfstudio(root, n=3, w=41, h=30, f=35.0, frame_extra=lambda i: {"depth_file_path": f"d{i}.npy"})
    for i in range(3):
        np.save(root / f"d{i}.npy", np.arange(30 * 41, dtype=np.float32).reshape(30, 41))
    before = _tree(root)
    scene = load_scene(make_cfg(root, downscale=4))
    # 41 / 4 = 10.25 -> 10, 30 / 4 = 7.5 -> 8 (halves round up); K scaled by new / old exactly
    assert scene.cameras.width.tolist() == [10] * 3 and scene.cameras.height.tolist() == [8] * 3
    np.testing.assert_allclose(scene.cameras.fx.numpy(), 35.0 * 10 / 41, rtol=1e-6)
    np.testing.assert_allclose(scene.cameras.fy.numpy(), 35.0 * 8 / 30, rtol=1e-6)
    np.testing.assert_allclose(scene.cameras.cx.numpy(), 20.5 * 10 / 41, rtol=1e-6)
    np.testing.assert_allclose(scene.cameras.cy.numpy(), 15.0 * 8 / 30, rtol=1e-6)
    p = scene.image_paths[1]
    assert p.is_relative_to(tmp_path / "cache") and read_image(p).shape == (8, 10, 3)
    depth = read_depth(scene.depth_paths[1])
    assert depth.shape == (8, 10) and np.isin(depth, np.arange(30 * 41)).all()  # nearest: no new values
    assert _tree(root) == before  # the dataset folder is never written

    mtimes = [q.stat().st_mtime_ns for q in scene.image_paths]
    again = load_scene(make_cfg(root, downscale=4))
    assert again.image_paths == scene.image_paths
    assert [q.stat().st_mtime_ns for q in again.image_paths] == mtimes  # reused, not rewritten

    half = load_scene(make_cfg(root, downscale=2))
    assert half.image_paths[0] != scene.image_paths[0] and half.cameras.width[0] == 21
    os.utime(root / "images" / "frame_000.png", ns=(1, 1))  # an edited source gets a fresh copy
    assert load_scene(make_cfg(root, downscale=4)).image_paths[0] != scene.image_paths[0]


def test_cache_dir_from_environment(tmp_path, make_cfg, monkeypatch):
    root = tmp_path / "ns"
    write_nerfstudio(root, n=2)
    monkeypatch.setenv("TRIDEHAZE_CACHE", str(tmp_path / "envcache"))
    scene = load_scene(make_cfg(root, downscale=2, cache_dir=None))
    assert scene.image_paths[0].is_relative_to(tmp_path / "envcache")


def test_undistortion_matches_colmap_projection(tmp_path, make_cfg):
    """Each undistorted pixel holds the original pixel COLMAP's own model says it came from."""
    w, h = 64, 48
    params = [40.0, 41.0, 32.0, 24.0, -0.15, 0.03, 0.002, -0.001]
    root = tmp_path / "cm"
    write_colmap(root, n=2, w=w, h=h, model="OPENCV", params=params, write_images=False)
    yy, xx = np.mgrid[0:h, 0:w]
    coded = np.stack([xx * 4, yy * 4, np.zeros_like(xx)], axis=-1).astype(np.uint8)  # colour encodes (u, v)
    for i in range(2):
        write_rgb(root / "images" / f"{i:04d}.png", coded)
    scene = load_scene(make_cfg(root))
    fx, fy, cx, cy = (float(getattr(scene.cameras, k)[0]) for k in ("fx", "fy", "cx", "cy"))
    assert fx != params[0]  # a new pinhole K was chosen
    und = read_image(scene.image_paths[0]).astype(np.float64)
    cam = pycolmap.Camera.create_from_model_name(1, "OPENCV", 0.0, w, h)
    cam.params = params
    for v in range(4, h - 4, 7):
        for u in range(4, w - 4, 9):
            ray = np.array([[(u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, 1.0]])
            src = cam.img_from_cam(ray)[0] - 0.5  # source pixel index (centres at +0.5 in COLMAP)
            np.testing.assert_allclose(und[v, u, :2] / 4, src, atol=0.6)
    # alpha = 0 (no black borders): every border pixel of the output samples inside the source image
    border = [(u, v) for u in range(w) for v in (0, h - 1)] + [(u, v) for v in range(h) for u in (0, w - 1)]
    rays = np.array([[(u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, 1.0] for u, v in border])
    src = cam.img_from_cam(rays)  # [B, 2], pixel centres at +0.5
    assert src.min() > -0.5 and (src[:, 0] < w + 0.5).all() and (src[:, 1] < h + 0.5).all()


def test_normalisation_centres_scales_and_keeps_projections(tmp_path, make_cfg):
    root = tmp_path / "ns"
    write_nerfstudio(root, n=5, extra_global={"ply_file_path": "p.ply"})
    data = json.loads((root / "transforms.json").read_text())
    for fr in data["frames"]:  # move the rig away from the origin and make it bigger
        m = np.array(fr["transform_matrix"])
        m[:3, 3] = m[:3, 3] * 3.0 + [10.0, -5.0, 2.0]
        fr["transform_matrix"] = m.tolist()
    (root / "transforms.json").write_text(json.dumps(data))
    pts = np.array([[10.2, -5.1, 2.3], [9.5, -4.0, 2.0]])
    write_ply_points(root / "p.ply", pts)
    raw = load_scene(make_cfg(root, center_poses=False, scale_poses=False))
    norm = load_scene(make_cfg(root))
    centers = norm.cameras.centers.double()
    np.testing.assert_allclose(centers.mean(0).numpy(), 0.0, atol=1e-5)
    assert float(centers.norm(dim=-1).max()) == pytest.approx(1.0, abs=1e-5)
    t = norm.transform
    np.testing.assert_allclose(t.apply_points(torch.from_numpy(pts)).numpy(), norm.points.numpy(), atol=1e-5)
    for i in range(5):
        args = [float(getattr(raw.cameras, k)[i]) for k in ("fx", "fy", "cx", "cy")]
        before = project(raw.cameras.camtoworlds[i].double().numpy(), *args, raw.points[0].double().numpy())
        after = project(norm.cameras.camtoworlds[i].double().numpy(), *args, norm.points[0].double().numpy())
        np.testing.assert_allclose(after, before, atol=1e-3)


def test_normalisation_single_camera_keeps_scale(tmp_path, make_cfg):
    root = tmp_path / "ns"
    write_nerfstudio(root, n=1)
    scene = load_scene(make_cfg(root))
    assert scene.transform.scale == 1.0 and scene.train_indices == [0] and scene.test_indices == []


@pytest.mark.parametrize(("test_every", "test"), [(8, [0, 8, 16]), (5, [0, 5, 10, 15]), (0, [])])
def test_every_nth_split(tmp_path, make_cfg, test_every, test):
    root = tmp_path / "ns"
    write_nerfstudio(root, n=20, w=8, h=6, f=5.0)
    scene = load_scene(make_cfg(root, test_every=test_every))
    assert scene.test_indices == test
    assert scene.train_indices == [i for i in range(20) if i not in test]


def test_explicit_split_one_list_gives_complement(tmp_path, make_cfg):
    root = tmp_path / "ns"
    write_nerfstudio(root, n=4, extra_global={"test_filenames": ["images/frame_001.png", "frame_003.png"]})
    scene = load_scene(make_cfg(root))
    assert scene.test_indices == [1, 3] and scene.train_indices == [0, 2]


def test_auto_detection_priority_and_explicit_parser(tmp_path, make_cfg):
    root = tmp_path / "both"
    write_colmap(root, n=3)
    write_nerfstudio(root, n=2)
    assert load_scene(make_cfg(root)).parser == "nerfstudio"
    scene = load_scene(make_cfg(root, parser="colmap"))
    assert scene.parser == "colmap" and len(scene) == 3


def test_image_set_lazy_float_and_clean(tmp_path, make_cfg):
    root = tmp_path / "ns"
    write_nerfstudio(root, n=2, clean=True)
    scene = load_scene(make_cfg(root))
    images = ImageSet.from_scene(scene)
    img = images[1]
    assert img.dtype == torch.float32 and img.shape == (30, 40, 3) and 0.0 <= img.min() <= img.max() <= 1.0
    np.testing.assert_allclose(img.numpy() * 255, make_image(40, 30, 1), atol=1e-3)
    (root / "images" / "frame_001.png").unlink()
    assert torch.equal(images[1], img)  # served from memory once loaded
    clean = ImageSet.from_scene(scene, "clean")
    np.testing.assert_allclose(clean[0].numpy() * 255, make_image(40, 30, 100), atol=1e-3)
