"""Torch reference rasterizer against closed-form expectations (float64 unless stated)."""

from __future__ import annotations

import math

import pytest
import torch

from components.gaussians.sh import C0, eval_sh, rgb_to_sh
from components.rasterizers import RasterizerConfig, TorchRasterizer
from components.rasterizers.projection import camera_centers

F64 = torch.float64
W, H = 32, 24
FX, FY, CX, CY = 50.0, 40.0, 16.0, 12.0


def _K(dtype=F64):
    return torch.tensor([[[FX, 0, CX], [0, FY, CY], [0, 0, 1]]], dtype=dtype)


def _eye(dtype=F64):
    return torch.eye(4, dtype=dtype)[None]


def _on_pixel_centre(px: int, py: int, z: float) -> list[float]:
    """World point (identity camera) that projects exactly onto the centre of pixel (px, py)."""
    return [(px + 0.5 - CX) * z / FX, (py + 0.5 - CY) * z / FY, z]


def _gaussians(means, scales, opac, colors, dtype=F64):
    n = len(means)
    return (
        torch.tensor(means, dtype=dtype),
        torch.tensor([[1.0, 0, 0, 0]] * n, dtype=dtype),
        torch.tensor(scales, dtype=dtype),
        torch.tensor(opac, dtype=dtype),
        torch.tensor(colors, dtype=dtype),
    )


def _render(means, quats, scales, opac, colors, **kw):
    rast = TorchRasterizer(kw.pop("config", None))
    return rast.rasterize(means, quats, scales, opac, colors, kw.pop("viewmats", _eye(means.dtype)),
                          kw.pop("Ks", _K(means.dtype)), kw.pop("width", W), kw.pop("height", H), **kw)  # fmt: skip


def test_single_isotropic_gaussian_matches_closed_form() -> None:
    s, o, z = 0.05, 0.8, 2.0
    mean = _on_pixel_centre(18, 10, z)
    g = _gaussians([mean], [[s, s, s]], [o], [[1.0, 0.5, 0.25]])
    out = _render(*g)
    x, y = mean[0], mean[1]
    # EWA: cov2d = s^2 J J^T + 0.3 I with the pinhole Jacobian at the mean (inside the FOV: no clamp)
    J = torch.tensor([[FX / z, 0, -FX * x / z**2], [0, FY / z, -FY * y / z**2]], dtype=F64)
    cov = s**2 * J @ J.T + 0.3 * torch.eye(2, dtype=F64)
    conic = torch.linalg.inv(cov)
    torch.testing.assert_close(out.means2d[0, 0], torch.tensor([18.5, 10.5], dtype=F64), rtol=0, atol=1e-12)
    alpha = out.alpha[0, ..., 0]
    # the peak is the pixel the pinhole projection names, and classic mode has no compensation
    assert divmod(int(alpha.argmax()), W) == (10, 18)
    assert alpha[10, 18].item() == pytest.approx(o, abs=1e-12)
    for px, py in [(19, 10), (18, 12), (15, 8)]:
        d = torch.tensor([18.5 - (px + 0.5), 10.5 - (py + 0.5)], dtype=F64)
        expect = o * math.exp(-0.5 * float(d @ conic @ d))
        assert alpha[py, px].item() == pytest.approx(expect, abs=1e-12)
    # a single Gaussian over black: rgb = colour * alpha
    torch.testing.assert_close(out.rgb[0], alpha[..., None] * g[4][0], rtol=0, atol=1e-12)
    # opacity-aware box (gsplat >= 1.5): half-extents of the ellipse where alpha reaches 1/255,
    # sqrt(2 log(255 o) var) per axis; the radius is the larger one
    extend = math.sqrt(2 * math.log(255 * o))
    rx, ry = math.ceil(extend * math.sqrt(cov[0, 0].item())), math.ceil(extend * math.sqrt(cov[1, 1].item()))
    assert out.radii[0, 0].item() == max(rx, ry)


