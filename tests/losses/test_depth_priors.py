"""Pseudo-depth sources: SfM projection, dark-channel depth, depth files."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from components.data.cameras import Cameras
from components.losses.depth_priors import depth_from_dcp, depth_from_file, depth_from_sfm

from .test_dcp import hazy_scene

K = torch.tensor([[100.0, 0.0, 32.5], [0.0, 100.0, 24.5], [0.0, 0.0, 1.0]])  # centre of pixel (32, 24)
H, W = 48, 64


def test_sfm_points_land_at_expected_pixels_with_z(device):
    pts = torch.tensor(
        [[0.0, 0.0, 2.0], [0.1, -0.2, 2.0], [0.0, 0.0, 5.0], [0.0, 0.0, -2.0], [9.0, 0.0, 1.0]], device=device
    )
    viewmat = torch.eye(4, device=device)
    prior, valid = depth_from_sfm(pts, viewmat, K.to(device), H, W, splat_radius=0, occlusion_window=0)
    assert prior.shape == (H, W) and prior.dtype == torch.float32 and valid.dtype == torch.bool
    assert valid.sum() == 2  # two pixels: the z-buffer pair shares one, behind / outside are dropped
    assert prior[24, 32].item() == pytest.approx(2.0)  # nearest of z = 2 and z = 5
    assert prior[14, 37].item() == pytest.approx(2.0)  # u = 32.5 + 5, v = 24.5 - 10
    assert (prior[~valid] == 0).all()


def test_sfm_splat_footprint_and_camera_pose(device):
    # camera 3 m behind the origin looking along +z (OpenCV axes), through Cameras.viewmats
    c2w = torch.eye(4, device=device)
    c2w[2, 3] = -3.0
    one = lambda x: torch.tensor([x], device=device)  # noqa: E731
    cams = Cameras(c2w[None], one(100.0), one(100.0), one(32.5), one(24.5), one(W), one(H))
    pts = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]], device=device)
    prior, valid = depth_from_sfm(pts, cams.viewmats()[0], cams.Ks()[0], H, W, splat_radius=1)
    assert valid.sum() == 9 and valid[23:26, 31:34].all()
    assert torch.allclose(prior[23:26, 31:34], torch.full((3, 3), 3.0, device=device))


def test_sfm_occlusion_filter_drops_points_seen_through_gaps(device):
    # a near point at pixel (32, 24) and a far one 2 px to its right (u = 32.5 + 100 * 0.2 / 10)
    pts = torch.tensor([[0.0, 0.0, 2.0], [0.2, 0.0, 10.0]], device=device)
    viewmat, k = torch.eye(4, device=device), K.to(device)
    _, keep = depth_from_sfm(pts, viewmat, k, H, W, splat_radius=0, occlusion_window=0)
    _, filt = depth_from_sfm(pts, viewmat, k, H, W, splat_radius=0, occlusion_window=5)
    assert keep[24, 34] and not filt[24, 34] and filt[24, 32]


def test_dcp_prior_monotone_in_true_depth():
    i, _, _, d = hazy_scene()
    prior, valid = depth_from_dcp(i)
    assert valid.float().mean() > 0.5  # the far top rows fall below t_min = 2 t0
    p, q = prior[valid].numpy(), d[valid.numpy()]
    rank = lambda x: np.argsort(np.argsort(x)).astype(np.float64)  # noqa: E731
    assert np.corrcoef(rank(p), rank(q))[0, 1] > 0.9
    assert (prior[~valid] == 0).all()


def test_file_prior_reads_npy_and_resizes(tmp_path):
    d = np.tile(np.arange(1, 31, dtype=np.float32), (20, 1))  # [20, 30], depth grows with x
    d[0, 0] = np.nan
    d[0, 1] = 0.0
    np.save(tmp_path / "d.npy", d)

    same, v = depth_from_file(tmp_path / "d.npy", 20, 30)
    assert not v[0, 0] and not v[0, 1] and v[1:].all()
    assert torch.equal(same[1], torch.from_numpy(d[1]))

    small, vs = depth_from_file(tmp_path / "d.npy", 10, 15)
    assert small.shape == (10, 15) and vs[1:].all()
    assert small[5, 0].item() == pytest.approx(1.5) and torch.isfinite(small).all()

    big, vb = depth_from_file(tmp_path / "d.npy", 40, 60)
    assert big.shape == (40, 60) and not vb[0, 0] and big[10, 59].item() == pytest.approx(30.0)

    inv, _ = depth_from_file(tmp_path / "d.npy", 20, 30, disparity=True)
    assert inv[5, 3].item() == pytest.approx(1 / 4)
