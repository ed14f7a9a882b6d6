"""Pearson depth loss and edge-aware smoothness: invariances, masking, gradients."""

from __future__ import annotations

import math

import pytest
import torch

from components.losses.depth import edge_aware_smoothness, pearson_depth_loss, trimmed_pearson_depth_loss


@pytest.fixture
def prior(device) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)  # drawn on the cpu: the same values on every device
    return torch.rand(24, 32, generator=g).to(device) * 10 + 1  # [H, W]


@pytest.mark.parametrize("a,b", [(1.0, 0.0), (3.0, -2.0), (0.01, 100.0)])
def test_pearson_zero_for_positive_affine(prior, a, b):
    assert pearson_depth_loss(a * prior + b, prior).item() == pytest.approx(0.0, abs=1e-5)


def test_pearson_two_for_negative_affine(prior):
    assert pearson_depth_loss(-2.0 * prior + 5.0, prior).item() == pytest.approx(2.0, abs=1e-5)


def test_pearson_invariant_to_scale_and_shift_of_either_input(prior):
    pred = prior + torch.randn(prior.shape, generator=torch.Generator().manual_seed(1)).to(prior.device) * 3
    base = pearson_depth_loss(pred, prior)
    assert 0.05 < base.item() < 1.0
    assert pearson_depth_loss(7 * pred + 3, prior).item() == pytest.approx(base.item(), abs=1e-5)
    assert pearson_depth_loss(pred, 0.1 * prior - 4).item() == pytest.approx(base.item(), abs=1e-5)


def test_pearson_ignores_masked_and_nonfinite_pixels(prior):
    pred = prior.clone()
    mask = torch.ones_like(prior, dtype=torch.bool)
    mask[:, :8] = False
    pred[:, :8] = -1000.0  # garbage where masked
    noisy_prior = prior.clone()
    noisy_prior[0, 10] = float("nan")  # ignored without a mask entry
    assert pearson_depth_loss(pred, noisy_prior, mask).item() == pytest.approx(0.0, abs=1e-5)
    assert pearson_depth_loss(pred, noisy_prior).item() > 0.5


def test_trimmed_pearson_drops_a_few_prior_outliers(prior):
    """5 % of the prior's pixels far off (SfM mismatches): the plain correlation sees them, a
    trim of 10 % leaves them out and the rendered depth that follows the true surface scores 0."""
    pred = 2.0 * prior + 1.0  # the render follows the true surface
    bad = prior.clone()
    g = torch.Generator().manual_seed(3)
    idx = torch.randperm(prior.numel(), generator=g)[: prior.numel() // 20].to(prior.device)
    bad.view(-1)[idx] = 60.0  # outliers well beyond the true range [1, 11]
    mask = torch.ones_like(prior, dtype=torch.bool)
    mask[0, :4] = False
    assert pearson_depth_loss(pred, bad, mask).item() > 0.3
    assert trimmed_pearson_depth_loss(pred, bad, mask, trim=0.1).item() == pytest.approx(0.0, abs=1e-4)


def test_trimmed_pearson_without_trim_is_pearson(prior):
    pred = prior + torch.randn(prior.shape, generator=torch.Generator().manual_seed(4)).to(prior.device)
    assert trimmed_pearson_depth_loss(pred, prior, trim=0.0).item() == pytest.approx(
        pearson_depth_loss(pred, prior).item(), abs=1e-7
    )


def test_trimmed_pearson_gradient_reaches_the_kept_pixels_only(prior):
    pred = prior + torch.randn(prior.shape, generator=torch.Generator().manual_seed(5)).to(prior.device)
    pred[2, 3] = 500.0  # the worst residual: trimmed
    pred.requires_grad_()
    trimmed_pearson_depth_loss(pred, prior, trim=0.2).backward()
    assert torch.isfinite(pred.grad).all()
    assert pred.grad[2, 3].item() == 0.0
    assert (pred.grad != 0).float().mean().item() > 0.7  # about 80 % of the pixels kept


def test_pearson_gradient_finite_and_nonzero(prior):
    noise = torch.randn(prior.shape, generator=torch.Generator().manual_seed(2)).to(prior.device)
    pred = (prior + noise).requires_grad_()
    pearson_depth_loss(pred, prior).backward()
    assert torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0


def test_pearson_degenerate_inputs_are_finite(prior):
    const = torch.full_like(prior, 3.0, requires_grad=True)
    loss = pearson_depth_loss(const, prior)
    loss.backward()
    assert loss.item() == pytest.approx(1.0, abs=1e-4)
    assert torch.isfinite(const.grad).all()

    pred = prior.clone().requires_grad_()
    few = torch.zeros_like(prior, dtype=torch.bool)
    few[0, :5] = True  # too few pixels -> 0, still differentiable
    loss = pearson_depth_loss(pred, prior, few)
    loss.backward()
    assert loss.item() == 0.0 and torch.isfinite(pred.grad).all()


def _step(device: torch.device, h: int = 16, w: int = 16) -> torch.Tensor:
    d = torch.ones(h, w, device=device)
    d[:, w // 2 :] = 2.0  # a vertical depth step
    return d


def test_smoothness_zero_for_constant_depth(device):
    img = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(3)).to(device)
    assert edge_aware_smoothness(torch.full((16, 16), 4.0, device=device), img).item() == pytest.approx(0.0)


def test_smoothness_cheaper_across_image_edge(device):
    flat = torch.full((16, 16, 3), 0.5, device=device)
    edge = flat.clone()
    edge[:, 8:] = 1.0  # image edge at the same column as the depth step
    d = _step(device)
    assert edge_aware_smoothness(d, edge).item() < 0.1 * edge_aware_smoothness(d, flat).item()


def test_smoothness_scale_invariant_masked_and_differentiable(device):
    img = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(4)).to(device)
    d = _step(device) + torch.rand(16, 16, generator=torch.Generator().manual_seed(5)).to(device)
    base = edge_aware_smoothness(d, img)
    assert edge_aware_smoothness(10 * d, img).item() == pytest.approx(base.item(), rel=1e-5)
    mask = torch.zeros(16, 16, dtype=torch.bool, device=device)
    mask[:, :8] = True
    masked = edge_aware_smoothness(_step(device), torch.full((16, 16, 3), 0.5, device=device), mask)
    assert masked.item() == pytest.approx(0.0)  # the step lies outside the mask
    dg = d.clone().requires_grad_()
    edge_aware_smoothness(dg, img).backward()
    assert torch.isfinite(dg.grad).all() and dg.grad.abs().sum() > 0


