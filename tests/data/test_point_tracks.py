"""Seed-point tracks (which views observed each point): parsed, re-indexed by the loader, and
used by the sfm depth prior instead of reprojecting every point into every view."""

from __future__ import annotations

import json

import numpy as np
import pycolmap
import pytest
import torch

from components.data.cameras import Cameras
from components.data.loader import load_scene, loaded_tracks
from components.data.ply import write_ply_points
from components.data.scene import PointTracks
from pipelines.tridehaze.priors import sfm_view_depth
from tests.conftest import require_real
from tridehaze_plugin.errors import DataError

from .synth import write_nerfstudio


def _scene_with_tracks(root, pairs, points=None):
    write_nerfstudio(
        root, n=4, extra_global={"ply_file_path": "points.ply", "point_tracks_file_path": "tracks.npy"}
    )
    if points is None:
        points = np.array([[0.0, 0.0, 0.0], [0.2, 0.1, -0.1], [-0.1, 0.1, 0.0]])
    write_ply_points(root / "points.ply", points, np.full((len(points), 3), 128))
    np.save(root / "tracks.npy", np.asarray(pairs))
    return json.loads((root / "transforms.json").read_text())["frames"]


def test_nerfstudio_tracks_follow_the_frames_by_name(tmp_path, make_cfg):
    root = tmp_path / "ns"
    frames = _scene_with_tracks(root, [[0, 0], [0, 2], [1, 3], [2, 1]])
    scene = load_scene(make_cfg(root, test_every=100))
    t = scene.point_tracks
    assert t is not None and t.names is None
    names = scene.names()
    got = {(int(p), names[int(v)]) for p, v in zip(t.point, t.view, strict=True)}
    want = {(p, frames[f]["file_path"]) for p, f in [(0, 0), (0, 2), (1, 3), (2, 1)]}
    assert got == want
    assert t.points_in(names.index(frames[2]["file_path"])).tolist() == [0]


def test_tracks_of_dropped_points_go_and_the_rest_are_renumbered(tmp_path, make_cfg):
    root = tmp_path / "ns"
    pts = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0], [-0.1, 0.1, 0.0]])
    _scene_with_tracks(root, [[0, 0], [1, 1], [2, 2]], points=pts)
    with pytest.warns(UserWarning):
        scene = load_scene(make_cfg(root, test_every=100))
    assert len(scene.points) == 2
    assert sorted(scene.point_tracks.point.tolist()) == [0, 1]  # point 2 is now point 1, point 1 gone


@pytest.mark.parametrize(
    ("pairs", "message"),
    [([[0, 0], [5, 1]], "out of range"), ([[0.5, 1.0]], "int pairs"), ([0, 1, 2], "int pairs")],
)
def test_bad_tracks_are_a_clear_error(tmp_path, make_cfg, pairs, message):
    root = tmp_path / "ns"
    _scene_with_tracks(root, pairs)
    with pytest.raises(DataError, match=message) as err:
        load_scene(make_cfg(root))
    assert "tracks.npy" in str(err.value)


