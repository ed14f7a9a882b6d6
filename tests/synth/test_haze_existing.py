"""td-synth haze on a tiny clean dataset with depth maps (and with depth rendered from a tiny run)."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from components.data.config import DataConfig
from components.data.images import read_image
from components.data.loader import load_scene
from components.synth.haze_existing import HazeConfig, WaveField, haze_dataset
from pipelines.evaluation.run_depth import run_depths
from tests.synth.conftest import make_tiny
from tridehaze_plugin.errors import ConfigError, UserError


@pytest.fixture(scope="module")
def clean_dataset(tmp_path_factory) -> Path:
    """A clear synthetic scene whose true depth is offered as the dataset's depth maps."""
    root = make_tiny(tmp_path_factory.mktemp("haze") / "clean", haze="none", num_views=6, test_every=3)
    meta = json.loads((root / "transforms.json").read_text())
    for fr in meta["frames"]:
        fr["depth_file_path"] = fr.pop("gt_depth_file_path")
        for k in ("clean_file_path", "gt_transmittance_file_path", "gt_scattering_file_path"):
            fr.pop(k)
    (root / "transforms.json").write_text(json.dumps(meta))
    return root


def _cfg(data: Path, out: Path, **kw) -> HazeConfig:
    return HazeConfig(data=data, output_dir=out, cache_dir=out.parent / "cache", **kw)


def _frames(root: Path) -> list[dict]:
    return json.loads((root / "transforms.json").read_text())["frames"]


def _ray_distance(fr: dict, depth: np.ndarray) -> np.ndarray:
    H, W = depth.shape
    xs, ys = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    norm = np.sqrt(((xs - fr["cx"]) / fr["fl_x"]) ** 2 + ((ys - fr["cy"]) / fr["fl_y"]) ** 2 + 1)
    return depth * norm


def test_median_target_and_clean_pairs(clean_dataset, tmp_path):
    out = tmp_path / "foggy"
    meta = haze_dataset(_cfg(clean_dataset, out, median_transmittance=0.3, airlight=(0.9, 0.85, 0.8)))
    T_all, beta, A = [], meta["beta"], np.array([0.9, 0.85, 0.8])
    src = {fr["file_path"].split("/")[-1]: fr for fr in _frames(clean_dataset)}
    for fr in _frames(out):
        T = np.load(out / fr["gt_transmittance_file_path"]).astype(np.float64)
        depth = np.load(out / fr["gt_depth_file_path"])
        clean = read_image(out / fr["clean_file_path"])
        # the clean copy is the source image, pixel for pixel
        assert np.array_equal(clean, read_image(clean_dataset / src[Path(fr["file_path"]).name]["file_path"]))
        # homogeneous fog along the ray: T = exp(-beta d), d the distance to the surface point
        np.testing.assert_allclose(T, np.exp(-beta * _ray_distance(fr, depth)), rtol=1e-5, atol=1e-7)
        hazy = read_image(out / fr["file_path"]).astype(np.float64) / 255
        J = clean.astype(np.float64) / 255
        assert np.abs(J * T[..., None] + A * (1 - T[..., None]) - hazy).max() <= 0.5 / 255 + 1e-6
        T_all.append(T.ravel())
    assert abs(float(np.median(np.concatenate(T_all))) - 0.3) < 0.01
    assert abs(meta["median_transmittance"] - 0.3) < 0.01


def test_output_loads_with_gt_as_extras(clean_dataset, tmp_path):
    out = tmp_path / "foggy"
    haze_dataset(_cfg(clean_dataset, out, beta=0.05, heterogeneous=0.6))
    scene = load_scene(DataConfig(data=out, cache_dir=tmp_path / "cache"))
    src = load_scene(DataConfig(data=clean_dataset, cache_dir=tmp_path / "cache"))
    assert len(scene) == 6 and scene.test_indices == src.test_indices == [0, 3]
    assert all(p is None for p in scene.depth_paths)  # the true depth is never a prior
    assert set(scene.extra_paths) == {"gt_depth_file_path", "gt_transmittance_file_path"}
    assert all(p is not None for p in scene.clean_paths)
    assert scene.points is not None and len(scene.points) == len(src.points)
    assert np.allclose(scene.cameras.camtoworlds.numpy(), src.cameras.camtoworlds.numpy(), atol=1e-5)
    # the tracks come along, to the same views by name
    assert len(src.point_tracks.point) > 0

    def pairs(s):
        return sorted(
            (int(p), Path(s.names()[v]).stem)
            for p, v in zip(s.point_tracks.point, s.point_tracks.view, strict=True)
        )

    assert pairs(scene) == pairs(src)