@pytest.mark.parametrize("tile", [1, 4, 16])
def test_every_pair_reaching_1_over_255_composites_whatever_the_tiles(tile: int) -> None:
    """An opaque splat's alpha stays >= 1/255 out to sqrt(2 log 255) = 3.33 sigma: those tail pixels
    are composited (gsplat >= 1.5's opacity-aware boxes), all of them and only them, at any tile size.
    (A 3-sigma box, gsplat 1.4, stops at 9 px here and drops the pixels 9.5 px away.)"""
    z, o, sigma = 2.0, 0.99, 2.95  # sigma in pixels, blur included: 3 sigma = 8.85, 3.33 sigma = 9.8
    s = math.sqrt(sigma**2 - 0.3) * z
    g = _gaussians([[0.0, 0.0, z]], [[s / FX, s / FY, 0.05]], [o], [[1.0] * 3])  # on the axis: J diagonal
    out = _render(*g, config=RasterizerConfig(tile_size=tile))
    px, py = torch.meshgrid(torch.arange(W, dtype=F64), torch.arange(H, dtype=F64), indexing="xy")
    d2 = ((CX - (px + 0.5)) ** 2 + (CY - (py + 0.5)) ** 2) / sigma**2  # [H, W]
    expect = o * torch.exp(-0.5 * d2)
    expect = torch.where(expect >= 1 / 255, expect, torch.zeros_like(expect))
    tail = (expect > 0) & (d2 > 9.0)  # beyond 3 sigma, still composited
    assert tail.sum() >= 20
    torch.testing.assert_close(out.alpha[0, ..., 0], expect, rtol=0, atol=1e-12)


def test_gaussians_below_1_over_255_opacity_are_culled() -> None:
    g = _gaussians([_on_pixel_centre(8, 8, 2.0), _on_pixel_centre(20, 8, 2.0)], [[0.1] * 3] * 2,
                   [0.9 / 255, 1.1 / 255], [[1.0] * 3] * 2)  # fmt: skip
    out = _render(*g)
    assert out.visible.tolist() == [[False, True]] and out.radii[0, 0].item() == 0
    assert out.alpha[0, 8, 8, 0].item() == 0.0 and out.alpha[0, 8, 20, 0].item() == pytest.approx(1.1 / 255)


def test_alpha_is_clamped_at_0999() -> None:
    g = _gaussians([_on_pixel_centre(5, 5, 2.0)], [[0.1] * 3], [1.0], [[1.0, 1.0, 1.0]])
    assert _render(*g).alpha[0, 5, 5, 0].item() == pytest.approx(0.999, abs=1e-15)


@pytest.mark.parametrize("swap", [False, True])
def test_two_gaussians_front_to_back(swap: bool) -> None:
    """Two Gaussians on one pixel ray: the nearer one is blended first, whatever the input order."""
    red, green = [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]
    z_red, z_green = (3.0, 2.0) if swap else (2.0, 3.0)
    a_red, a_green = 0.6, 0.7
    g = _gaussians(
        [_on_pixel_centre(10, 8, z_red), _on_pixel_centre(10, 8, z_green)],
        [[0.05 * z_red] * 3, [0.05 * z_green] * 3],
        [a_red, a_green],
        [red, green],
    )
    bg = torch.tensor([0.0, 0.0, 1.0], dtype=F64)
    out = _render(*g, background=bg)
    if not swap:  # red in front
        expect = [a_red, a_green * (1 - a_red), (1 - a_red) * (1 - a_green)]
        depth = (2.0 * a_red + 3.0 * a_green * (1 - a_red)) / (1 - (1 - a_red) * (1 - a_green))
    else:
        expect = [a_red * (1 - a_green), a_green, (1 - a_red) * (1 - a_green)]
        depth = (2.0 * a_green + 3.0 * a_red * (1 - a_green)) / (1 - (1 - a_red) * (1 - a_green))
    torch.testing.assert_close(out.rgb[0, 8, 10], torch.tensor(expect, dtype=F64), rtol=0, atol=1e-12)
    assert out.depth[0, 8, 10, 0].item() == pytest.approx(depth, abs=1e-12)


def test_expected_depth_of_a_single_opaque_gaussian_is_its_z() -> None:
    z = 2.7
    g = _gaussians([_on_pixel_centre(12, 9, z)], [[0.3, 0.2, 0.1]], [1.0], [[0.5] * 3])
    out = _render(*g)
    hit = out.alpha[0, ..., 0] > 0
    assert hit.sum() > 50
    torch.testing.assert_close(out.depth[0, ..., 0][hit], torch.full_like(out.depth[0, ..., 0][hit], z))
    assert (out.depth[0, ..., 0][~hit] == 0).all()
    torch.testing.assert_close(out.depth_accum, out.depth * out.alpha, rtol=0, atol=1e-12)
    assert out.depths[0, 0].item() == pytest.approx(z)


