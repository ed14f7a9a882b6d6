"""PSNR/SSIM used in training readouts and evaluation."""

from __future__ import annotations

import math

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