def test_wave_field_optical_depth_is_the_exact_integral():
    f = WaveField.make(0.7, wavelength=3.0, seed=2)
    rng = np.random.default_rng(0)
    o = rng.normal(size=3)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dist = rng.uniform(0.1, 20, 50)
    s = (np.arange(20000) + 0.5) / 20000  # fine midpoint rule
    pts = o + (dist[:, None, None] * s[None, :, None]) * d[:, None, :]
    numeric = f(pts).mean(axis=1) * dist
    np.testing.assert_allclose(f.optical_depth(o, d, dist), numeric, rtol=1e-6)
    assert (f(rng.normal(size=(1000, 3)) * 10) > 0).all()


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"beta": -0.1}, "--beta"),
        ({"median_transmittance": 1.0}, "--median-transmittance"),
        ({"median_transmittance": 0.0}, "--median-transmittance"),
        ({"beta": 0.1, "median_transmittance": 0.5}, "either"),
        ({"heterogeneous": 1.0}, "--heterogeneous"),
    ],
)
def test_bad_options(clean_dataset, tmp_path, kw, match):
    with pytest.raises(UserError, match=match):
        haze_dataset(_cfg(clean_dataset, tmp_path / "o", **kw))
    assert not (tmp_path / "o").exists()


def test_dataset_without_depth_needs_a_run(tiny_dataset, tmp_path):
    with pytest.raises(UserError, match="--depth-from-run"):
        haze_dataset(_cfg(tiny_dataset, tmp_path / "o"))
    assert not (tmp_path / "o").exists()


def test_depth_from_a_run_is_in_dataset_units(clean_dataset, tmp_path):
    """Depth rendered by a (tiny) trained run, converted from the run's normalised world back to metres."""
    import torch

    from pipelines.engine.run_loader import load_run
    from pipelines.engine.trainer import Trainer
    from tridehaze_plugin.cli.train import parse_args

    args = (
        f"vanilla-gs --data {clean_dataset} --output-dir {tmp_path / 'runs'} --max-steps 30 --timestamp run"
    )
    args += (
        f" --pipeline.rasterizer.backend torch --no-eval-at-end --threads 1 --cache-dir {tmp_path / 'cache'}"
    )
    cfg = parse_args(args.split())
    cfg = replace(cfg, steps_per_log=1000)
    Trainer(cfg).train()
    config = next((tmp_path / "runs").rglob("config.yml"))
    out = tmp_path / "foggy"
    meta = haze_dataset(_cfg(clean_dataset, out, depth_from_run=config, beta=0.02, min_alpha=0.0), run_depths)
    assert meta["depth_source"].startswith("run")
    run = load_run(config)
    scale = run.datamanager.scene.transform.scale
    assert not math.isclose(scale, 1.0, rel_tol=0.05)  # the conversion matters here
    with torch.no_grad():
        res = run.pipeline.render(run.datamanager.camera(1))
    expected = res["depth"][..., 0].numpy() / scale
    got = np.load(out / _frames(out)[1]["gt_depth_file_path"])
    ok = expected > 0
    np.testing.assert_allclose(got[ok], expected[ok], rtol=1e-3)


