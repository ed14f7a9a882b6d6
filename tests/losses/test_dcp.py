"""Dark channel prior on synthetic hazy images with known transmittance and airlight."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.nn import functional as F

from components.losses.dcp import (
    box_guided_filter,
    dark_channel_bound,
    dcp_transmittance_loss,
    dehaze,
    estimate_dcp,
    guided_filter,
    min_filter,
)

AIRLIGHT = np.array([0.8, 0.85, 0.9], np.float32)
H, W = 96, 128


def clean_texture(seed: int = 0, block: int = 4) -> np.ndarray:
    """[H, W, 3] colourful blocks with one zero channel each: the dark channel is exactly 0.

    Colours stay below the airlight, as for most outdoor surfaces: objects brighter than A would
    out-shine the haziest pixels in the dark channel (a known DCP failure, not tested here).
    """
    rng = np.random.default_rng(seed)
    hb, wb = H // block, W // block
    col = rng.uniform(0.05, 0.7, (hb, wb, 3)).astype(np.float32)
    col[np.arange(hb)[:, None], np.arange(wb)[None, :], rng.integers(0, 3, (hb, wb))] = 0.0
    return np.kron(col, np.ones((block, block, 1), np.float32))


def depth_map() -> np.ndarray:
    """[H, W] ground-plane-like depth growing towards the top, with a near box in the middle."""
    rows = np.linspace(40.0, 2.0, H, dtype=np.float32)[:, None]
    d = np.repeat(rows, W, axis=1)
    d[40:70, 50:90] = 4.0
    return d


def hazy_scene(beta: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(hazy I, clean J, true t, depth) under I = J t + A (1 - t)."""
    j = clean_texture()
    d = depth_map()
    t = np.exp(-beta * d).astype(np.float32)
    i = j * t[..., None] + AIRLIGHT * (1 - t[..., None])
    return i.astype(np.float32), j, t, d


def test_airlight_and_transmittance_close_to_truth():
    i, _, t, _ = hazy_scene()
    res = estimate_dcp(i)
    assert res.transmittance.shape == (H, W) and res.transmittance.dtype == np.float32
    assert res.airlight.shape == (3,)
    assert np.abs(res.airlight - AIRLIGHT).max() < 0.05
    assert np.abs(res.transmittance - t).mean() < 0.1
    assert res.transmittance.min() >= 0.05 and res.transmittance.max() <= 1.0


def test_uint8_input_and_explicit_parameters():
    i, _, t, _ = hazy_scene()
    res = estimate_dcp((i * 255 + 0.5).astype(np.uint8), patch=5, guided_radius=8, omega=1.0, t0=0.1)
    assert np.abs(res.transmittance - t).mean() < 0.1
    assert res.transmittance.min() >= 0.1


def test_haze_free_dark_image_gives_full_transmittance():
    res = estimate_dcp(clean_texture(seed=1) * 0.5)
    assert res.transmittance.mean() > 0.97


def test_dehaze_recovers_clean_image():
    i, j, t, _ = hazy_scene()
    near = t > 0.3  # far pixels amplify any error in t by 1/t
    hazy_err = np.abs(i - j)[near].mean()
    # unrefined t is exact here (dark channel 0 everywhere) up to depth edges: tight check of the formula
    exact = dehaze(i, estimate_dcp(i, omega=1.0, guided_radius=0))
    assert exact.shape == i.shape and exact.min() >= 0 and exact.max() <= 1
    assert np.abs(exact - j)[near].mean() < 0.03
    # the guided filter copies some grey-level texture into t: looser, but far better than the input
    assert np.abs(dehaze(i, estimate_dcp(i)) - j)[near].mean() < 0.3 * hazy_err


def test_transmittance_loss(device):
    t = torch.rand(8, 8, device=device, requires_grad=True)
    assert dcp_transmittance_loss(t, t.detach()).item() == 0.0
    target = torch.zeros(8, 8, device=device)
    loss = dcp_transmittance_loss(t, target)
    assert loss.item() == pytest.approx(t.detach().square().mean().item())
    loss.backward()
    assert torch.isfinite(t.grad).all()
    mask = torch.zeros(8, 8, dtype=torch.bool, device=device)
    mask[0, 0] = True
    assert dcp_transmittance_loss(t, target, mask).item() == pytest.approx(t[0, 0].item() ** 2)
    assert dcp_transmittance_loss(t, target, torch.zeros_like(mask)).item() == 0.0


