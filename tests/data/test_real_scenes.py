"""The real COLMAP scenes in ../shared (read-only; skipped locally where absent, required in CI)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pycolmap

from components.data.images import image_size, read_image
from components.data.loader import load_scene
from tests.conftest import require_real


def _colmap_by_name(root: Path) -> dict[str, pycolmap.Camera]:
    rec = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    return {f"images/{im.name}": rec.cameras[im.camera_id] for im in rec.images.values()}


def test_statue_per_image_sizes_and_intrinsics(make_cfg):
    statue = require_real("statue")
    cams = _colmap_by_name(statue)
    full = load_scene(make_cfg(statue))
    assert full.parser == "colmap" and len(full) == 23 and len(full.points) > 1000
    heights = set()
    for i, name in enumerate(full.names()):
        cam = cams[name]
        fx, fy, cx, cy = cam.params
        assert (int(full.cameras.width[i]), int(full.cameras.height[i])) == (cam.width, cam.height)
        np.testing.assert_allclose(
            [float(full.cameras.fx[i]), float(full.cameras.cy[i])], [fx, cy], rtol=1e-6
        )
        # pinhole at full size: the originals are used (compared resolved: ../shared may be a link)
        assert full.image_paths[i].resolve() == (statue / name).resolve()
        heights.add(cam.height)
    assert len(heights) >= 5  # the scene really mixes image heights

    small = load_scene(make_cfg(statue, downscale=4))
    for i, name in enumerate(small.names()):
        cam = cams[name]
        w, h = int(small.cameras.width[i]), int(small.cameras.height[i])
        assert (w, h) == (int(np.floor(cam.width / 4 + 0.5)), int(np.floor(cam.height / 4 + 0.5)))
        np.testing.assert_allclose(float(small.cameras.fy[i]), cam.params[1] * h / cam.height, rtol=1e-5)
        np.testing.assert_allclose(float(small.cameras.cx[i]), cam.params[2] * w / cam.width, rtol=1e-5)
    for i in (0, 11, 22):
        assert image_size(small.image_paths[i]) == (int(small.cameras.width[i]), int(small.cameras.height[i]))


def test_beer_undistorted_downscaled_and_cached(make_cfg, tmp_path):
    beer = require_real("beer")
    cams = _colmap_by_name(beer)
    scene = load_scene(make_cfg(beer, downscale=4))
    assert len(scene) == 71 and scene.parser == "colmap"
    assert len(scene.test_indices) == 9 and scene.test_indices[:2] == [0, 8]
    for i in (0, 35, 70):
        cam, name = cams[scene.names()[i]], scene.names()[i]
        f, cx, cy, k = cam.params
        sx, sy = 180 / 720, 320 / 1280
        assert (int(scene.cameras.width[i]), int(scene.cameras.height[i])) == (180, 320)
        # k > 0 here: alpha=0 undistortion zooms in (larger focal) to avoid black borders
        assert k > 0 and float(scene.cameras.fx[i]) > f * sx * (1 + 1e-4)
        assert float(scene.cameras.fy[i]) > f * sy * (1 + 1e-4)
        assert (
            abs(float(scene.cameras.cx[i]) - cx * sx) < 1.0
            and abs(float(scene.cameras.cy[i]) - cy * sy) < 1.0
        )
        p = scene.image_paths[i]
        assert p.is_relative_to(tmp_path / "cache") and read_image(p).shape == (320, 180, 3), name
    mtimes = [p.stat().st_mtime_ns for p in scene.image_paths]
    again = load_scene(make_cfg(beer, downscale=4))
    assert again.image_paths == scene.image_paths
    assert [p.stat().st_mtime_ns for p in again.image_paths] == mtimes
