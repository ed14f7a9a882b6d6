"""Gaussian model: initialisation, parameter views, optimizer groups, checkpoints, rendering."""

from __future__ import annotations

import math

import pytest
import torch

from components.data.cameras import Cameras
from components.gaussians import PARAM_NAMES, GaussianModel, GaussianModelConfig
from components.gaussians import knn as knn_module
from components.gaussians.knn import knn_distances
from components.gaussians.sh import sh_to_rgb
from components.rasterizers import TorchRasterizer
from tridehaze_plugin.registry import REGISTRY


def _brute_force_knn(points: torch.Tensor, k: int) -> torch.Tensor:
    d = ((points[:, None, :] - points[None, :, :]) ** 2).sum(-1).sqrt()
    d.fill_diagonal_(float("inf"))
    return d.sort(dim=1).values[:, :k]


def test_knn_matches_brute_force_in_small_chunks() -> None:
    gen = torch.Generator().manual_seed(0)
    pts = torch.randn(300, 3, generator=gen, dtype=torch.float64) * 3 + 100.0  # far from the origin
    pts[7] = pts[3]  # a duplicate point: distance 0, still "another" point
    ref = _brute_force_knn(pts, 3)
    out = knn_distances(pts, k=3, max_elems=1000)  # several chunks
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-10)
    assert out[7, 0] == 0 and out[3, 0] == 0
    assert knn_distances(pts[:2], k=3).shape == (2, 3)


