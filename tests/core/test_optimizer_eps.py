"""Per-group Adam epsilon: a component's own epsilon reaches its optimizer, and slows a parameter
whose gradient is far below it while leaving one whose gradient is far above it at Adam's rate."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from pipelines.engine.optimizers import OptimizerConfig, Optimizers


def _groups() -> dict[str, tuple[nn.Parameter, float]]:
    return {"weak": (nn.Parameter(torch.zeros(4)), 0.01), "strong": (nn.Parameter(torch.zeros(4)), 0.01)}


def test_group_eps_reaches_its_optimizer_only() -> None:
    opts = Optimizers(_groups(), OptimizerConfig(), max_steps=10, eps={"weak": 1e-6})
    assert opts.optimizers["weak"].param_groups[0]["eps"] == 1e-6
    assert opts.optimizers["strong"].param_groups[0]["eps"] == 1e-15


def test_unknown_group_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown parameter groups"):
        Optimizers(_groups(), OptimizerConfig(), max_steps=10, eps={"medium.features": 1e-6})


@pytest.mark.parametrize("eps, weak_ratio", [(1e-15, 1.0), (1e-6, 0.01)])
def test_eps_slows_only_the_weakly_pulled(eps: float, weak_ratio: float) -> None:
    groups = _groups()
    opts = Optimizers(groups, OptimizerConfig(), max_steps=10, eps={"weak": eps, "strong": eps})
    weak, strong = groups["weak"][0], groups["strong"][0]
    for _ in range(5):
        opts.zero_grad()
        weak.grad = torch.full_like(weak, 1e-8)  # a gradient 100x below 1e-6
        strong.grad = torch.full_like(strong, 1e-3)  # 1000x above it
        opts.step()
    moved_weak, moved_strong = float(weak.detach().abs().max()), float(strong.detach().abs().max())
    assert moved_strong == pytest.approx(0.05, rel=1e-3)  # 5 steps at the rate (Adam's sign-like step)
    assert moved_weak / moved_strong == pytest.approx(weak_ratio, rel=0.05)


def test_scales_multiply_the_named_groups_base_rate_and_return_to_it() -> None:
    """A pipeline's ``lr_scales``: the named group at its base rate times the factor, the others as
    they were, and a factor of 1 restores the base rate (the scales are a function of the step)."""
    opts = Optimizers(_groups(), OptimizerConfig(), max_steps=10)
    opts.schedule(3, {"weak": 3.0})
    assert opts.optimizers["weak"].param_groups[0]["lr"] == pytest.approx(0.03)
    assert opts.optimizers["strong"].param_groups[0]["lr"] == pytest.approx(0.01)
    opts.schedule(4, {"weak": 1.0})
    assert opts.optimizers["weak"].param_groups[0]["lr"] == pytest.approx(0.01)
    with pytest.raises(ValueError, match="unknown parameter groups"):
        opts.schedule(5, {"medium.features": 2.0})