def test_transmittance_lower_bound_penalises_only_t_below_the_estimate(device):
    t = torch.tensor([[0.2, 0.5], [0.8, 0.5]], device=device, requires_grad=True)
    t_dcp = torch.full((2, 2), 0.5, device=device)
    loss = dcp_transmittance_loss(t, t_dcp, lower_bound=True)
    assert loss.item() == pytest.approx(0.3**2 / 4)  # only the 0.2 pixel is below the bound
    loss.backward()
    assert t.grad[0, 0].item() < 0.0  # pushed up towards the bound
    assert t.grad[0, 1].item() == 0.0 and t.grad[1, 0].item() == 0.0 and t.grad[1, 1].item() == 0.0


def test_dark_channel_under_estimates_transmittance_of_a_bright_surface():
    """Why ``lower_bound`` exists: a haze-free patch without dark pixels reads as hazy."""
    a = np.array([0.9, 0.9, 0.9], np.float32)
    i = np.empty((40, 40, 3), np.float32)
    i[:20] = a  # sky: pure airlight, so the estimate finds the true airlight
    t_true = 0.8
    i[20:] = 0.6 * t_true + a * (1 - t_true)  # bright grey wall (no channel near 0), thin haze
    est = estimate_dcp(i, guided_radius=0)
    np.testing.assert_allclose(est.airlight, a, atol=1e-6)
    wall_t = est.transmittance[30:].mean()  # away from the min filter's reach into the sky
    assert wall_t == pytest.approx(1 - 0.95 * (0.6 * t_true + 0.9 * (1 - t_true)) / 0.9, abs=1e-5)
    assert wall_t < t_true - 0.4


