"""td-synth's seed clouds: the default is as sparse and noisy as SfM on hazy photos; clean on request."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from components.data.cameras import ViewIntrinsics
from components.data.ply import read_ply_points
from components.synth.seed_cloud import (
    SFM_MIN_POINTS,
    SFM_NOISE_FLOOR,
    SFM_NOISE_SLOPE,
    SFM_OUTLIERS,
    default_count,
    pick_pixels,
    place_points,
)
from tests.synth.conftest import make_tiny

GL_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def test_default_counts():
    assert default_count("sfm", 20) == 600  # 30 per train view, whatever the render size
    assert default_count("sfm", 1) == SFM_MIN_POINTS
    assert default_count("clean", 20) == 4000


def test_features_come_from_contrast_not_from_flat_or_sky_pixels():
    rng = np.random.default_rng(0)
    hazy = torch.full((40, 40, 3), 0.6)  # [H, W, 3] flat grey
    hazy[:, 20:] = torch.from_numpy(rng.uniform(0.3, 0.9, size=(40, 20, 1))).float()  # textured right half
    hit = np.ones(40 * 40, bool)
    hit[: 40 * 5] = False  # the top rows are sky
    cols = pick_pixels("sfm", hit, hazy, 300, np.random.default_rng(1)) % 40
    rows = pick_pixels("sfm", hit, hazy, 300, np.random.default_rng(1)) // 40
    assert len(cols) == 300 and rows.min() >= 5
    assert (cols >= 18).mean() > 0.95  # the flat half has no features (its 3x3 border aside)
    uniform = pick_pixels("clean", hit, hazy, 300, np.random.default_rng(1)) % 40
    assert 0.35 < (uniform < 20).mean() < 0.65 and len(np.unique(uniform)) > 30


def test_sfm_depth_noise_and_outliers_follow_the_model(monkeypatch):
    n = 200_000
    rng = np.random.default_rng(3)
    o, d = np.zeros((n, 3)), np.tile([0.0, 0.0, 1.0], (n, 1))
    t = np.full(n, 5.0)
    z = place_points("sfm", o, d, t, 0.0, rng)[:, 2]
    rel = z / 5.0 - 1.0
    outlier = np.abs(rel) > 0.2  # the noise's sigma is 3 % here: beyond 0.2 only outliers remain
    assert abs(outlier.mean() - SFM_OUTLIERS * 0.6) < 0.01  # |factor - 1| > 0.2 for 60 % of U(0.5, 1.5)
    monkeypatch.setattr("components.synth.seed_cloud.SFM_OUTLIERS", 0.0)  # the noise alone
    rel = place_points("sfm", o, d, t, 0.0, np.random.default_rng(4))[:, 2] / 5.0 - 1.0
    assert np.std(rel) == pytest.approx(SFM_NOISE_FLOOR + SFM_NOISE_SLOPE, rel=0.02)  # t = the median
    clean = place_points("clean", o, d, t, 0.003, np.random.default_rng(3))
    assert np.std(clean[:, 2] / 5.0 - 1.0) == pytest.approx(0.003, rel=0.05)


def _best_view_errors(root) -> np.ndarray:
    """Per seed point, its relative depth error in the train view where it agrees best."""
    tf = json.loads((root / "transforms.json").read_text())
    xyz, _ = read_ply_points(root / "points3d.ply")
    K = np.array([[tf["fl_x"], 0, tf["cx"]], [0, tf["fl_y"], tf["cy"]], [0, 0, 1.0]])
    best = np.full(len(xyz), np.inf)
    for fr in tf["frames"]:
        if fr["file_path"] not in tf["train_filenames"]:
            continue
        w2c = np.linalg.inv(np.asarray(fr["transform_matrix"]) @ GL_CV)
        cam = xyz @ w2c[:3, :3].T + w2c[:3, 3]  # [N, 3]
        uv = (cam @ K.T)[:, :2] / np.maximum(cam[:, 2:3], 1e-9)
        depth = np.load(root / fr["gt_depth_file_path"])  # [H, W]
        h, w = depth.shape
        u, v = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        inside = (cam[:, 2] > 0) & (u >= 0) & (v >= 0) & (u < w) & (v < h)
        zt = depth[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)]
        best = np.minimum(best, np.where(inside, np.abs(cam[:, 2] - zt) / zt, np.inf))
    return best


def test_default_cloud_is_sfm_like_and_clean_stays_available(tmp_path):
    common = dict(num_views=9, width=64, height=48, num_points=1500, test_every=0)
    sfm = make_tiny(tmp_path / "sfm", **common)
    clean = make_tiny(tmp_path / "clean", seed_cloud="clean", **common)
    assert (sfm / "images" / "0003.png").read_bytes() == (clean / "images" / "0003.png").read_bytes()
    e_sfm, e_clean = _best_view_errors(sfm), _best_view_errors(clean)
    assert len(e_sfm) == len(e_clean) == 1500
    assert np.median(e_clean) < 0.005 and (e_clean > 0.1).mean() < 0.01
    assert 0.005 < np.median(e_sfm) < 0.05  # measured SfM: 0.5-8 % by depth
    assert 0.02 < (e_sfm > 0.1).mean() < 0.2  # measured SfM: 3-11 % beyond 10 %
    meta = json.loads((sfm / "synth_meta.json").read_text())
    assert meta["settings"]["seed_cloud"] == "sfm"
    auto = make_tiny(tmp_path / "auto", **{**common, "num_points": None})
    assert len(read_ply_points(auto / "points3d.ply")[0]) == default_count("sfm", 9)


def test_tracks_hold_the_views_that_see_each_point(tmp_path):
    """Each point's track holds the view it was drawn from, and a tracked view sees the point's
    surface at the point's depth, while the in-image views left out see something nearer."""
    root = make_tiny(tmp_path / "t", seed_cloud="clean", num_views=9, width=64, height=48, num_points=400)
    meta = json.loads((root / "transforms.json").read_text())
    pairs = np.load(root / meta["point_tracks_file_path"])
    xyz, _ = read_ply_points(root / "points3d.ply")
    assert pairs.shape[1] == 2 and pairs.dtype.kind == "i"
    lengths = np.bincount(pairs[:, 0], minlength=len(xyz))
    assert lengths.min() >= 1 and np.median(lengths) >= 2
    train = {f["file_path"] for f in meta["frames"]} - set(meta["test_filenames"])
    assert {meta["frames"][j]["file_path"] for j in pairs[:, 1]} <= train
    tracked = set(map(tuple, pairs.tolist()))
    agree = {True: [], False: []}
    for j, fr in enumerate(meta["frames"]):
        if fr["file_path"] not in train:
            continue
        c2w = np.asarray(fr["transform_matrix"], np.float64) @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV axes
        pc = (xyz - c2w[:3, 3]) @ c2w[:3, :3]  # [M, 3]
        u = meta["fl_x"] * pc[:, 0] / pc[:, 2] + meta["cx"]
        v = meta["fl_y"] * pc[:, 1] / pc[:, 2] + meta["cy"]
        inside = (pc[:, 2] > 0) & (u >= 0) & (u < meta["w"]) & (v >= 0) & (v < meta["h"])
        z_true = np.load(root / fr["gt_depth_file_path"])
        for k in np.flatnonzero(inside):
            zt = z_true[int(v[k]), int(u[k])]
            agree[(k, j) in tracked].append(abs(pc[k, 2] / zt - 1) < 0.05)
    assert np.mean(agree[True]) > 0.9  # the rest: edge pixels, whose centre sees the other surface
    assert len(agree[False]) > 50 and np.mean(agree[False]) < 0.2  # hidden behind a nearer surface