def test_near_and_far_plane_culling() -> None:
    g = _gaussians([[0.0, 0.0, 0.005], [0.0, 0.0, -1.0], [0.0, 0.0, 50.0]], [[0.001] * 3] * 3, [0.9] * 3,
                   [[1.0] * 3] * 3)  # fmt: skip
    out = _render(*g, config=RasterizerConfig(far_plane=40.0))
    assert out.visible.tolist() == [[False, False, False]] and (out.radii == 0).all()
    assert (out.alpha == 0).all()
    out = _render(*g, config=RasterizerConfig(near_plane=0.001, far_plane=100.0))
    assert out.visible.tolist() == [[True, False, True]]


def test_background_per_camera_and_empty_scene() -> None:
    g = _gaussians([[0.0, 0.0, -1.0]], [[0.1] * 3], [0.9], [[1.0] * 3])  # behind the camera
    bg = torch.tensor([[0.1, 0.2, 0.3], [0.9, 0.8, 0.7]], dtype=F64)
    out = _render(*g, viewmats=_eye().repeat(2, 1, 1), Ks=_K().repeat(2, 1, 1), background=bg)
    assert out.rgb.shape == (2, H, W, 3)
    torch.testing.assert_close(out.rgb, bg[:, None, None, :].expand(2, H, W, 3))
    assert (out.alpha == 0).all() and (out.depth == 0).all()
    # a half-transparent Gaussian lets (1 - alpha) of the background through
    g = _gaussians([_on_pixel_centre(4, 4, 2.0)], [[0.1] * 3], [0.5], [[1.0, 1.0, 1.0]])
    out = _render(*g, background=bg[1])
    torch.testing.assert_close(out.rgb[0, 4, 4], 0.5 + 0.5 * bg[1])


def test_sh_degree_zero_is_a_constant_colour() -> None:
    gen = torch.Generator().manual_seed(0)
    means = torch.randn(30, 3, generator=gen, dtype=F64) * 0.4 + torch.tensor([0, 0, 3.0], dtype=F64)
    quats = torch.randn(30, 4, generator=gen, dtype=F64)
    scales = torch.rand(30, 3, generator=gen, dtype=F64) * 0.2 + 0.02
    opac = torch.rand(30, generator=gen, dtype=F64)
    rgb = torch.rand(30, 3, generator=gen, dtype=F64)
    sh = torch.randn(30, 16, 3, generator=gen, dtype=F64)  # higher bands must be ignored at degree 0
    sh[:, 0] = rgb_to_sh(rgb)
    ref = _render(means, quats, scales, opac, rgb)
    out = _render(means, quats, scales, opac, sh, sh_degree=0)
    torch.testing.assert_close(out.rgb, ref.rgb, rtol=0, atol=1e-12)


def test_sh_colours_use_the_direction_from_the_camera_centre() -> None:
    gen = torch.Generator().manual_seed(1)
    means = torch.randn(25, 3, generator=gen, dtype=F64) * 0.4
    quats = torch.randn(25, 4, generator=gen, dtype=F64)
    scales = torch.rand(25, 3, generator=gen, dtype=F64) * 0.2 + 0.02
    opac = torch.rand(25, generator=gen, dtype=F64)
    sh = torch.randn(25, 16, 3, generator=gen, dtype=F64) * 0.5
    c2w = torch.eye(4, dtype=F64)
    c2w[:3, 3] = torch.tensor([0.3, -0.2, -3.0], dtype=F64)  # camera moved back, not at the origin
    viewmat = torch.linalg.inv(c2w)[None]
    centre = camera_centers(viewmat)[0]
    torch.testing.assert_close(centre, c2w[:3, 3])
    colours = torch.clamp_min(eval_sh(2, sh, means - centre) + 0.5, 0.0)  # [N, 3]
    ref = _render(means, quats, scales, opac, colours, viewmats=viewmat)
    out = _render(means, quats, scales, opac, sh, sh_degree=2, viewmats=viewmat)
    torch.testing.assert_close(out.rgb, ref.rgb, rtol=0, atol=1e-12)
    assert C0 == pytest.approx(0.5 / math.sqrt(math.pi))


