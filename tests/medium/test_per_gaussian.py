"""The per-Gaussian composite (``--pipeline.composite.per-gaussian``): each Gaussian hazed at its
own depth, exact against the closed form in a homogeneous medium; the gradient policy per
Gaussian; the settings it cannot serve refused."""

from __future__ import annotations

import pytest
import torch

from components.gaussians.model import GaussianModel, GaussianModelConfig, logit
from components.gaussians.sh import rgb_to_sh
from components.gradients.policies import MDTGC, GradientPolicy
from components.medium.compositing import CompositeConfig, MediumCompositor
from components.rasterizers.base import RasterizerConfig
from pipelines.tridehaze.per_gaussian import render_per_gaussian
from tests.medium.test_compositing import AnalyticField, _camera
from tridehaze_plugin.errors import ConfigError

BETA, LIGHT = 0.35, 0.6


def _layered_model(device: torch.device) -> GaussianModel:
    """Half-transparent Gaussians at three depths in front of the camera, overlapping on screen."""
    means = torch.tensor([[0.0, 0.0, -1.5], [0.25, 0.1, 0.0], [-0.2, -0.1, 1.5], [0.6, 0.4, 0.5]])
    colors = torch.tensor([[0.9, 0.2, 0.1], [0.1, 0.8, 0.3], [0.2, 0.3, 0.9], [0.5, 0.5, 0.5]])
    params = {
        "means": means,
        "quats": torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(4, 1),
        "log_scales": torch.full((4, 3), -1.2),
        "opacity_logits": torch.full((4,), logit(0.6)),
        "sh0": rgb_to_sh(colors)[:, None, :],
        "shN": torch.zeros(4, 15, 3),
    }
    return GaussianModel(GaussianModelConfig(), params).to(device)


def _render(device, policy: GradientPolicy, stage: int = 1, depth_gradient: bool = False, stride: int = 3):
    model = _layered_model(device)
    field = AnalyticField(b0=BETA, light=LIGHT).to(device)
    comp = MediumCompositor(CompositeConfig(num_samples=8, ray_stride=stride, depth_gradient=depth_gradient))
    rasterizer = RasterizerConfig(backend="torch").setup(device=device)
    cam = _camera(device)
    bg = torch.tensor([0.2, 0.4, 0.6], device=device)
    r = render_per_gaussian(model, rasterizer, comp, field, cam, 0, bg, policy, stage, with_clean=True)
    return model, field, comp, rasterizer, cam, bg, r


def _closed_form(model, cam):
    """exp(-beta * distance) to each Gaussian centre [N, 1], and the centres' camera z [N]."""
    viewmat = cam.viewmats()[0]
    cam_pts = model.means @ viewmat[:3, :3].T + viewmat[:3, 3]  # [N, 3]
    return torch.exp(-BETA * cam_pts.norm(dim=-1))[:, None], cam_pts[:, 2]