def test_sfm_tracks_are_short_like_colmaps():
    """``sfm`` tracks keep the finding view, then a share of the seeing views near its ray only:
    a subset of the complete tracks, median length far below theirs (COLMAP: 3 of 8-11)."""
    from components.synth.generate import camera_poses
    from components.synth.layouts import make_layout
    from components.synth.render import render_clean
    from components.synth.seed_cloud import SFM_TRACK_ANGLE, SFM_TRACK_KEEP, seed_tracks

    layout = make_layout("courtyard", 3)
    _, poses = camera_poses(layout, "auto", 16)
    K = ViewIntrinsics.from_fov(64, 48, 60.0)
    view = render_clean(layout, poses[5], K, 1)
    pix = np.flatnonzero(view.hit.numpy())[::7][:300]
    surface = view.origins.numpy()[pix] + view.t_end.numpy()[pix, None] * view.dirs.numpy()[pix]  # [M, 3]
    views = list(range(16))
    source = np.full(len(surface), 5)
    complete = seed_tracks(layout.geometry, surface, poses, K, views)
    short = seed_tracks(layout.geometry, surface, poses, K, views, "sfm", source, np.random.default_rng(0))
    full, kept = set(map(tuple, complete.tolist())), set(map(tuple, short.tolist()))
    assert kept <= full
    assert {(k, 5) for k in range(len(surface)) if (k, 5) in full} <= kept  # the finding view stays
    ray = lambda k, j: (surface[k] - poses[j][:3, 3]) / np.linalg.norm(surface[k] - poses[j][:3, 3])  # noqa: E731
    angle = lambda k, j: np.degrees(np.arccos(np.clip(ray(k, j) @ ray(k, 5), -1, 1)))  # noqa: E731
    near = [(k, j) for k, j in full if j != 5 and angle(k, j) < SFM_TRACK_ANGLE]
    assert all(angle(k, j) < SFM_TRACK_ANGLE + 1e-3 for k, j in kept if j != 5)
    assert len(near) > 200 and abs(np.mean([p in kept for p in near]) - SFM_TRACK_KEEP) < 0.08
    length = lambda p: np.median(np.bincount(p[:, 0], minlength=len(surface)))  # noqa: E731
    assert length(short) < 0.6 * length(complete)
    with pytest.raises(ValueError, match="source view"):
        seed_tracks(layout.geometry, surface, poses, K, views, "sfm")
