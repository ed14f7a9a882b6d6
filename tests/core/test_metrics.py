"""PSNR/SSIM used in training readouts and evaluation."""

from __future__ import annotations

import math

import pytest
import torch

from pipelines.engine.metrics import psnr, ssim


def test_psnr_known_value_and_identity():
    a = torch.zeros(8, 8, 3)
    b = torch.full((8, 8, 3), 0.1)  # mse 0.01 -> 20 dB
    assert math.isclose(float(psnr(b, a)), 20.0, rel_tol=1e-5)
    assert float(psnr(a, a)) == 100.0


def test_ssim_identity_and_monotone_in_noise():
    g = torch.Generator().manual_seed(0)
    img = torch.rand(40, 50, 3, generator=g)
    assert math.isclose(float(ssim(img, img)), 1.0, abs_tol=1e-5)
    noise = torch.randn(40, 50, 3, generator=g)
    values = [float(ssim((img + s * noise).clamp(0, 1), img)) for s in (0.02, 0.1, 0.3)]
    assert values[0] > values[1] > values[2]


def test_step_diagnostics_are_read_back_in_one_transfer_with_the_same_values():
    """The trainer's ``scalars``: tensors and floats mixed, values exactly what ``float()`` gives."""
    from pipelines.engine.trainer import scalars

    vals = {"loss": torch.tensor(0.1234567, dtype=torch.float32), "psnr": 27.5, "t": torch.tensor([0.3])}
    out = scalars(vals)
    assert out == {"loss": float(vals["loss"]), "psnr": 27.5, "t": float(vals["t"])}
    assert all(type(v) is float for v in out.values())
    assert scalars({"n": 3}) == {"n": 3.0}


def test_ssim_fits_its_window_to_tiny_images():
    import kornia

    from components.losses.reconstruction import L1SSIMLoss, ReconstructionLossConfig
    from components.metrics.ssim import fitted_window

    assert [fitted_window(11, s, 40) for s in (1, 2, 3, 4, 5, 6, 30)] == [1, 3, 5, 7, 9, 11, 11]
    torch.manual_seed(0)
    for h, w in ((1, 7), (2, 2), (4, 5), (5, 9)):  # kornia's own 11x11 window fails on all of these
        a, b = torch.rand(h, w, 3), torch.rand(h, w, 3)
        assert float(ssim(a, a)) == pytest.approx(1.0, abs=1e-5)
        assert float(ssim(a, b)) < 0.9
        loss, _ = L1SSIMLoss(ReconstructionLossConfig())(a.requires_grad_(), b)
        loss.backward()
        assert torch.isfinite(a.grad).all()
    a, b = torch.rand(6, 9, 3), torch.rand(6, 9, 3)  # from 6 pixels a side: kornia's result, untouched
    ref = kornia.metrics.ssim(a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None], 11).mean()
    assert float(ssim(a, b)) == pytest.approx(float(ref), abs=1e-6)