def test_dark_channel_bound_with_the_haze_light_per_pixel():
    """Where the haze light is dimmer than one global airlight, the global estimate lands above the
    true t (no longer a bound); the per-pixel light keeps it below, and tight on dark patches."""
    H, W, t = 12, 15, 0.4
    j = torch.full((H, W, 3), 0.5)
    j[1::3, 1::3] = 0.0  # a black pixel in every 3x3 patch
    light = torch.full((H, W, 3), 0.9)
    light[:, W // 2 :] = 0.5  # the haze light away from the sun is dimmer
    i = j * t + light * (1 - t)
    own = dark_channel_bound(i, light, patch=3, omega=1.0)
    torch.testing.assert_close(own, torch.full_like(own, t), atol=1e-5, rtol=0)
    glob = dark_channel_bound(i, torch.full_like(light, 0.9), patch=3, omega=1.0)
    assert float(glob[:, W // 2 + 2 :].min()) > t + 0.2  # one airlight: far above the truth
    soft = dark_channel_bound(i, light, patch=3)  # omega 0.95 keeps a little haze: never above t
    assert float(soft.max()) <= t + 0.05 * (1 - t) + 1e-6


@pytest.mark.parametrize("upper_weight", [0.0, 0.25, 1.0])
def test_transmittance_bound_with_an_upper_weight_is_between_the_bound_and_the_mse(device, upper_weight):
    t = torch.tensor([[0.2, 0.5], [0.8, 0.5]], device=device)
    t_dcp = torch.full((2, 2), 0.5, device=device)
    loss = dcp_transmittance_loss(t, t_dcp, lower_bound=True, upper_weight=upper_weight)
    assert loss.item() == pytest.approx((0.3**2 + upper_weight * 0.3**2) / 4)
    if upper_weight == 1.0:  # the two-sided loss
        assert loss.item() == pytest.approx(dcp_transmittance_loss(t, t_dcp).item())


@pytest.mark.parametrize("shape,radius", [((72, 96), 12), ((31, 17), 4), ((8, 8), 1)])
def test_box_guided_filter_matches_opencv_contrib(shape, radius):
    """The fallback for OpenCV builds without ximgproc equals the contrib filter, the reference
    (opencv-contrib is a dependency of the project, so the reference is always there)."""
    from cv2 import ximgproc

    rng = np.random.default_rng(3)
    guide = rng.random(shape).astype(np.float32)
    src = (0.5 * guide + 0.5 * rng.random(shape)).astype(
        np.float32
    )  # correlated, as t is with the grey image
    ref = ximgproc.guidedFilter(guide, src, radius, 1e-3)
    out = box_guided_filter(guide, src, radius, 1e-3)
    assert out.shape == shape and out.dtype == np.float32
    np.testing.assert_allclose(out, ref, rtol=0, atol=2e-5)  # float32 rounding of the window sums
    np.testing.assert_array_equal(guided_filter(guide, src, radius, 1e-3), ref)  # contrib present: it is used


def test_dark_channel_without_opencv_contrib(monkeypatch):
    """Where only a plain OpenCV build is installed, the dark channel uses the box-filter fallback
    and gives the same transmittance."""
    import components.losses.dcp as dcp_module

    rng = np.random.default_rng(5)
    img = rng.random((40, 56, 3)).astype(np.float32)
    ref = estimate_dcp(img)
    monkeypatch.setattr(dcp_module, "ximgproc", None)
    monkeypatch.delattr(dcp_module.cv2, "ximgproc")  # as if never installed: a direct call would fail
    out = estimate_dcp(img)
    np.testing.assert_allclose(out.transmittance, ref.transmittance, rtol=0, atol=2e-5)
    np.testing.assert_array_equal(out.airlight, ref.airlight)


def test_a_known_airlight_replaces_the_estimate_where_no_pixel_is_opaque():
    """Indoors no pixel is opaque haze, so the brightest dark-channel pixels are surfaces seen
    through part of the haze: their colour is dimmer than the light, and t comes out too low. With
    the light given, t is the prior's own (within the guided filter's smoothing)."""
    j = clean_texture(seed=3)
    t = np.linspace(0.7, 0.35, H, dtype=np.float32)[:, None].repeat(W, axis=1)  # [H, W], never opaque
    i = (j * t[..., None] + AIRLIGHT * (1 - t[..., None])).astype(np.float32)
    estimated = estimate_dcp(i, omega=1.0)
    given = estimate_dcp(i, omega=1.0, airlight=AIRLIGHT)
    np.testing.assert_array_equal(given.airlight, AIRLIGHT)
    assert given.airlight.dtype == np.float32
    assert (estimated.airlight < AIRLIGHT - 0.05).all()  # the estimate is too dim here
    err_estimated = np.abs(estimated.transmittance - t).mean()
    err_given = np.abs(given.transmittance - t).mean()
    assert err_given < 0.03 < err_estimated
    # the raw dark channel is the input's, whichever light is used
    np.testing.assert_array_equal(given.dark, estimated.dark)


@pytest.mark.parametrize(
    "shape,patch", [((240, 320), 7), ((72, 96), 3), ((5, 3), 7), ((1, 1), 3), ((31, 17), 15)]
)
def test_min_filter_equals_max_pool(shape: tuple[int, int], patch: int) -> None:
    """The separable doubling min filter gives max_pool2d's min exactly, borders and patches
    larger than the image included (it replaced max_pool2d in the per-step bound)."""
    x = torch.rand(*shape, generator=torch.Generator().manual_seed(patch))
    x[0, 0] = 0.5  # ties between neighbours
    if x.numel() > 1:
        x.view(-1)[1] = 0.5
    ref = -F.max_pool2d(-x[None, None], patch, stride=1, padding=patch // 2)[0, 0]
    assert torch.equal(min_filter(x, patch), ref)


def test_transmittance_loss_weight_scales_each_pixel_and_keeps_the_mask_count(device):
    """A per-pixel weight multiplies a pixel's penalty; the mean stays over the mask's pixels."""
    t = torch.tensor([[0.1, 0.4], [0.6, 0.9]], device=device)
    t_dcp = torch.full((2, 2), 1.0, device=device)
    w = torch.tensor([[0.5, 1.0], [0.0, 2.0]], device=device)
    sq = (1.0 - t) ** 2
    assert dcp_transmittance_loss(t, t_dcp, weight=w).item() == pytest.approx((sq * w).sum().item() / 4)
    mask = torch.tensor([[True, True], [False, False]], device=device)
    expected = (sq * w)[0].sum().item() / 2  # two masked pixels, their weights 0.5 and 1
    assert dcp_transmittance_loss(t, t_dcp, mask, weight=w).item() == pytest.approx(expected)
    assert dcp_transmittance_loss(t, t_dcp, mask, weight=torch.ones_like(w)).item() == pytest.approx(
        dcp_transmittance_loss(t, t_dcp, mask).item()
    )