def test_colmap_tracks_match_pycolmap(make_cfg):
    statue = require_real("statue")
    scene = load_scene(make_cfg(statue))
    rec = pycolmap.Reconstruction(str(statue / "sparse" / "0"))
    names = scene.names()
    ids = sorted(rec.points3D)
    lengths = np.bincount(scene.point_tracks.point, minlength=len(scene.points))
    for k in (0, len(ids) // 2, len(ids) - 1):
        p = rec.points3D[ids[k]]
        seen = sorted({names.index(f"images/{rec.images[e.image_id].name}") for e in p.track.elements})
        assert sorted(set(scene.point_tracks.view[scene.point_tracks.point == k].tolist())) == seen
        assert lengths[k] == len(p.track.elements)


def _camera_at_origin(w=9, h=7):
    return Cameras(
        camtoworlds=torch.eye(4)[None],
        fx=torch.tensor([10.0]),
        fy=torch.tensor([10.0]),
        cx=torch.tensor([w / 2]),
        cy=torch.tensor([h / 2]),
        width=torch.tensor([w]),
        height=torch.tensor([h]),
    )


def test_the_prior_keeps_a_tracked_far_point_that_the_occlusion_guess_drops():
    """Grazing ground: a far point one pixel row above a near one. Reprojected with the occlusion
    guess, the far point's pixels are taken for a hidden surface and dropped; its track says the
    view saw it."""
    cam = _camera_at_origin()  # OpenCV axes: looking down +z, rows grow downwards
    near = torch.tensor([[0.0, 0.1, 1.0]])  # u 4.5, v 4.5: pixel (4, 4), z 1
    far = torch.tensor([[0.0, 0.0, 5.0]])  # u 4.5, v 3.5: pixel (3, 4), z 5
    pts = torch.cat([near, far])
    d0, v0 = sfm_view_depth(pts, None, 0, cam, 7, 9)
    assert v0[4, 4] and d0[4, 4] == pytest.approx(1.0)
    assert not v0[2, 4]  # the far point's splat above the near one's: dropped as "hidden"
    tracks = PointTracks(np.array([0, 1]), np.array([0, 0]))
    d1, v1 = sfm_view_depth(pts, tracks, 0, cam, 7, 9)
    assert v1[2, 4] and d1[2, 4] == pytest.approx(5.0)
    assert d1[4, 4] == pytest.approx(1.0)  # the nearest still wins where both splat


def test_the_prior_leaves_out_an_untracked_hidden_point():
    cam = _camera_at_origin()
    pts = torch.tensor([[0.0, 0.0, 5.0]])  # alone, so the occlusion guess cannot drop it
    _, v0 = sfm_view_depth(pts, None, 0, cam, 7, 9)
    assert v0.any()
    _, v1 = sfm_view_depth(
        pts, PointTracks(np.array([0]), np.array([1])), 0, cam, 7, 9
    )  # seen by view 1 only
    assert not v1.any()


def test_the_union_prior_adds_untracked_points_where_no_tracked_one_lands():
    """Real tracks miss views that see a point: ``union`` keeps the tracked pixels as they are and
    fills the rest from the other points, reprojected with the occlusion guess."""
    cam = _camera_at_origin()
    near = torch.tensor([[0.0, 0.1, 1.0]])  # pixel (4, 4), z 1, tracked in view 0
    far = torch.tensor([[0.0, 0.0, 5.0]])  # pixel (3, 4), z 5, tracked in view 0
    lone = torch.tensor([[-0.3, -0.2, 1.0]])  # pixel (1, 1), z 1, in no track of view 0
    pts = torch.cat([near, far, lone])
    tracks = PointTracks(np.array([0, 1, 2]), np.array([0, 0, 1]))
    d_only, v_only = sfm_view_depth(pts, tracks, 0, cam, 7, 9)
    d, v = sfm_view_depth(pts, tracks, 0, cam, 7, 9, union=True)
    assert not v_only[1, 1] and v[1, 1] and d[1, 1] == pytest.approx(1.0)
    assert torch.equal(d[v_only], d_only[v_only])  # the tracked pixels unchanged (far ground kept)
    assert v[2, 4] and d[2, 4] == pytest.approx(5.0)


def test_union_without_tracks_and_for_a_view_tracking_nothing_is_the_old_reprojection():
    """``tri-dehaze`` uses ``union``: a dataset without tracks, or a view none of whose points
    are tracked, must get exactly the prior it got before (every point, the occlusion guess)."""
    cam = _camera_at_origin()
    near = torch.tensor([[0.0, 0.1, 1.0], [0.02, 0.1, 1.0]])  # pixel (4, 4), z 1
    hidden = torch.tensor([[0.0, 0.1, 5.0]])  # pixel (2, 4), z 5: the guess drops it beside near
    lone = torch.tensor([[-0.3, -0.2, 1.0]])  # pixel (1, 1), z 1
    pts = torch.cat([near, hidden, lone])
    d0, v0 = sfm_view_depth(pts, None, 0, cam, 7, 9)
    assert v0.any()
    d1, v1 = sfm_view_depth(pts, None, 0, cam, 7, 9, union=True)
    elsewhere = PointTracks(np.array([0, 1, 2, 3]), np.array([1, 1, 1, 1]))  # all in view 1
    d2, v2 = sfm_view_depth(pts, elsewhere, 0, cam, 7, 9, union=True)
    for d, v in ((d1, v1), (d2, v2)):
        assert torch.equal(v, v0) and torch.equal(d[v], d0[v0])


def test_a_parser_pair_outside_its_own_points_or_frames_raises():
    """A plugin parser's bug must surface, not silently thin the depth prior."""
    kept = np.array([True, False, True])
    good = PointTracks(np.array([0, 1, 2]), np.array([0, 1, 1]), names=["a", "b"])
    got = loaded_tracks(good, kept, ["b", "a"])  # loaded views in another order
    assert sorted(zip(got.point.tolist(), got.view.tolist(), strict=True)) == [(0, 1), (1, 0)]
    for point, view in ([3, 0], [0, 2], [-1, 0]):
        bad = PointTracks(np.array([0, point]), np.array([0, view]), names=["a", "b"])
        with pytest.raises(ValueError, match="outside the parser's 3 points / 2 frames"):
            loaded_tracks(bad, kept, ["a", "b"])
