"""Autograd of the torch reference rasterizer against finite differences (float64 gradcheck).

The scene is built away from the discontinuities of the rules: every pixel is inside the
3-sigma box of every Gaussian, alphas stay well above 1/255 and below the 0.999 clamp, the
transmittance never reaches 1e-4 and the means stay inside the Jacobian clamp.
"""

from __future__ import annotations

import torch

from components.rasterizers import TorchRasterizer

F64 = torch.float64
W, H = 8, 6


def _scene():
    means = torch.tensor([[0.05, -0.03, 2.0], [-0.04, 0.02, 2.3], [0.0, 0.04, 2.6]], dtype=F64)
    quats = torch.tensor([[1.0, 0.1, -0.2, 0.3], [0.9, -0.3, 0.2, 0.1], [0.8, 0.2, 0.4, -0.1]], dtype=F64)
    scales = torch.tensor([[0.5, 0.35, 0.45], [0.4, 0.6, 0.5], [0.55, 0.45, 0.5]], dtype=F64)
    opac = torch.tensor([0.5, 0.6, 0.4], dtype=F64)
    colors = torch.tensor([[0.9, 0.2, 0.1], [0.1, 0.8, 0.3], [0.2, 0.3, 0.9]], dtype=F64)
    viewmat = torch.eye(4, dtype=F64)[None]
    viewmat[0, :3, 3] = torch.tensor([0.01, -0.02, 0.05], dtype=F64)
    K = torch.tensor([[[20.0, 0, 4.1], [0, 18.0, 2.9], [0, 0, 1]]], dtype=F64)
    return means, quats, scales, opac, colors, viewmat, K


def _outputs(rast, means, quats, scales, opac, colors, viewmat, K, sh_degree=None):
    bg = torch.tensor([0.3, 0.2, 0.1], dtype=F64)
    out = rast.rasterize(means, quats, scales, opac, colors, viewmat, K, W, H, bg, sh_degree=sh_degree)
    return out.rgb, out.alpha, out.depth


def test_scene_is_away_from_discontinuities() -> None:
    means, quats, scales, opac, colors, viewmat, K = _scene()
    out = TorchRasterizer().rasterize(means, quats, scales, opac, colors, viewmat, K, W, H)
    assert out.visible.all() and (out.radii >= 10).all()  # boxes cover the whole 8x6 image
    assert out.alpha.max() < 0.95 and out.alpha.min() > 0.3


def test_gradcheck_all_inputs() -> None:
    rast = TorchRasterizer()
    inputs = tuple(t.clone().requires_grad_() for t in _scene())
    assert torch.autograd.gradcheck(lambda *xs: _outputs(rast, *xs), inputs, eps=1e-6, atol=1e-7, rtol=1e-5)


def test_gradcheck_sh_coefficients() -> None:
    rast = TorchRasterizer()
    means, quats, scales, opac, _, viewmat, K = _scene()
    gen = torch.Generator().manual_seed(0)
    sh = torch.randn(3, 9, 3, generator=gen, dtype=F64) * 0.2
    sh[:, 0] += 1.0  # colours stay positive: no clamp kink
    means = means.clone().requires_grad_()
    sh = sh.requires_grad_()
    assert torch.autograd.gradcheck(
        lambda m, c: _outputs(rast, m, quats, scales, opac, c, viewmat, K, sh_degree=2)[0],
        (means, sh),
        eps=1e-6,
        atol=1e-7,
        rtol=1e-5,
    )


def test_gradcheck_with_the_stop_rule_active() -> None:
    """Behind a nearly opaque pair the third Gaussian is cut off by the stop rule: zero gradient there."""
    rast = TorchRasterizer()
    means, quats, scales, _, colors, viewmat, K = _scene()
    opac = torch.tensor([0.995, 0.995, 0.9], dtype=F64)
    out = rast.rasterize(means, quats, scales, opac, colors, viewmat, K, W, H)
    front = rast.rasterize(means[:2], quats[:2], scales[:2], opac[:2], colors[:2], viewmat, K, W, H)
    # the third Gaussian covers every pixel with alpha > 0.3, yet leaves these pixels untouched
    stopped = (out.alpha == front.alpha)[0, ..., 0]
    assert stopped.any() and (~stopped).any()
    inputs = tuple(t.clone().requires_grad_() for t in (means, scales, opac, colors))
    assert torch.autograd.gradcheck(
        lambda m, s, o, c: _outputs(rast, m, quats, s, o, c, viewmat, K)[:2],
        inputs,
        eps=1e-7,
        atol=1e-7,
        rtol=1e-5,
    )
    colors = colors.clone().requires_grad_()
    rast.rasterize(means, quats, scales, opac, colors, viewmat, K, W, H).rgb[0][stopped].sum().backward()
    assert (colors.grad[2] == 0).all() and (colors.grad[:2] != 0).all()