@pytest.mark.parametrize("stride", [3, 4])
def test_each_gaussian_is_hazed_at_its_own_depth(device, stride):
    """In a homogeneous medium T_i = exp(-beta |x_i - o|) and S_i = L (1 - T_i) exactly, whatever the
    coarse-ray stride; the composite is the alpha blend of c_i T_i + S_i plus the background seen
    through the medium to the far bound (exact where a pixel is mostly uncovered)."""
    model, field, comp, rasterizer, cam, bg, r = _render(device, GradientPolicy(0.1), stride=stride)
    assert comp.depth_factor(24, 32) == (2 if stride == 4 else 1)  # the pre-pass at half resolution
    T, z = _closed_form(model, cam)
    assert bool((z > 0).all())
    alpha = r.out.alpha[0]  # [H, W, 1]
    H, W = alpha.shape[:2]
    march = r.march
    K = cam.Ks()[0]
    viewmat = cam.viewmats()[0]
    cam_pts = model.means @ viewmat[:3, :3].T + viewmat[:3, 3]
    uv = cam_pts[:, :2] / cam_pts[:, 2:] * K.diagonal()[:2] + K[:2, 2]
    T_g, S_g = comp.read_points(march, cam, uv, z, (H, W))
    _, T_far, S_far = comp.read_view(march, field, cam, r.out.depth[0], alpha)
    torch.testing.assert_close(T_g[:, None], T, rtol=0, atol=2e-6)
    torch.testing.assert_close(S_g, (LIGHT * (1 - T)).expand(-1, 3), rtol=0, atol=2e-6)
    colors = model.sh_coeffs[:, 0, :] * 0.28209479177387814 + 0.5  # [N, 3] (SH degree 0)
    blended = model.render_values(rasterizer, cam, torch.cat([colors * T_g[:, None] + S_g, colors], -1))[0]
    torch.testing.assert_close(
        r.hazy, blended[..., :3] + (1 - alpha) * (bg * T_far + S_far), rtol=0, atol=1e-6
    )
    torch.testing.assert_close(r.clean, blended[..., 3:] + (1 - alpha) * bg, rtol=0, atol=1e-6)
    xs = (torch.arange(W, device=device) + 0.5 - W / 2) / 30.0
    ys = (torch.arange(H, device=device) + 0.5 - H / 2) / 33.0
    far = comp.far_bound(field)
    expect_far = torch.exp(-BETA * far * torch.sqrt(1 + xs[None] ** 2 + ys[:, None] ** 2))[..., None]
    open_px = alpha[..., 0] < 0.5
    assert int(open_px.sum()) > 100
    torch.testing.assert_close(T_far[open_px], expect_far[open_px], rtol=0, atol=2e-6)
    # Gaussians at different depths overlap, so this is not the per-pixel form J T(D) + S(D)
    per_pixel = comp(field, cam, r.out.depth[0], r.out.alpha[0])
    gap = (r.hazy - (r.clean * per_pixel.transmittance + per_pixel.scattering)).abs().amax(-1)
    assert float(gap.detach()[alpha[..., 0] > 0.5].max()) > 0.02


def test_the_policy_scales_each_gaussians_gradient_by_its_own_transmittance(device):
    grads = {}
    for name, policy in (("none", GradientPolicy(0.05)), ("md-tgc", MDTGC(0.05))):
        model, *_, r = _render(device, policy, stage=2)
        r.hazy.sum().backward()
        grads[name] = model.params["sh0"].grad[:, 0, :].clone()  # [N, 3]
    model, *_, cam, _, _ = _render(device, GradientPolicy(0.05))
    ratio = (1.0 / _closed_form(model, cam)[0].clamp_min(0.05)).expand(-1, 3)
    seen = grads["none"].abs() > 1e-6
    assert int(seen.sum()) >= 6
    torch.testing.assert_close(grads["md-tgc"][seen] / grads["none"][seen], ratio[seen], rtol=1e-3, atol=0)


def test_the_haze_gradient_reaches_the_depth_only_when_asked(device):
    """The medium always learns from the composite; each centre's camera z gets the haze's
    gradient only with ``depth_gradient`` (the splats' screen positions get theirs either way)."""
    means_grad = {}
    for depth_gradient in (False, True):
        model, field, *_, r = _render(device, GradientPolicy(0.05), depth_gradient=depth_gradient)
        r.hazy.sum().backward()
        assert field.scale.grad is not None and float(field.scale.grad.abs()) > 0
        means_grad[depth_gradient] = model.params["means"].grad.clone()  # [N, 3]
    assert not torch.allclose(means_grad[False], means_grad[True], rtol=1e-3, atol=1e-6)


def test_settings_it_cannot_serve_are_refused():
    with pytest.raises(ConfigError, match="per-gaussian"):
        CompositeConfig(per_gaussian=True, background="infinite").check_values()
    with pytest.raises(ConfigError, match="per-gaussian"):
        CompositeConfig(per_gaussian=True, clean_sky="haze-light").check_values()
    CompositeConfig(per_gaussian=True).check_values()