def test_a_depth_far_beyond_the_seed_points_is_flagged():
    """Statue's depth run put its background at 5-15x the SfM points' depth (session 24): such
    pixels are counted, views that see too few points are skipped."""
    import torch

    from components.data.cameras import Cameras
    from components.synth.haze_existing import DEPTH_BEYOND_FACTOR, depth_beyond_points

    H, W = 8, 10
    cams = Cameras(
        torch.eye(4)[None].repeat(2, 1, 1), torch.full((2,), 10.0), torch.full((2,), 10.0),
        torch.full((2,), W / 2), torch.full((2,), H / 2), torch.full((2,), W), torch.full((2,), H),
    )  # fmt: skip
    rng = np.random.default_rng(0)
    points = torch.from_numpy(
        np.stack([rng.uniform(-0.3, 0.3, 50), rng.uniform(-0.3, 0.3, 50), rng.uniform(1.0, 2.0, 50)], -1)
    )
    near = np.full((H, W), 1.5)
    far = near.copy()
    far[:, : W // 2] = 3.0 * DEPTH_BEYOND_FACTOR  # half the view far behind every point
    assert depth_beyond_points(cams, points, [near, far]) == pytest.approx(0.25)
    assert depth_beyond_points(cams, points[:5], [near, far]) is None  # too few points to judge
    behind = points * torch.tensor(
        [1.0, 1.0, -1.0], dtype=points.dtype
    )  # points behind the cameras are not seen
    assert depth_beyond_points(cams, behind, [near, far]) is None


def test_the_depth_check_is_recorded(clean_dataset, tmp_path):
    meta = haze_dataset(_cfg(clean_dataset, tmp_path / "foggy", beta=0.05))
    assert meta["depth_beyond_points"]["share"] == pytest.approx(0.0, abs=0.05)


def test_the_depth_is_clamped_at_the_points_it_can_be_seen_with():
    """--max-depth-factor: a depth beyond the factor times the farthest seen point is moved to it;
    a view seeing too few points keeps its depth."""
    import torch

    from components.data.cameras import Cameras
    from components.synth.haze_existing import clamp_to_points, farthest_seen_points

    H, W = 8, 10
    cams = Cameras(
        torch.eye(4)[None].repeat(2, 1, 1), torch.full((2,), 10.0), torch.full((2,), 10.0),
        torch.full((2,), W / 2), torch.full((2,), H / 2), torch.full((2,), W), torch.full((2,), H),
    )  # fmt: skip
    points = torch.zeros(40, 3, dtype=torch.float64)
    points[:, 2] = torch.linspace(1.0, 2.0, 40, dtype=torch.float64)  # on the optical axis, z 1 .. 2
    depth = np.full((H, W), 1.5)
    depth[:, : W // 2] = 20.0  # an invented background
    far = farthest_seen_points(cams, points, [depth, depth])
    assert far[0] == pytest.approx(np.quantile(np.linspace(1.0, 2.0, 40), 0.98))
    out, moved = clamp_to_points(cams, points, [depth, depth], 1.5)
    assert moved == pytest.approx(0.5)
    assert out[0][:, : W // 2] == pytest.approx(1.5 * far[0]) and (out[0][:, W // 2 :] == 1.5).all()
    out, moved = clamp_to_points(cams, points[:5], [depth], 1.5)  # too few points: unchanged
    assert moved == 0.0 and (out[0] == depth).all()


def test_a_clamped_set_records_it_and_a_bad_factor_is_refused(clean_dataset, tmp_path):
    meta = haze_dataset(_cfg(clean_dataset, tmp_path / "foggy", beta=0.05, max_depth_factor=1.5))
    assert meta["depth_clamp"]["factor"] == 1.5 and 0.0 <= meta["depth_clamp"]["share"] < 0.5
    assert meta["depth_beyond_points"]["share"] == 0.0  # nothing is left beyond 2x after a 1.5x clamp
    for bad in (0.5, float("nan")):
        with pytest.raises(ConfigError, match="--max-depth-factor"):
            _cfg(clean_dataset, tmp_path / "x", beta=0.05, max_depth_factor=bad).check()


def test_clamping_a_set_without_seed_points_is_a_clear_error(clean_dataset, tmp_path):
    import shutil

    bare = tmp_path / "bare"
    shutil.copytree(clean_dataset, bare)
    meta = json.loads((bare / "transforms.json").read_text())
    meta.pop("ply_file_path")
    (bare / "transforms.json").write_text(json.dumps(meta))
    (bare / "points3d.ply").unlink()
    with pytest.raises(UserError, match="has none") as err:
        haze_dataset(_cfg(bare, tmp_path / "foggy", beta=0.05, max_depth_factor=1.5))
    assert "leave --max-depth-factor out" in str(err.value.fix)
    assert not (tmp_path / "foggy" / "transforms.json").exists()


def test_the_haze_ball_chord_is_the_ray_inside_it():
    """Against a dense sampling of the ray: the entry point and the length inside the ball, for
    cameras inside and outside it, rays that miss it and surfaces in front of, inside and behind it."""
    from components.synth.haze_ball import HazeBall

    ball = HazeBall(np.array([0.5, -0.2, 3.0]), 1.3)
    rng = np.random.default_rng(1)
    s = (np.arange(200000) + 0.5) / 200000
    for o in (np.array([0.0, 0.0, 0.0]), np.array([0.4, 0.1, 2.5])):  # outside, inside
        d = rng.normal(size=(40, 3)) + np.array([0.5, -0.2, 3.0]) - o
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        dist = rng.uniform(0.2, 8.0, 40)
        enter, length = ball.chord(o, d, dist)
        inside = ball.contains(o + (dist[:, None, None] * s[None, :, None]) * d[:, None, :])  # [40, S]
        np.testing.assert_allclose(length, inside.mean(axis=1) * dist, atol=1e-4)
        first = np.where(inside.any(axis=1), inside.argmax(axis=1) / len(s), 1.0) * dist
        np.testing.assert_allclose(enter[length > 1e-3], first[length > 1e-3], atol=1e-4)
        assert (length >= 0).all() and (enter <= dist).all()
    enter, length = ball.chord(np.zeros(3), np.array([[0.0, 1.0, 0.0]]), np.array([10.0]))  # misses
    assert length[0] == 0.0


def test_the_haze_ball_is_one_medium_for_every_view(clean_dataset, tmp_path):
    """--haze-ball-factor: the written T is exp(-beta * the field integrated over the ray's part
    inside the ball), each view's from its own camera (one 3D medium), and the set records it."""
    from components.synth.haze_ball import HazeBall

    out = tmp_path / "foggy"
    cfg = _cfg(clean_dataset, out, median_transmittance=0.6, haze_ball_factor=0.3, heterogeneous=0.5)
    meta = haze_dataset(cfg)
    ball_meta = meta["haze_ball"]
    pts = np.asarray(load_scene(DataConfig(data=clean_dataset, center_poses=False, scale_poses=False)).points)
    ball = HazeBall.around(pts, 0.3)
    np.testing.assert_allclose(ball_meta["centre"], ball.centre)
    assert ball_meta["factor"] == 0.3 and ball_meta["radius"] == pytest.approx(ball.radius)
    assert ball_meta["cameras_inside"] == 0  # every ray enters the haze on its way, not at the camera
    Ts = [np.load(out / fr["gt_transmittance_file_path"]) for fr in _frames(out)]
    assert ball_meta["clear_share"] == pytest.approx(np.mean(np.concatenate([t.ravel() for t in Ts]) == 1.0))
    hf = meta["heterogeneous_field"]
    field = WaveField(hf["h"], np.asarray(hf["waves"]), np.asarray(hf["phases"]))
    s = (np.arange(4000) + 0.5) / 4000
    for fr in _frames(out)[:3]:
        depth = np.load(out / fr["gt_depth_file_path"])
        T = np.load(out / fr["gt_transmittance_file_path"])
        c2w = np.asarray(fr["transform_matrix"], np.float64)
        H, W = depth.shape
        ys, xs = np.array([H // 4, H // 2, 3 * H // 4]), np.array([W // 3, W // 2, 2 * W // 3])
        cam = np.stack(
            [(xs + 0.5 - fr["cx"]) / fr["fl_x"], -(ys + 0.5 - fr["cy"]) / fr["fl_y"], -np.ones(3)], -1
        )
        dist = _ray_distance(fr, depth)[ys, xs]
        d = cam / np.linalg.norm(cam, axis=1, keepdims=True) @ c2w[:3, :3].T
        pts_ray = c2w[:3, 3] + (dist[:, None, None] * s[None, :, None]) * d[:, None, :]  # [3, S, 3]
        tau = (field(pts_ray) * ball.contains(pts_ray)).mean(axis=1) * dist
        np.testing.assert_allclose(T[ys, xs], np.exp(-meta["beta"] * tau), atol=2e-3)


def test_a_bad_haze_ball_is_refused(clean_dataset, tmp_path):
    for kw in ({"haze_ball_factor": 0.0}, {"haze_ball_factor": float("inf")},
               {"haze_ball_factor": 1.5, "max_depth_factor": 1.5}):  # fmt: skip
        with pytest.raises(ConfigError, match="--haze-ball-factor"):
            _cfg(clean_dataset, tmp_path / "x", beta=0.05, **kw).check()
    with pytest.raises(UserError, match="half of the pixels see no haze"):
        haze_dataset(_cfg(clean_dataset, tmp_path / "tiny", median_transmittance=0.5, haze_ball_factor=1e-4))
    assert not (tmp_path / "tiny" / "transforms.json").exists()
