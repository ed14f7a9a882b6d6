"""The ``gsplat`` backend's side of the contract, checked on CPU.

gsplat's ``rasterization`` runs CUDA kernels only, so here it is replaced by a CPU stand-in
that keeps its contract for the call the backend makes (classic, non-packed, ``RGB+ED``, gsplat
1.5.x) and is built from gsplat's own PyTorch code where gsplat has it: quaternion/scale to
covariance, EWA projection and SH evaluation (``gsplat.cuda._torch_impl``). Two pieces exist only
as CUDA in gsplat and are written here from its kernels: the opacity-aware per-axis radii
(``ProjectionEWA3DGSFused.cu``; the PyTorch twin still uses 3.33 sigma) and classic compositing
(``RasterizeToPixels3DGSFwd.cu``; done densely, every pixel against every visible Gaussian).

What this proves: the backend hands gsplat the tensors in the layout and activation it expects
(wxyz quaternions, activated scales and opacities, world-to-camera, SH [N, K, 3], backgrounds
[C, 3]), unpacks its outputs into ``RasterizeOutput`` (colour / depth split, per-axis radii,
screen-space gradients) and that gsplat's projection and SH agree with ours. What it cannot prove:
that the CUDA kernels match their PyTorch twins; ``test_gsplat_parity.py`` (``-m gpu``) does.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import gsplat
import pytest
import torch
from gsplat.cuda._torch_impl import _fully_fused_projection, _quat_scale_to_covar_preci, _spherical_harmonics

from components.rasterizers import RasterizerConfig, TorchRasterizer
from components.rasterizers.gsplat_backend import GsplatRasterizer

ALPHA_THRESHOLD = 1.0 / 255.0  # gsplat's Common.h


def _radii(conics_cov2d: torch.Tensor, means2d, opacities, valid, width, height):
    """ProjectionEWA3DGSFused.cu: extend = min(3.33, sqrt(2 log(o / (1/255)))); per-axis ceil."""
    var_x, var_y = conics_cov2d
    op = opacities[None].expand_as(var_x)  # [C, N]
    extend = torch.sqrt(2.0 * torch.log(op / ALPHA_THRESHOLD).clamp_min(0.0)).clamp_max(3.33)
    rx, ry = torch.ceil(extend * torch.sqrt(var_x)), torch.ceil(extend * torch.sqrt(var_y))
    mx, my = means2d.unbind(-1)
    keep = valid & (op >= ALPHA_THRESHOLD) & ((rx > 0) | (ry > 0))
    keep &= (mx + rx > 0) & (mx - rx < width) & (my + ry > 0) & (my - ry < height)
    return torch.stack([rx, ry], dim=-1).where(keep[..., None], torch.zeros_like(rx)[..., None]).int()


def _composite(means2d, conics, opacities, payload, depths, visible, width, height, background):
    """RasterizeToPixels3DGSFwd.cu, densely: front to back, skip sigma < 0 or alpha < 1/255,
    stop (exclusive) once T would fall to 1e-4."""
    py, px = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
    pix = torch.stack([px.reshape(-1), py.reshape(-1)], dim=-1).to(means2d) + 0.5  # [P, 2]
    renders, alphas = [], []
    for c in range(means2d.shape[0]):
        ids = visible[c].nonzero().squeeze(1)
        ids = ids[torch.argsort(depths[c, ids].detach(), stable=True)]  # radix sort on depth: stable
        d = means2d[c, ids][None] - pix[:, None]  # [P, M, 2]
        a, b, cc = conics[c, ids].unbind(-1)  # [M]
        sigma = 0.5 * (a * d[..., 0] ** 2 + cc * d[..., 1] ** 2) + b * d[..., 0] * d[..., 1]  # [P, M]
        alpha = torch.clamp_max(opacities[ids] * torch.exp(-sigma), 0.999)
        alpha = torch.where((sigma < 0) | (alpha < ALPHA_THRESHOLD), torch.zeros_like(alpha), alpha)
        keep = (torch.cumprod(1.0 - alpha, dim=1) > 1e-4).detach()  # a prefix: T only falls
        alpha = alpha * keep
        t_incl = torch.cumprod(1.0 - alpha, dim=1)
        t_excl = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], dim=1)
        acc = (alpha * t_excl) @ payload[c, ids]  # [P, D + 1]
        t_final = t_incl[:, -1:] if ids.numel() else torch.ones_like(pix[:, :1])
        if background is not None:
            acc = acc + t_final * background[c]
        renders.append(acc.reshape(height, width, -1))
        alphas.append((1.0 - t_final).reshape(height, width, 1))
    return torch.stack(renders), torch.stack(alphas)


def cpu_rasterization(
    means, quats, scales, opacities, colors, viewmats, Ks, width, height, *,
    near_plane, far_plane, eps2d, sh_degree, packed, tile_size, backgrounds, render_mode, rasterize_mode,
):  # fmt: skip
    """``gsplat.rasterization`` for the one call the backend makes, on CPU (see module docstring)."""
    assert not packed and rasterize_mode == "classic" and render_mode == "RGB+ED", "unexpected call"
    assert tile_size == 16 and isinstance(width, int) and isinstance(height, int)
    C, N = viewmats.shape[0], means.shape[0]
    assert quats.shape == (N, 4) and scales.shape == (N, 3) and opacities.shape == (N,)
    assert (scales > 0).all() and ((opacities >= 0) & (opacities <= 1)).all(), "expects activated values"
    covars, _ = _quat_scale_to_covar_preci(quats, scales, compute_covar=True, compute_preci=False)
    _, means2d, depths, conics, _ = _fully_fused_projection(
        means, covars, viewmats, Ks, width, height, eps2d=eps2d, near_plane=near_plane, far_plane=far_plane
    )  # [C, N, 2], [C, N], [C, N, 3]
    # the blurred 2D covariance's diagonal, back from the conic (inverse): var_x = c / det(conic)
    ca, cb, cc = conics.detach().unbind(-1)
    det = (ca * cc - cb * cb).clamp_min(1e-30)
    valid = (depths > near_plane) & (depths < far_plane)
    radii = _radii((cc / det, ca / det), means2d.detach(), opacities.detach(), valid, width, height)
    if sh_degree is not None:
        assert colors.shape == (N, (sh_degree + 1) ** 2, 3) or colors.shape[-2] >= (sh_degree + 1) ** 2
        campos = torch.inverse(viewmats)[:, :3, 3]  # [C, 3]
        dirs = means[None] - campos[:, None]  # [C, N, 3]
        colors = _spherical_harmonics(sh_degree, dirs, colors[None].expand(C, -1, -1, -1))
        colors = torch.clamp_min(colors + 0.5, 0.0)  # [C, N, 3]
    else:
        colors = colors.expand(C, N, colors.shape[-1])
    payload = torch.cat([colors, depths[..., None]], dim=-1)  # RGB+ED: depth as a last channel
    if backgrounds is not None:
        assert backgrounds.shape == (C, colors.shape[-1]), backgrounds.shape
        backgrounds = torch.cat([backgrounds, torch.zeros(C, 1)], dim=-1)
    visible = (radii > 0).all(dim=-1)
    render, alphas = _composite(
        means2d, conics, opacities, payload, depths, visible, width, height, backgrounds
    )
    render = torch.cat([render[..., :-1], render[..., -1:] / alphas.clamp(min=1e-10)], dim=-1)
    return render, alphas, {"means2d": means2d, "radii": radii, "depths": depths, "conics": conics}


@pytest.fixture
def cpu_gsplat(monkeypatch):
    monkeypatch.setattr(gsplat, "rasterization", cpu_rasterization)
    return GsplatRasterizer(RasterizerConfig(backend="gsplat"))


def _scene(n: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * 0.5 + torch.tensor([0.0, 0.0, 3.0])
    means[0] = torch.tensor([0.0, 0.0, -1.0])  # behind the camera
    means[1] = torch.tensor([5.0, 0.0, 2.0])  # off-screen
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.08 + 0.01
    opac = torch.rand(n, generator=g) * 0.95 + 0.04
    opac[2] = 0.5 / 255  # below 1/255: culled
    sh = torch.randn(n, 16, 3, generator=g) * 0.3
    ang = 0.15
    view = torch.eye(4)[None].repeat(2, 1, 1)
    view[1, :3, :3] = torch.tensor(
        [[math.cos(ang), 0, math.sin(ang)], [0, 1, 0], [-math.sin(ang), 0, math.cos(ang)]]
    )
    view[1, :3, 3] = torch.tensor([0.2, -0.1, 0.3])  # a second camera, turned and shifted
    K = torch.tensor([[70.0, 0, 30.0], [0, 65.0, 22.0], [0, 0, 1]])[None].repeat(2, 1, 1)
    return means, quats, scales, opac, sh, view, K


def _run(rast, args, grads: bool, **kw):
    inputs = [a.clone().requires_grad_(grads and i < 5) for i, a in enumerate(args)]
    out = rast.rasterize(*inputs, **kw)
    if grads:
        (out.rgb.square().sum() + 0.01 * out.depth.sum() + out.alpha.sum()).backward()
    return out, [x.grad for x in inputs[:5]], out.means2d.grad


@pytest.mark.parametrize("sh_degree", [3, 1, None])
def test_gsplat_backend_matches_torch_reference_through_gsplats_code(cpu_gsplat, sh_degree) -> None:
    means, quats, scales, opac, sh, view, K = _scene(300, 0)
    colors = sh if sh_degree is not None else torch.sigmoid(sh[:, 0])  # SH [N, 16, 3] or RGB [N, 3]
    args = (means, quats, scales, opac, colors, view, K)
    kw = dict(width=60, height=45, background=torch.tensor([0.1, 0.2, 0.3]), sh_degree=sh_degree)
    a, ga, ma = _run(cpu_gsplat, args, True, **kw)
    b, gb, mb = _run(TorchRasterizer(), args, True, **kw)
    assert 0.3 < float(b.alpha.detach().mean()) < 0.99  # a scene that blends, not empty, not saturated
    assert a.rgb.shape == b.rgb.shape == (2, 45, 60, 3) and a.radii.shape == (2, 300)
    torch.testing.assert_close(a.rgb, b.rgb, atol=2e-5, rtol=0)
    torch.testing.assert_close(a.alpha, b.alpha, atol=2e-5, rtol=0)
    torch.testing.assert_close(a.depth, b.depth, atol=1e-4, rtol=1e-5)
    torch.testing.assert_close(a.depth_accum, b.depth_accum, atol=1e-4, rtol=1e-5)
    assert torch.equal(a.radii, b.radii) and torch.equal(a.visible, b.visible)
    assert not a.visible[:, :3].any()  # behind, off-screen, transparent
    torch.testing.assert_close(a.depths, b.depths)
    for x, y in zip(ga, gb, strict=True):  # means, quats, scales, opacities, colours
        torch.testing.assert_close(x, y, atol=2e-4 * float(y.abs().max()), rtol=0)
    assert ma is not None and mb is not None  # the screen-space gradient densification reads
    torch.testing.assert_close(ma, mb, atol=2e-4 * float(mb.abs().max()), rtol=0)


def test_gsplat_backend_background_forms_and_per_camera_colours(cpu_gsplat) -> None:
    means, quats, scales, opac, sh, view, K = _scene(120, 1)
    per_cam = torch.sigmoid(torch.randn(2, 120, 3, generator=torch.Generator().manual_seed(3)))  # [C, N, 3]
    for background in (None, torch.tensor([0.5, 0.4, 0.3]), torch.tensor([[0.0, 0.0, 1.0], [1.0, 0, 0]])):
        args = (means, quats, scales, opac, per_cam, view, K)
        a, *_ = _run(cpu_gsplat, args, False, width=40, height=30, background=background)
        b, *_ = _run(TorchRasterizer(), args, False, width=40, height=30, background=background)
        torch.testing.assert_close(a.rgb, b.rgb, atol=2e-5, rtol=0)
        assert (a.depth[a.alpha == 0] == 0).all()  # no hit: depth 0


def test_rasterizer_benchmark_runs_a_gsplat_row(cpu_gsplat, monkeypatch) -> None:
    """benchmarks/rasterizers.py with gsplat among the backends (on a GPU its inputs are CUDA tensors;
    here the stand-in renders CPU ones)."""
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "rasterizers.py"
    spec = importlib.util.spec_from_file_location("bench_rasterizers", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.device_of("gsplat").type == "cuda" and bench.device_of("cpu").type == "cpu"
    monkeypatch.setattr(bench, "device_of", lambda backend: torch.device("cpu"))
    monkeypatch.setattr(GsplatRasterizer, "unavailable_reason", classmethod(lambda cls: None))
    monkeypatch.setattr(GsplatRasterizer, "runs_on", classmethod(lambda cls, device: True))  # the stand-in
    rows = bench.bench_case(["torch", "gsplat"], 200, 32, 24, repeats=1, scale_mult=1.0)
    assert [r["backend"] for r in rows] == ["torch", "gsplat"]
    assert all(r["forward_s"] > 0 and r["fwd_bwd_s"] > 0 and r["speedup_fwd_bwd"] > 0 for r in rows)
