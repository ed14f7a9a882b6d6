"""td-synth scene output: what the trainer's loader sees, exactness of the stored maps, determinism."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from components.data.config import DataConfig
from components.data.images import read_image
from components.data.loader import load_scene
from components.synth.generate import GENERATOR_VERSION, mismatch
from tests.synth.conftest import TINY, make_tiny
from tridehaze_plugin.errors import UserError


def _load(root: Path, tmp_path: Path):
    return load_scene(DataConfig(data=root, cache_dir=tmp_path / "cache"))


def test_loader_reads_it(tiny_dataset, tmp_path):
    scene = _load(tiny_dataset, tmp_path)
    assert scene.parser == "nerfstudio"
    assert len(scene) == 9
    assert scene.test_indices == [0, 8] and scene.train_indices == list(range(1, 8))  # every 8th view
    assert all(p is not None and p.is_file() for p in scene.clean_paths)
    # ground truth goes to extra_paths, never to depth priors
    assert all(p is None for p in scene.depth_paths)
    assert set(scene.extra_paths) == {
        "gt_depth_file_path",
        "gt_transmittance_file_path",
        "gt_scattering_file_path",
    }
    assert scene.points is not None and 100 < len(scene.points) <= 300
    assert int(scene.cameras.width[0]) == 40 and int(scene.cameras.height[0]) == 30
    meta = json.loads((tiny_dataset / "synth_meta.json").read_text())
    assert 0 < meta["mean_transmittance"] < 1 and meta["medium"]["preset"] == "patchy"
    # the folder says which generator wrote it, so a set is not reused across generator changes
    assert meta["generator_version"] == GENERATOR_VERSION and mismatch(tiny_dataset, TINY) is None
    assert "num_views" in mismatch(tiny_dataset, replace(TINY, num_views=10))


def test_stored_maps_obey_the_image_formation(tiny_dataset):
    meta = json.loads((tiny_dataset / "transforms.json").read_text())
    for fr in meta["frames"]:
        hazy = read_image(tiny_dataset / fr["file_path"]).astype(np.float64) / 255
        clean = read_image(tiny_dataset / fr["clean_file_path"]).astype(np.float64) / 255
        T = np.load(tiny_dataset / fr["gt_transmittance_file_path"])
        S = np.load(tiny_dataset / fr["gt_scattering_file_path"])
        depth = np.load(tiny_dataset / fr["gt_depth_file_path"])
        assert T.dtype == np.float32 and T.shape == (30, 40) and depth.shape == (30, 40)
        assert (T > 0).all() and (T <= 1).all() and (depth > 0).all()
        # 8-bit rounding of clean and hazy: at most 1/255 each
        assert np.abs(clean * T[..., None] + S - hazy).max() <= 1.0 / 255 + 1e-6


def test_seed_points_lie_on_visible_surfaces(tiny_dataset, tmp_path):
    """Seed points project into a view at (about) the stored true depth."""
    from components.data.ply import read_ply_points

    meta = json.loads((tiny_dataset / "transforms.json").read_text())
    pts, cols = read_ply_points(tiny_dataset / meta["ply_file_path"])
    assert cols is not None and len(pts) == len(cols)
    fr = meta["frames"][1]
    c2w = np.asarray(fr["transform_matrix"]) @ np.diag([1.0, -1, -1, 1])  # OpenGL -> OpenCV
    depth = np.load(tiny_dataset / fr["gt_depth_file_path"])
    cam = (pts - c2w[:3, 3]) @ c2w[:3, :3]  # [M, 3] camera coordinates
    front = cam[:, 2] > 0.1
    u = meta["fl_x"] * cam[front, 0] / cam[front, 2] + meta["cx"]
    v = meta["fl_y"] * cam[front, 1] / cam[front, 2] + meta["cy"]
    inside = (u >= 0) & (u < 40) & (v >= 0) & (v < 30)
    z = cam[front, 2][inside]
    zd = depth[v[inside].astype(int), u[inside].astype(int)]
    visible = np.abs(z - zd) < 0.05 * zd  # points of this view (others may be occluded)
    assert visible.mean() > 0.3


def test_no_haze_gives_hazy_equal_to_clean(tmp_path):
    root = make_tiny(tmp_path / "clear", haze="none", num_views=3, test_every=0)
    meta = json.loads((root / "transforms.json").read_text())
    assert meta["test_filenames"] == []
    for fr in meta["frames"]:
        assert (root / fr["file_path"]).read_bytes() == (root / fr["clean_file_path"]).read_bytes()
        assert (np.load(root / fr["gt_transmittance_file_path"]) == 1).all()
        assert (np.load(root / fr["gt_scattering_file_path"]) == 0).all()


def test_same_seed_same_bytes_other_seed_differs(tmp_path):
    a = make_tiny(tmp_path / "a", num_views=2, layout="street", haze="height")
    b = make_tiny(tmp_path / "b", num_views=2, layout="street", haze="height")
    c = make_tiny(tmp_path / "c", num_views=2, layout="street", haze="height", seed=1)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file() and p.name != "synth_meta.json")
    assert (
        len(files) == 1 + 1 + 1 + 2 * 5 + 1
    )  # transforms, ply, tracks, 5 files per view, the output manifest
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    assert (a / "images/0001.png").read_bytes() != (c / "images/0001.png").read_bytes()


def test_existing_output_is_protected(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(UserError, match="not empty"):
        make_tiny(out, num_views=2)
    assert (out / "keep.txt").read_text() == "mine"
    with pytest.raises(UserError, match="--overwrite refused: td-synth did not write this folder"):
        make_tiny(out, num_views=2, overwrite=True)  # --overwrite never deletes a folder we did not write
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    (out / "keep.txt").unlink()
    make_tiny(out, num_views=2)
    first = (out / "transforms.json").read_bytes()
    make_tiny(out, num_views=3, overwrite=True)  # our own dataset: replaced
    assert (out / "transforms.json").read_bytes() != first
    (out / "images" / "notes.txt").write_text("mine")  # a file we did not write, deep inside
    with pytest.raises(UserError, match=r"holds 1 file\(s\) td-synth did not write \(images/notes.txt\)"):
        make_tiny(out, num_views=2, overwrite=True)
    assert (out / "images" / "notes.txt").read_text() == "mine"
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no temporary folders left behind


def test_output_is_readable_like_any_new_file(tiny_dataset):
    """Staging uses private temp files/folders; the finished dataset follows the umask instead."""
    import os

    mask = os.umask(0)
    os.umask(mask)
    assert tiny_dataset.stat().st_mode & 0o777 == 0o777 & ~mask
    for p in (tiny_dataset / "transforms.json", tiny_dataset / "images" / "0000.png"):
        assert p.stat().st_mode & 0o777 == 0o666 & ~mask


def test_seed_colors_clean_or_hazy(tmp_path):
    from components.data.ply import read_ply_points

    a = make_tiny(tmp_path / "a", num_views=2, haze="dense", test_every=0, point_colors="clean")
    b = make_tiny(tmp_path / "b", num_views=2, haze="dense", test_every=0)  # default: hazy
    xa, ca = read_ply_points(a / "points3d.ply")
    xb, cb = read_ply_points(b / "points3d.ply")
    assert np.array_equal(xa, xb) and not np.array_equal(ca, cb)
