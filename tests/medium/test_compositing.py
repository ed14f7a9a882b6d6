"""Compositing I = J*T + S: exact where the maths is closed-form, coarse rays close to per-pixel rays,
per-pixel depth edges, and the extremes (no haze, opaque haze)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from components.data.cameras import Cameras
from components.medium.base import FieldBounds, MediumConfig, MediumField, MediumSample
from components.medium.compositing import (
    CompositeConfig,
    MediumCompositor,
    MediumRender,
    below_horizon,
    composite,
    composite_over_backdrop,
    homogeneous_along_rays,
)

H, W = 24, 32


def _camera(device: torch.device) -> Cameras:
    c2w = torch.eye(4)[None]
    c2w[0, :3, 3] = torch.tensor([0.1, -0.2, -3.0])
    f = torch.tensor([30.0])
    return Cameras(
        c2w, f, f * 1.1, torch.tensor([W / 2]), torch.tensor([H / 2]), torch.tensor([W]), torch.tensor([H])
    ).to(device)


class AnalyticField(MediumField):
    """beta(x) = b0 + b1 * sin(x) * cos(y) (smooth), light L(x, v) = l0 + view * v; one learnable scalar."""

    def __init__(self, b0: float = 0.3, b1: float = 0.0, light: float = 0.6, view: float = 0.0) -> None:
        super().__init__(MediumConfig(), FieldBounds(torch.zeros(3), torch.full((3,), 5.0)))
        self.scale = torch.nn.Parameter(torch.tensor(1.0))
        self.b0, self.b1, self.l0, self.view = b0, b1, light, view

    def forward(self, x, dirs):
        beta = self.scale * (self.b0 + self.b1 * torch.sin(x[:, 0]) * torch.cos(x[:, 1]))
        light = (self.l0 + self.view * dirs).clamp(0, 1)
        return MediumSample(beta=beta, light=light)


def _path_length(cam: Cameras, z: torch.Tensor) -> torch.Tensor:  # z [H, W] -> distance along ray
    xs = (torch.arange(W, device=z.device) + 0.5 - W / 2) / 30.0
    ys = (torch.arange(H, device=z.device) + 0.5 - H / 2) / 33.0
    return z * torch.sqrt(1 + xs[None] ** 2 + ys[:, None] ** 2)


def _depth_with_edges(device: torch.device, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)  # drawn on the cpu: the same depths on every device
    z = 2.0 + torch.rand(H, W, generator=g).to(device) * 0.2
    z[:, W // 2 + 1 :] += 3.0  # a depth edge inside a 4x4 block column
    z[5:9, 3:6] = 0.7  # a near object
    return z[..., None]


@pytest.mark.parametrize("stride", [1, 2, 4, 5])
def test_homogeneous_medium_is_exact_for_every_stride(device, stride):
    cam = _camera(device)
    field = AnalyticField(b0=0.4, b1=0.0).to(device)
    z = _depth_with_edges(device)
    ones = torch.ones_like(z)
    comp = MediumCompositor(CompositeConfig(num_samples=16, ray_stride=stride))
    med = comp(field, cam, z, ones)
    expect_T = torch.exp(-0.4 * _path_length(cam, z[..., 0]))
    torch.testing.assert_close(med.transmittance[..., 0], expect_T, rtol=0, atol=2e-6)
    # with constant L the sum telescopes: S = L (1 - T)
    expect_S = (0.6 * (1 - expect_T))[..., None].expand(-1, -1, 3)
    torch.testing.assert_close(med.scattering, expect_S, rtol=0, atol=2e-6)


def test_depth_edges_stay_per_pixel(device):
    """Two neighbours across a depth edge in one coarse block get their own transmittance."""
    cam = _camera(device)
    field = AnalyticField(b0=0.4).to(device)
    z = _depth_with_edges(device)
    med = MediumCompositor(CompositeConfig(ray_stride=8))(field, cam, z, torch.ones_like(z))
    T = med.transmittance[..., 0].detach()
    a, b = W // 2, W // 2 + 1
    assert float(T[10, a] - T[10, b]) > 0.25  # exp(-0.8) vs exp(-2): near pixel clearer than its neighbour
    expect = torch.exp(-0.4 * _path_length(cam, z[..., 0]))
    assert float((T[:, a] - expect[:, a]).abs().max()) < 1e-5


def test_coarse_rays_close_to_per_pixel_rays_on_smooth_medium(device):
    cam = _camera(device)
    field = AnalyticField(b0=0.3, b1=0.25, view=0.1).to(device)
    z = _depth_with_edges(device)
    ones = torch.ones_like(z)
    full = MediumCompositor(CompositeConfig(num_samples=16, ray_stride=1))(field, cam, z, ones)
    fine = MediumCompositor(CompositeConfig(num_samples=256, ray_stride=1))(field, cam, z, ones)
    errs = {}
    for s in (2, 4, 8):
        coarse = MediumCompositor(CompositeConfig(num_samples=16, ray_stride=s))(field, cam, z, ones)
        errs[s] = float((coarse.transmittance - full.transmittance).detach().abs().max())
        assert float((coarse.scattering - full.scattering).detach().abs().max()) < 0.05
    # error grows with the ray spacing and stays small at the default stride (4)
    assert errs[2] < errs[4] < errs[8] < 0.05, errs
    assert errs[4] < 0.02, errs
    # and the per-pixel march converges to a fine reference
    assert float((full.transmittance - fine.transmittance).detach().abs().max()) < 5e-3


def test_background_rays_reach_far_bound(device):
    cam = _camera(device)
    field = AnalyticField(b0=0.2).to(device)
    z = torch.full((H, W, 1), 1.0, device=device)
    alpha = torch.zeros_like(z)
    comp = MediumCompositor(CompositeConfig(far=10.0))
    med = comp(field, cam, z, alpha)
    torch.testing.assert_close(med.end_depth, torch.full_like(z, 10.0))
    assert comp.far_bound(field) == 10.0
    default = MediumCompositor(CompositeConfig()).far_bound(field)
    assert default == pytest.approx(2 * math.sqrt(3 * 25.0), rel=1e-6)


def test_no_haze_gives_identity(device):
    cam = _camera(device)
    field = AnalyticField(b0=0.0).to(device)
    z = _depth_with_edges(device)
    med = MediumCompositor(CompositeConfig())(field, cam, z, torch.ones_like(z))
    J = torch.rand(H, W, 3, device=device)
    assert torch.equal(med.transmittance, torch.ones_like(med.transmittance))
    assert torch.equal(med.scattering, torch.zeros_like(med.scattering))
    assert torch.equal(composite(J, med), J)


def test_opaque_haze_is_finite_and_shows_only_the_medium(device):
    cam = _camera(device)
    field = AnalyticField(b0=1e4, light=0.5).to(device)
    z = _depth_with_edges(device)
    comp = MediumCompositor(CompositeConfig())
    med = comp(field, cam, z, torch.ones_like(z))
    J = torch.rand(H, W, 3, device=device, requires_grad=True)
    hazy = composite(J, med)
    assert torch.isfinite(hazy).all()
    assert float(med.transmittance.detach().max()) <= 1e-6 + 1e-12
    torch.testing.assert_close(hazy.detach(), med.scattering.detach(), atol=2e-6, rtol=0)
    hazy.sum().backward()
    assert torch.isfinite(J.grad).all() and torch.isfinite(field.scale.grad)


def test_gradients_reach_medium_and_depth_only_when_asked(device):
    cam = _camera(device)
    field = AnalyticField(b0=0.3, b1=0.2).to(device)
    for flag in (False, True):
        z = _depth_with_edges(device).requires_grad_(True)
        med = MediumCompositor(CompositeConfig(depth_gradient=flag))(field, cam, z, torch.ones_like(z))
        (med.transmittance.sum() + med.scattering.sum()).backward()
        assert field.scale.grad is not None and float(field.scale.grad.abs()) > 0
        field.scale.grad = None
        if flag:
            assert z.grad is not None and float(z.grad.abs().sum()) > 0
        else:
            assert z.grad is None


def test_coverage_gradient_only_when_asked_and_it_says_less_cover_means_more_haze(device):
    cam = _camera(device)
    field = AnalyticField(b0=0.3, b1=0.2).to(device)
    z = _depth_with_edges(device)
    for flag in (False, True):
        alpha = torch.full_like(z, 0.8).requires_grad_(True)
        med = MediumCompositor(CompositeConfig(coverage_gradient=flag))(field, cam, z, alpha)
        med.transmittance.sum().backward()
        if flag:  # less coverage: the ray ends nearer the far bound, so T falls
            assert alpha.grad is not None and float(alpha.grad.min()) >= 0 and float(alpha.grad.sum()) > 0
        else:
            assert alpha.grad is None


def test_none_medium_and_homogeneous_helper(device):
    from components.medium.fields import NoMedium  # noqa: PLC0415 - registered by the fields module

    cam = _camera(device)
    z = _depth_with_edges(device)
    none = NoMedium(MediumConfig(backend="none"), FieldBounds(torch.zeros(3), torch.ones(3))).to(device)
    med = MediumCompositor(CompositeConfig())(none, cam, z, torch.ones_like(z))
    assert torch.equal(med.transmittance, torch.ones_like(z))
    beta = torch.full((H, W), 0.4, device=device)
    light = torch.full((H, W, 3), 0.6, device=device)
    hom = homogeneous_along_rays(beta, light, cam, z)
    expect = torch.exp(-0.4 * _path_length(cam, z[..., 0]))
    torch.testing.assert_close(hom.transmittance[..., 0], expect, rtol=0, atol=2e-6)
    torch.testing.assert_close(
        hom.scattering, 0.6 * (1 - expect)[..., None].expand(-1, -1, 3), rtol=0, atol=2e-6
    )


@pytest.mark.parametrize("stride", [1, 4])
def test_infinite_background_sees_the_medium_to_infinity(device, stride):
    """Uncovered pixels are pure in-scattering (T = 0, S = L in a homogeneous medium); covered
    pixels match the ``far`` mode exactly; a half-covered pixel is the alpha blend of the two."""
    cam = _camera(device)
    field = AnalyticField(b0=0.4, b1=0.0, light=0.6).to(device)
    z = _depth_with_edges(device)
    alpha = torch.ones_like(z)
    alpha[:, :8] = 0.0  # sky
    alpha[:, 8:10] = 0.5  # semi-transparent edge
    inf = MediumCompositor(CompositeConfig(ray_stride=stride, num_samples=8, background="infinite"))
    far = MediumCompositor(CompositeConfig(ray_stride=stride, num_samples=8))
    med = inf(field, cam, z, alpha)
    ref = far(field, cam, z, torch.ones_like(z))  # every ray ends at its surface
    torch.testing.assert_close(med.transmittance[:, 10:], ref.transmittance[:, 10:], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(med.scattering[:, 10:], ref.scattering[:, 10:], atol=1e-5, rtol=1e-5)
    sky = med.scattering[:, :8]
    torch.testing.assert_close(sky, torch.full_like(sky, 0.6), atol=1e-5, rtol=1e-5)
    open_sky = med.sky[:, :10]  # only marched to infinity where the pixel is not fully covered
    torch.testing.assert_close(open_sky, torch.full_like(open_sky, 0.6), atol=1e-5, rtol=1e-5)
    T_pix = med.pixel_transmittance()
    assert float(T_pix[:, :8].detach().abs().max()) == 0.0
    half = 0.5 * ref.scattering[:, 8:10] + 0.5 * 0.6
    torch.testing.assert_close(med.scattering[:, 8:10], half, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(T_pix[:, 8:10], 0.5 * ref.transmittance[:, 8:10], atol=1e-5, rtol=1e-5)
    # the clean render shows the sky light where nothing covers the pixel, the surface elsewhere
    clean = torch.rand(H, W, 3, device=device) * alpha  # premultiplied
    filled = med.clean_with_sky(clean)
    torch.testing.assert_close(filled[:, :8], torch.full_like(filled[:, :8], 0.6), atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(filled[:, 10:], clean[:, 10:])
    # and I = J*T + S holds with the premultiplied colour: the sky share adds light, hides nothing
    hazy = composite(clean, med)
    expect = clean * med.transmittance + alpha * ref.scattering + (1 - alpha) * 0.6
    torch.testing.assert_close(hazy, expect, atol=1e-5, rtol=1e-5)


def test_infinite_background_in_a_varying_medium_continues_with_the_boundary_value(device):
    """Past the far bound the field keeps its last value: the sky light is S(far) + T(far) L_last."""
    cam = _camera(device)
    field = AnalyticField(b0=0.3, b1=0.2, light=0.5, view=0.2).to(device)
    z = _depth_with_edges(device)
    alpha = torch.zeros_like(z)
    cfg = CompositeConfig(ray_stride=1, num_samples=8, background="infinite", far=6.0)
    med = MediumCompositor(cfg)(field, cam, z, alpha)
    to_far = MediumCompositor(replace(cfg, background="far"))(
        field, cam, torch.full_like(z, 6.0), torch.ones_like(z)
    )
    assert float(med.pixel_transmittance().detach().max()) == 0.0
    # the sky is at least what the march to the far bound gathered, and adds light in proportion to T(far)
    extra = (med.sky - to_far.scattering).detach()  # [H, W, 3]
    assert float(extra.min()) >= 0.0
    assert float((extra / to_far.transmittance.detach()).max()) <= 1.0 + 1e-5  # L <= 1
    assert float(extra.mean()) > 0.01


def test_infinite_background_passes_the_gradient_of_coverage(device):
    """A hole in a surface brightens the pixel towards the haze light: alpha must see that."""
    cam = _camera(device)
    field = AnalyticField(b0=0.4, light=0.9).to(device)
    z = _depth_with_edges(device)
    alpha = torch.full_like(z, 0.7).requires_grad_(True)
    med = MediumCompositor(CompositeConfig(ray_stride=1, num_samples=8, background="infinite"))(
        field, cam, z, alpha
    )
    med.scattering.sum().backward()
    # dS/dalpha = S(surface) - S(infinity) < 0: more coverage, less haze light
    assert float(alpha.grad.max()) < 0.0
    assert not med.coverage.requires_grad  # the reported coverage is a measurement, not a route


@pytest.mark.parametrize("clean_sky", ["background", "haze-light"])
def test_clean_sky_changes_the_clean_render_only(device, clean_sky):
    """``clean_sky`` fills uncovered pixels of the clean render with the light from infinity; T and
    S (the hazy composite, hence training) are those of the far-bound march either way."""
    cam = _camera(device)
    field = AnalyticField(b0=0.4, light=0.6).to(device)
    z = _depth_with_edges(device)
    alpha = torch.ones_like(z)
    alpha[:, :8] = 0.0
    ref = MediumCompositor(CompositeConfig(ray_stride=1, num_samples=8))(field, cam, z, alpha)
    med = MediumCompositor(CompositeConfig(ray_stride=1, num_samples=8, clean_sky=clean_sky))(
        field, cam, z, alpha
    )
    torch.testing.assert_close(med.transmittance, ref.transmittance)
    torch.testing.assert_close(med.scattering, ref.scattering)
    torch.testing.assert_close(med.pixel_transmittance(), ref.transmittance)
    clean = torch.rand(H, W, 3, device=device) * alpha
    filled = med.clean_with_sky(clean)
    if clean_sky == "background":
        assert med.sky is None
        torch.testing.assert_close(filled, clean)
    else:  # homogeneous to infinity: the sky is the light
        torch.testing.assert_close(filled[:, :8], torch.full_like(filled[:, :8], 0.6), atol=1e-5, rtol=1e-5)
        torch.testing.assert_close(filled[:, 8:], clean[:, 8:])


def test_infinite_background_can_keep_the_background_colour_in_the_clean_render(device):
    cam = _camera(device)
    field = AnalyticField(b0=0.4, light=0.6).to(device)
    z = _depth_with_edges(device)
    alpha = torch.zeros_like(z)
    cfg = CompositeConfig(ray_stride=1, num_samples=8, background="infinite", clean_sky="background")
    med = MediumCompositor(cfg)(field, cam, z, alpha)
    assert med.at_infinity and med.sky is None
    torch.testing.assert_close(med.scattering, torch.full_like(med.scattering, 0.6), atol=1e-5, rtol=1e-5)
    clean = torch.zeros(H, W, 3, device=device)
    torch.testing.assert_close(med.clean_with_sky(clean), clean)


def test_clean_t0_is_the_clamped_inversion_of_the_models_own_composite(device):
    """``clean_t0``: the clean render shown is (I - A) / max(T, t0) + A of the model's composite I
    (homogeneous light A, so S = A (1 - T)): unchanged where T >= t0, the light itself where T -> 0,
    and linear in T / t0 between; T and S are untouched."""
    cam = _camera(device)
    field = AnalyticField(b0=0.8, light=0.6).to(device)
    z = _depth_with_edges(device) * 2.0  # T from about 0.3 (near object) to below 0.01 (far half)
    alpha = torch.ones_like(z)
    t0 = 0.1
    ref = MediumCompositor(CompositeConfig(ray_stride=1, num_samples=8))(field, cam, z, alpha)
    comp = MediumCompositor(CompositeConfig(ray_stride=1, num_samples=8, clean_t0=t0))
    med = comp(field, cam, z, alpha)
    torch.testing.assert_close(med.transmittance, ref.transmittance)
    torch.testing.assert_close(med.scattering, ref.scattering)
    T = med.transmittance.detach()  # [H, W, 1]
    assert float(T.min()) < 0.02 and float(T.max()) > 0.2  # both regimes are exercised
    clean = torch.rand(H, W, 3, device=device)
    hazy = composite(clean, med)  # [H, W, 3]
    expected = (hazy.detach() - 0.6) / T.clamp_min(t0) + 0.6
    shown = comp.clean_view(med, clean).detach()
    torch.testing.assert_close(shown, expected, atol=1e-4, rtol=1e-4)
    observed = (T >= t0).expand_as(clean)
    torch.testing.assert_close(shown[observed], clean[observed])
    opaque = (T < 0.01).expand_as(clean)
    assert float((shown[opaque] - 0.6).abs().max()) < 0.01
    off = MediumCompositor(CompositeConfig(ray_stride=1, num_samples=8))
    torch.testing.assert_close(off.clean_view(ref, clean), clean)


def test_clean_fill_farthest_seen_fades_to_the_mean_of_the_band_just_above_t0(device):
    """``farthest-seen``: below t0 the shown colour goes to the mean clean colour of the pixels
    with T in [t0, 2 t0) (the same ramp as the haze-light fade); above t0 nothing changes; a view
    with too few such pixels keeps the haze light; ``auto`` follows the one-light verdict."""
    H, W, t0 = 20, 30, 0.1
    T = torch.linspace(0.01, 0.9, H * W, device=device).reshape(H, W, 1)  # every regime
    light = 0.6
    med = MediumRender(T, light * (1.0 - T).expand(H, W, 3), torch.ones_like(T))
    clean = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(1)).to(device)
    band = ((T >= t0) & (T < 2 * t0))[..., 0]
    assert int(band.sum()) > 20
    fill = clean[band].mean(dim=0)  # [3]
    w = T / T.clamp_min(t0)
    expected = w * clean + (1 - w) * fill
    comp = MediumCompositor(CompositeConfig(clean_t0=t0, clean_fill="farthest-seen"))
    shown = comp.clean_view(med, clean)
    torch.testing.assert_close(shown, expected)
    kept = (T >= t0).expand_as(clean)
    torch.testing.assert_close(shown[kept], clean[kept])
    # auto: the fill where the run judged its light one light, the haze light elsewhere
    auto = MediumCompositor(CompositeConfig(clean_t0=t0, clean_fill="auto"))
    torch.testing.assert_close(auto.clean_view(med, clean, one_light=True), expected)
    haze = MediumCompositor(CompositeConfig(clean_t0=t0)).clean_view(med, clean)
    torch.testing.assert_close(auto.clean_view(med, clean, one_light=False), haze)
    assert float((haze - expected).abs().max()) > 0.1  # the two fills differ here
    # a view with no pixel just above t0 (all opaque haze or all clear) keeps the haze light
    gap = torch.where(T < t0, T, T.clamp_min(2 * t0))  # [H, W, 1]: the band emptied
    med_gap = MediumRender(gap, light * (1.0 - gap).expand(H, W, 3), torch.ones_like(gap))
    torch.testing.assert_close(
        comp.clean_view(med_gap, clean),
        MediumCompositor(CompositeConfig(clean_t0=t0)).clean_view(med_gap, clean),
    )


def test_clean_fill_farthest_ground_fills_below_the_horizon_only(device):
    """``farthest-ground``: under t0, rays below the horizon fade to the mean clean colour of the
    band just above t0 *below the horizon*; rays above it keep the haze light; nothing changes
    where T >= t0; without the horizon mask, or with too few band pixels under the horizon, it is
    the haze-light fade. ``auto`` does not pick it."""
    H, W, t0, light = 20, 30, 0.1, 0.6
    T = torch.linspace(0.01, 0.9, H * W, device=device).reshape(W, H, 1).transpose(0, 1)  # varies along x
    med = MediumRender(T, light * (1.0 - T).expand(H, W, 3), torch.ones_like(T))
    clean = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(2)).to(device)
    below = torch.zeros(H, W, dtype=torch.bool, device=device)
    below[H // 2 :] = True  # the lower half of the image looks down
    band = ((T >= t0) & (T < 2 * t0))[..., 0] & below
    assert int(band.sum()) > 20
    ground = clean[band].mean(dim=0)  # [3]
    haze_light = MediumCompositor(CompositeConfig(clean_t0=t0)).clean_view(med, clean)
    w = T / T.clamp_min(t0)
    expected = torch.where(below[..., None], w * clean + (1 - w) * ground, haze_light)
    comp = MediumCompositor(CompositeConfig(clean_t0=t0, clean_fill="farthest-ground"))
    shown = med.faded_clean(clean, t0, "farthest-ground", below)
    torch.testing.assert_close(shown, expected)
    assert float((shown - haze_light).abs().max()) > 0.1  # the lower half's fade moved
    kept = (T >= t0).expand_as(clean)
    torch.testing.assert_close(shown[kept], clean[kept])
    torch.testing.assert_close(comp.clean_view(med, clean), haze_light)  # no camera: the haze light
    torch.testing.assert_close(med.faded_clean(clean, t0, "farthest-ground"), haze_light)  # no horizon
    few = torch.zeros_like(below)
    few[-1, :3] = True  # three pixels under the horizon: too few to average
    torch.testing.assert_close(med.faded_clean(clean, t0, "farthest-ground", few), haze_light)
    auto = MediumCompositor(CompositeConfig(clean_t0=t0, clean_fill="auto"))  # never farthest-ground
    assert auto.fill(one_light=False) == "haze-light" and auto.fill(one_light=True) == "farthest-seen"
    torch.testing.assert_close(auto.clean_view(med, clean, one_light=False), haze_light)


def test_below_horizon_splits_a_level_camera_at_its_principal_row(device):
    """A level camera (image y down, world z up) sees the ground on the rows below its principal
    point and the sky above; tilting the up vector to the opposite sign swaps the halves."""
    H, W = 24, 32
    c2w = torch.tensor(
        [[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 1.5], [0, 0, 0, 1]]
    )  # looks along +y, y-image down = -z
    f = torch.tensor([30.0])
    cam = Cameras(
        c2w[None], f, f, torch.tensor([W / 2]), torch.tensor([H / 2]), torch.tensor([W]), torch.tensor([H])
    ).to(device)
    up = torch.tensor([0.0, 0.0, 1.0], device=device)
    below = below_horizon(cam, H, W, up)  # [H, W]
    assert below.shape == (H, W)
    assert bool(below[H // 2 :].all()) and not bool(below[: H // 2].any())
    assert torch.equal(below_horizon(cam, H, W, -up), ~below)


class _InputsField(AnalyticField):
    """AnalyticField whose extinction scale and light level are gradcheck's inputs, so both gathered
    tables (optical depth and scattering) carry gradients."""

    def __init__(self) -> None:
        super().__init__(b0=0.3, b1=0.2, view=0.1)
        self.inputs: dict[str, torch.Tensor] = {}

    def forward(self, x, dirs):
        wave = self.b0 + self.b1 * torch.sin(x[:, 0]) * torch.cos(x[:, 1])
        return MediumSample(beta=self.inputs["scale"] * wave, light=self.inputs["level"] + self.view * dirs)


@pytest.mark.parametrize("stride", [1, 4])
def test_compositor_gradients_match_finite_differences(stride):
    """The per-pixel gather and its backward (one split of the gathered rows) against float64 finite
    differences, for the field's extinction and light. (The depth's gradient is a design
    approximation: the coarse rays' sample positions follow the detached depth, so it is not
    checked against finite differences here.)"""
    cam = _camera(torch.device("cpu")).to(torch.float64)
    field = _InputsField().double()
    comp = MediumCompositor(CompositeConfig(ray_stride=stride, t_floor=1e-9))
    z = _depth_with_edges(torch.device("cpu")).double()
    alpha = torch.ones_like(z)

    def render(scale, level):
        field.inputs = {"scale": scale, "level": level}
        med = comp(field, cam, z, alpha)
        return med.transmittance, med.scattering

    inputs = (
        torch.tensor(1.0, dtype=torch.float64, requires_grad=True),
        torch.tensor(0.55, dtype=torch.float64, requires_grad=True),
    )
    assert torch.autograd.gradcheck(render, inputs, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)


@pytest.mark.parametrize("stride", [1, 4])
def test_scattered_light_is_the_field_light_and_its_gradient_skips_the_extinction(device, stride):
    """The light anchor's input: for a constant light it is that light, whatever the extinction, and
    its gradient reaches the light only (the shares of the in-scattering are detached)."""
    cam = _camera(device)
    field = AnalyticField(b0=0.3, b1=0.2, light=0.6).to(device)
    z = _depth_with_edges(device)
    med = MediumCompositor(CompositeConfig(ray_stride=stride))(field, cam, z, torch.ones_like(z))
    assert med.scattered_light.shape == (3,)
    torch.testing.assert_close(
        med.scattered_light, torch.full((3,), 0.6, device=device), rtol=1e-5, atol=1e-5
    )
    assert not med.scattered_light.requires_grad  # the light is a constant; only the scale is learnable

    field = _InputsField().to(device)
    scale = torch.tensor(1.0, device=device, requires_grad=True)
    level = torch.tensor(0.5, device=device, requires_grad=True)
    field.inputs = {"scale": scale, "level": level}
    med = MediumCompositor(CompositeConfig(ray_stride=stride))(field, cam, z, torch.ones_like(z))
    g_scale, g_level = torch.autograd.grad(med.scattered_light.sum(), (scale, level), allow_unused=True)
    assert g_scale is None or float(g_scale.abs()) == 0.0
    assert float(g_level) == pytest.approx(3.0, rel=1e-5)  # d/dlevel of the sum of 3 channels


def test_scattered_light_of_the_per_pixel_helper(device):
    cam = _camera(device)
    beta = torch.full((H, W), 0.2, device=device)
    light = torch.full((H, W, 3), 0.4, device=device)
    med = homogeneous_along_rays(beta, light, cam, _depth_with_edges(device))
    torch.testing.assert_close(med.scattered_light, torch.full((3,), 0.4, device=device))


def test_backdrop_term_holds_t_constant(device):
    """Forward: the plain composite of surface + backdrop. Backward: T sees only the surface, the
    backdrop keeps its gradient (its coverage answers for it) and S is unchanged."""
    g = torch.Generator().manual_seed(0)
    surface = torch.rand(H, W, 3, generator=g).to(device) * 0.5
    backdrop = (torch.rand(H, W, 3, generator=g).to(device) * 0.5).requires_grad_()
    T = (torch.rand(H, W, 1, generator=g).to(device) * 0.9 + 0.05).requires_grad_()
    S = (torch.rand(H, W, 3, generator=g).to(device) * 0.3).requires_grad_()
    med = MediumRender(T, S, torch.ones(H, W, 1, device=device))
    held = composite_over_backdrop(surface, backdrop, med)
    plain = composite(surface + backdrop, med)  # the same sums in another order: float32 rounding
    torch.testing.assert_close(held, plain, rtol=0, atol=1e-6)
    weights = torch.rand(H, W, 3, generator=g).to(device)
    dT, dS, dB = torch.autograd.grad((held * weights).sum(), (T, S, backdrop))
    torch.testing.assert_close(dT, (weights * surface).sum(-1, keepdim=True), rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(dS, weights)
    torch.testing.assert_close(dB, weights * T.detach())
