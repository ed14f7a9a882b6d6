"""The opacity entropy prior: its values, and that its gradient moves opacities away from 1/2."""

from __future__ import annotations

import math

import pytest
import torch

from components.losses.opacity import opacity_entropy


def test_entropy_is_ln2_at_half_and_zero_at_the_ends():
    assert opacity_entropy(torch.full((5,), 0.5)).item() == pytest.approx(math.log(2.0), rel=1e-6)
    assert opacity_entropy(torch.tensor([0.0, 1.0, 0.0])).item() < 1e-4  # clamped, finite
    assert opacity_entropy(torch.empty(0)).item() == 0.0


def test_a_gradient_step_moves_each_opacity_towards_its_nearer_end():
    logits = torch.tensor([-2.0, -0.1, 0.1, 2.0], requires_grad=True)
    opacity_entropy(torch.sigmoid(logits)).backward()
    stepped = logits.detach() - 10.0 * logits.grad
    assert (stepped.abs() > logits.detach().abs()).all()  # every opacity further from 1/2
    assert torch.equal(torch.sign(stepped), torch.sign(logits.detach()))