@pytest.mark.parametrize("kind", ["uniform", "clustered", "planar", "duplicates"])
def test_grid_knn_is_exact(kind: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The voxel-grid path (used for large clouds) against brute force, on awkward distributions."""
    monkeypatch.setattr(knn_module, "BRUTE_FORCE_MAX_POINTS", 0)
    gen = torch.Generator().manual_seed(1)
    pts = torch.rand(3000, 3, generator=gen, dtype=torch.float64)
    if kind == "clustered":  # a tight blob plus sparse outliers: needs the coarser retries
        pts = torch.cat([torch.randn(2700, 3, generator=gen, dtype=torch.float64) * 0.01, pts[:300] * 20])
    elif kind == "planar":
        pts[:, 2] = 0.5
    elif kind == "duplicates":
        pts[1500:] = pts[:1500]
    ref = _brute_force_knn(pts, 3)
    torch.testing.assert_close(knn_distances(pts, k=3, max_elems=1 << 16), ref, rtol=0, atol=1e-12)


def test_init_from_points() -> None:
    gen = torch.Generator().manual_seed(1)
    pts = torch.rand(500, 3, generator=gen) * 2 - 1
    cols = torch.rand(500, 3, generator=gen)
    cfg = GaussianModelConfig(init_opacity=0.2, init_scale_mult=0.5)
    model = cfg.setup(points=pts, colors=cols, scene_extent=2.0)
    assert isinstance(model, GaussianModel) and model.num_gaussians == 500
    torch.testing.assert_close(model.means.detach(), pts)
    # scale: RMS distance to the 3 nearest neighbours (3DGS / gsplat recipe), isotropic
    rms = _brute_force_knn(pts.double(), 3).square().mean(-1).sqrt().float()
    torch.testing.assert_close(
        model.scales.detach(), (0.5 * rms)[:, None].expand(500, 3), rtol=1e-5, atol=1e-7
    )
    torch.testing.assert_close(model.opacities.detach(), torch.full((500,), 0.2), rtol=1e-6, atol=0)
    torch.testing.assert_close(sh_to_rgb(model.sh0.detach()[:, 0]), cols, rtol=0, atol=1e-6)
    assert model.shN.shape == (500, 15, 3) and (model.shN == 0).all()
    torch.testing.assert_close(model.normalized_quats.detach(), torch.tensor([[1.0, 0, 0, 0]]).expand(500, 4))
    assert model.sh_coeffs.shape == (500, 16, 3)


def test_init_subsamples_and_random_fallback() -> None:
    pts = torch.randn(1000, 3)
    cols = (torch.rand(1000, 3) * 255).to(torch.uint8)
    model = GaussianModelConfig(max_init_points=300, sh_degree=1).setup(pts, cols, 1.0)
    assert model.num_gaussians == 300 and model.shN.shape == (300, 3, 3)
    rows = (model.means.detach()[:, None, :] == pts[None]).all(-1)  # every mean is one of the seeds
    assert rows.any(1).all() and rows.sum(1).eq(1).all()
    model = GaussianModelConfig(random_init_points=2000, random_init_extent=1.5).setup(
        None, None, scene_extent=2.0
    )
    assert model.num_gaussians == 2000
    assert model.means.abs().max() <= 3.0 and model.means.abs().max() > 2.5
    assert torch.isfinite(model.log_scales).all()
    single = GaussianModelConfig().setup(torch.zeros(1, 3), None, scene_extent=4.0)
    assert single.num_gaussians == 1 and torch.isfinite(single.log_scales).all()


def test_param_groups_cover_every_parameter() -> None:
    model = GaussianModelConfig(means_lr=1e-4, sh0_lr=2e-3).setup(torch.randn(50, 3), None, scene_extent=3.0)
    groups = model.param_groups()
    assert list(groups) == list(PARAM_NAMES)
    assert {id(p) for p, _ in groups.values()} == {id(p) for p in model.parameters()}
    assert groups["means"][1] == pytest.approx(3e-4)
    assert groups["shN"][1] == pytest.approx(1e-4)
    assert (
        groups["opacity_logits"][1] == 5e-2 and groups["log_scales"][1] == 5e-3 and groups["quats"][1] == 1e-3
    )
    optim = torch.optim.Adam([{"params": [p], "lr": lr, "name": n} for n, (p, lr) in groups.items()])
    assert len(optim.param_groups) == 6


def test_active_sh_degree_grows_every_interval() -> None:
    model = GaussianModelConfig(sh_degree=2, sh_degree_interval=100).setup(torch.randn(10, 3), None)
    assert [model.active_sh_degree(s) for s in (0, 99, 100, 250, 10_000)] == [0, 0, 1, 2, 2]


def test_replace_params_and_load_a_checkpoint_with_another_size() -> None:
    small = GaussianModelConfig().setup(torch.randn(20, 3), None)
    big = GaussianModelConfig().setup(torch.randn(35, 3), None)
    small.load_state_dict(big.state_dict())
    assert small.num_gaussians == 35
    torch.testing.assert_close(small.means, big.means)
    with pytest.raises(ValueError, match="disagree"):
        small.replace_params({"means": torch.zeros(3, 3)})


def test_registered_and_renders_through_a_rasterizer() -> None:
    assert REGISTRY.get("gaussian_model", "3dgs") is GaussianModel
    gen = torch.Generator().manual_seed(3)
    pts = torch.randn(200, 3, generator=gen) * 0.3
    model = GaussianModelConfig(init_opacity=0.5).setup(
        pts, torch.rand(200, 3, generator=gen), scene_extent=1.0
    )
    c2w = torch.eye(4).repeat(2, 1, 1)
    c2w[:, 2, 3] = torch.tensor([-3.0, -2.5])
    f = torch.tensor([30.0, 30.0])
    cams = Cameras(c2w, f, f, torch.tensor([16.0, 16.0]), torch.tensor([12.0, 12.0]),
                   torch.tensor([32, 32]), torch.tensor([24, 24]))  # fmt: skip
    out = model.render(TorchRasterizer(), cams, step=2500, background=torch.ones(3))
    assert out.rgb.shape == (2, 24, 32, 3) and out.alpha.max() > 0.5
    out.rgb.mean().backward()
    for name in PARAM_NAMES:
        grad = model.params[name].grad
        assert grad is not None and torch.isfinite(grad).all(), name
    assert model.params["shN"].grad.abs().sum() > 0  # step 2500: degree 2 is active
    mixed = Cameras.cat([cams[0], cams[1].rescaled(0.5, 0.5, torch.tensor([16]), torch.tensor([12]))])
    with pytest.raises(ValueError, match="one size"):
        model.render(TorchRasterizer(), mixed, step=0)
    assert math.isclose(model.opacities[0].item(), 0.5, rel_tol=1e-6)
