"""Gradient policies: the forward pass never changes; the gradient entering J is scaled by 1/clamp(T)."""

from __future__ import annotations

import pytest
import torch

from components.gradients.policies import MDTGC, TGC, GradientPolicy, ScaleGradient, compensation
from tridehaze_plugin.registry import REGISTRY

F64 = torch.float64


def _compose(policy: GradientPolicy, stage: int, device: torch.device, seed: int = 0):
    g = torch.Generator().manual_seed(seed)  # drawn on the cpu: the same values on every device
    J = torch.rand(8, 9, 3, generator=g, dtype=F64).to(device).requires_grad_(True)
    T = torch.rand(8, 9, 1, generator=g, dtype=F64).to(device) * 0.98 + 0.01
    T[0, 0] = 1e-4  # far below t_min
    T = T.requires_grad_(True)
    S = torch.rand(8, 9, 3, generator=g, dtype=F64).to(device).requires_grad_(True)
    w = torch.randn(8, 9, 3, generator=g, dtype=F64).to(device)
    out = policy.apply(J, T, stage) * T + S
    (out * w).sum().backward()
    return out.detach(), J.grad, T.grad, S.grad


@pytest.mark.parametrize("stage", [1, 2])
def test_forward_identical_across_policies(device, stage):
    outs = [_compose(cls(0.1), stage, device)[0] for cls in (GradientPolicy, TGC, MDTGC)]
    assert torch.equal(outs[0], outs[1]) and torch.equal(outs[0], outs[2])


def test_gradient_ratio_is_exactly_inverse_clamped_transmittance(device):
    t_min = 0.1
    _, gJ_none, gT_none, gS_none = _compose(GradientPolicy(t_min), 2, device)
    _, gJ_tgc, gT_tgc, gS_tgc = _compose(TGC(t_min), 2, device)
    g = torch.Generator().manual_seed(0)
    torch.rand(8, 9, 3, generator=g, dtype=F64)
    T = torch.rand(8, 9, 1, generator=g, dtype=F64).to(device) * 0.98 + 0.01
    T[0, 0] = 1e-4
    expected = 1.0 / T.clamp(min=t_min)
    torch.testing.assert_close(gJ_tgc, gJ_none * expected, rtol=1e-12, atol=0)
    # only J's gradient changes
    assert torch.equal(gT_tgc, gT_none) and torch.equal(gS_tgc, gS_none)
    assert float(expected.max()) == pytest.approx(1 / t_min)


def test_md_tgc_only_in_stage_two(device):
    _, g_none, _, _ = _compose(GradientPolicy(0.1), 1, device)
    _, g_md1, _, _ = _compose(MDTGC(0.1), 1, device)
    _, g_md2, _, _ = _compose(MDTGC(0.1), 2, device)
    assert torch.equal(g_md1, g_none)
    assert not torch.allclose(g_md2, g_none)
    assert TGC(0.1).active(1) and TGC(0.1).active(2) and not GradientPolicy(0.1).active(2)


def test_scale_gradient_identity_forward_and_no_grad_to_scale(device):
    x = torch.randn(5, dtype=F64, device=device, requires_grad=True)
    scale = torch.full((5,), 3.0, dtype=F64, device=device, requires_grad=True)
    y = ScaleGradient.apply(x, scale)
    assert torch.equal(y, x)
    y.sum().backward()
    assert torch.equal(x.grad, torch.full((5,), 3.0, dtype=F64, device=device))
    assert scale.grad is None


def test_compensation_is_detached_and_bounded(device):
    T = torch.tensor([0.0, 0.05, 0.5, 1.0], device=device, requires_grad=True)
    c = compensation(T, 0.1)
    assert not c.requires_grad
    torch.testing.assert_close(c, torch.tensor([10.0, 10.0, 2.0, 1.0], device=device))


def test_registered_and_t_min_checked():
    for name, cls in (("none", GradientPolicy), ("tgc", TGC), ("md-tgc", MDTGC)):
        assert REGISTRY.get("gradient_policy", name) is cls
    with pytest.raises(ValueError, match="t_min"):
        TGC(0.0)