def test_log_depth_l1_is_the_mean_relative_error_over_valid_pixels():
    from components.losses.depth import MIN_VALID_PIXELS, log_depth_l1

    prior = torch.full((8, 8), 2.0)
    prior[0, :4] = float("inf")  # not a prior pixel
    prior[1, :4] = 0.0  # nor this
    mask = torch.ones(8, 8, dtype=torch.bool)
    mask[7] = False
    pred = torch.full((8, 8), 2.0, requires_grad=True)
    with torch.no_grad():
        pred[2:4] = 2.0 * math.e  # ln error 1 on 16 pixels
        pred[7] = 100.0  # masked out
    loss = log_depth_l1(pred, prior, mask)
    n_valid = 64 - 8 - 8  # minus the bad prior pixels and the masked row
    assert loss.item() == pytest.approx(16 / n_valid, rel=1e-5)
    loss.backward()
    assert (
        torch.isfinite(pred.grad).all()
        and pred.grad[7].abs().sum() == 0
        and pred.grad[0, :4].abs().sum() == 0
    )
    # same relative error whatever the scale: the loss is on ln z
    assert log_depth_l1(pred.detach() * 10, prior * 10, mask).item() == pytest.approx(loss.item(), rel=1e-5)
    few = torch.zeros(8, 8, dtype=torch.bool)
    few.view(-1)[: MIN_VALID_PIXELS - 1] = True
    assert log_depth_l1(pred, prior, few).item() == 0.0


def _two_gaussians(z_back: float) -> dict:
    """Two large, nearly opaque Gaussians straight ahead of a camera at the origin, at z 2 and z_back."""
    means = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, z_back]], requires_grad=True)
    return {
        "means": means,
        "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2),
        "scales": torch.full((2, 3), 1.0),
        "opacities": torch.tensor([0.6, 0.9]),
    }


def _spread(g: dict) -> torch.Tensor:
    from components.losses.depth import depth_spread
    from components.rasterizers.torch_reference import TorchRasterizer

    rast = TorchRasterizer()
    K = torch.tensor([[[20.0, 0.0, 8.0], [0.0, 20.0, 8.0], [0.0, 0.0, 1.0]]])  # [1, 3, 3]
    view = torch.eye(4)[None]  # [1, 4, 4]
    z = g["means"][:, 2]  # [2] camera z (identity view)
    values = torch.stack([torch.ones_like(z), z, z * z], -1)  # [2, 3]
    args = (g["means"], g["quats"], g["scales"], g["opacities"], values, view, K, 16, 16)
    return depth_spread(rast.rasterize(*args, background=torch.zeros(3)).rgb[0])


def test_depth_spread_is_zero_on_one_surface_and_grows_with_the_gap():
    one = _spread(_two_gaussians(2.0))
    near, far = _spread(_two_gaussians(2.5)), _spread(_two_gaussians(4.0))
    assert one.item() == pytest.approx(0.0, abs=1e-5)
    assert 0.0 < near.item() < far.item()
    # two point depths with blend weights a, b: Var / E^2 = a b (z1 - z2)^2 / (a z1 + b z2)^2, a + b = 1;
    # at the image centre a = 0.6 / (0.6 + 0.4 * 0.9), b = 0.36 / 0.96; the mean over pixels is lower
    a, b = 0.6 / 0.96, 0.36 / 0.96
    centre = a * b * 4.0 / (a * 2.0 + b * 4.0) ** 2
    assert 0.3 * centre < far.item() <= centre * 1.001


def test_depth_spread_gradient_draws_the_gaussians_together():
    g = _two_gaussians(4.0)
    _spread(g).backward()
    dz = g["means"].grad[:, 2]
    assert dz[0] < 0 < dz[1]  # descent moves the front one back and the back one forward
