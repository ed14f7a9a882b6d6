"""The coverage entropy: zero at 0 and 1, ln 2 at one half, and its gradient picks the near side."""

from __future__ import annotations

import math

import pytest
import torch

from components.losses.coverage import coverage_entropy


def test_values_at_the_ends_and_the_middle():
    assert float(coverage_entropy(torch.tensor([0.0, 1.0]))) == pytest.approx(0.0, abs=2e-3)
    assert float(coverage_entropy(torch.full((4, 5, 1), 0.5))) == pytest.approx(math.log(2.0), abs=1e-6)
    a = torch.tensor([0.2, 0.9])
    expected = -sum(float(x * math.log(x) + (1 - x) * math.log(1 - x)) for x in a) / 2
    assert float(coverage_entropy(a)) == pytest.approx(expected, rel=1e-5)


def test_gradient_pushes_each_pixel_to_its_nearer_end():
    a = torch.tensor([0.1, 0.4, 0.6, 0.95], requires_grad=True)
    coverage_entropy(a).backward()
    g = a.grad
    assert g[0] > 0 and g[1] > 0  # descent lowers coverage below one half
    assert g[2] < 0 and g[3] < 0  # and raises it above
    b = torch.tensor([0.0, 1.0], requires_grad=True)
    coverage_entropy(b).backward()
    assert torch.isfinite(b.grad).all()