def _random_scene(n: int, seed: int, dtype=F64):
    gen = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=gen, dtype=dtype) * 0.5 + torch.tensor([0, 0, 3.0], dtype=dtype)
    return (
        means,
        torch.randn(n, 4, generator=gen, dtype=dtype),
        torch.rand(n, 3, generator=gen, dtype=dtype) * 0.2 + 0.01,
        torch.rand(n, generator=gen, dtype=dtype),
        torch.rand(n, 3, generator=gen, dtype=dtype),
    )


def test_batched_cameras_equal_separate_calls() -> None:
    g = _random_scene(60, 2)
    c2w = torch.eye(4, dtype=F64).repeat(2, 1, 1)
    c2w[1, :3, 3] = torch.tensor([0.4, 0.1, -0.5], dtype=F64)
    ang = 0.2
    c2w[1, :3, :3] = torch.tensor(
        [[math.cos(ang), 0, math.sin(ang)], [0, 1, 0], [-math.sin(ang), 0, math.cos(ang)]], dtype=F64
    )
    viewmats = torch.linalg.inv(c2w)
    Ks = torch.cat([_K(), _K() * torch.tensor([[1.2], [1.1], [1.0]], dtype=F64)])
    bg = torch.tensor([[0.0, 0.5, 1.0], [1.0, 0.5, 0.0]], dtype=F64)
    both = _render(*g, viewmats=viewmats, Ks=Ks, background=bg)
    for c in range(2):
        one = _render(*g, viewmats=viewmats[c : c + 1], Ks=Ks[c : c + 1], background=bg[c])
        for field in ("rgb", "alpha", "depth", "means2d"):
            torch.testing.assert_close(getattr(both, field)[c], getattr(one, field)[0], rtol=0, atol=1e-12)
        assert torch.equal(both.radii[c], one.radii[0])


def test_float32_agrees_with_float64() -> None:
    g64 = _random_scene(200, 3)
    g32 = tuple(t.float() for t in g64)
    out64 = _render(*g64)
    out32 = _render(*g32, viewmats=_eye(torch.float32), Ks=_K(torch.float32))
    assert out32.rgb.dtype == torch.float32
    torch.testing.assert_close(out32.rgb.double(), out64.rgb, rtol=0, atol=2e-4)
    torch.testing.assert_close(out32.alpha.double(), out64.alpha, rtol=0, atol=2e-4)


def test_means2d_gradient_is_retained_for_densification() -> None:
    means, quats, scales, opac, colors = (t.float().requires_grad_() for t in _random_scene(40, 4))
    out = _render(means, quats, scales, opac, colors, viewmats=_eye(torch.float32), Ks=_K(torch.float32))
    out.rgb.sum().backward()
    assert out.means2d.grad is not None and out.means2d.grad.shape == (1, 40, 2)
    assert (out.means2d.grad[0, out.visible[0]].abs().sum(-1) > 0).any()
    assert (out.means2d.grad[0, ~out.visible[0]] == 0).all()
    assert out.radii.dtype == torch.int32 and out.visible.dtype == torch.bool
    for t in (means, quats, scales, opac, colors):
        assert t.grad is not None and torch.isfinite(t.grad).all()


def test_backward_when_nothing_is_visible() -> None:
    means, quats, scales, opac, colors = (t.requires_grad_() for t in _gaussians([[0, 0, -2.0]], [[0.1] * 3], [0.5], [[1.0] * 3]))  # fmt: skip
    out = _render(means, quats, scales, opac, colors)
    out.rgb.sum().backward()
    assert means.grad is not None and (means.grad == 0).all()


def test_empty_model() -> None:
    g = tuple(torch.zeros((0, *shape), dtype=F64) for shape in [(3,), (4,), (3,), (), (3,)])
    out = _render(*g, background=torch.ones(3, dtype=F64))
    assert out.rgb.shape == (1, H, W, 3) and (out.rgb == 1).all() and out.means2d.shape == (1, 0, 2)
