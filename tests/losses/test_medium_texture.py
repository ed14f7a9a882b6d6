"""The medium-texture prior (`--pipeline.lambda-path-extinction`): zero for a homogeneous medium
whatever the geometry, blind to depth edges and to rays that leave the scene, scale-free, and its
gradient flattens a texture in the medium; in the pipeline only when weighted and while the
medium learns."""

from __future__ import annotations

import pytest
import torch

from components.losses.medium_texture import path_extinction_roughness


def _rough(T: torch.Tensor, z: torch.Tensor, surface: torch.Tensor | None = None) -> torch.Tensor:
    return path_extinction_roughness(
        T, z, torch.ones_like(z, dtype=torch.bool) if surface is None else surface, 0.05
    )


def _ramp(h: int = 12, w: int = 16) -> torch.Tensor:
    """[H, W] end depths of a floor receding from 2 to 6 (smooth, no edge)."""
    return torch.linspace(2.0, 6.0, h)[:, None].expand(h, w).contiguous()


def test_homogeneous_medium_costs_nothing_on_any_geometry():
    z = _ramp()
    z[:, 8:] = 20.0  # a depth edge too
    T = torch.exp(-0.3 * z)
    assert _rough(T, z).item() == pytest.approx(0.0, abs=1e-10)


def test_texture_costs_and_scale_does_not_matter():
    z = torch.full((12, 16), 4.0)
    checker = ((torch.arange(12)[:, None] + torch.arange(16)[None]) % 2).float()  # [H, W]
    beta = 0.2 * (1.0 + 0.2 * checker)
    thin = _rough(torch.exp(-beta * z), z)
    dense = _rough(torch.exp(-5.0 * beta * z), z)
    # relative to the mean 1.1: every adjacent pair differs by 0.2 / 1.1
    assert thin.item() == pytest.approx((0.2 / 1.1) ** 2, rel=1e-4)
    assert dense.item() == pytest.approx(thin.item(), rel=1e-4)


def test_a_depth_edge_may_change_the_medium():
    z = torch.full((12, 16), 4.0)
    z[:, 8:] = 8.0
    beta = torch.full((12, 16), 0.2)
    beta[:, 8:] = 0.5  # the far rays cross other haze
    assert _rough(torch.exp(-beta * z), z).item() == pytest.approx(0.0, abs=1e-10)
    z[:, 8:] = 4.1  # but not across a step under the threshold
    assert _rough(torch.exp(-beta * z), z).item() > 0.01


def test_a_global_scale_of_the_medium_gets_no_gradient():
    z = _ramp()
    checker = ((torch.arange(12)[:, None] + torch.arange(16)[None]) % 2).float()
    scale = torch.tensor(1.0, requires_grad=True)
    rough = _rough(torch.exp(-scale * 0.2 * (1.0 + 0.2 * checker) * z), z)
    rough.backward()
    assert rough.item() > 0.01 and abs(scale.grad.item()) < 1e-6 * rough.item()


def test_rays_that_leave_the_scene_are_not_held():
    z = torch.full((12, 16), 4.0)
    beta = torch.full((12, 16), 0.2)
    sky = torch.zeros(12, 16, dtype=torch.bool)
    sky[:4] = True
    beta[:4] = 0.2 * (1.0 + 0.5 * (torch.arange(16) % 2))  # the sky's haze varies, at the same far z
    T = torch.exp(-beta * z)
    assert _rough(T, z).item() > 0.01
    assert _rough(T, z, ~sky).item() == pytest.approx(0.0, abs=1e-10)


def test_gradient_flattens_the_texture():
    z = torch.full((8, 8), 3.0)
    checker = ((torch.arange(8)[:, None] + torch.arange(8)[None]) % 2).float()
    beta = (0.2 + 0.05 * checker).requires_grad_(True)
    _rough(torch.exp(-beta * z), z).backward()
    g = beta.grad
    # descent thins the denser cells and thickens the thinner ones
    assert (g[checker == 1] > 0).all() and (g[checker == 0] < 0).all()


def test_pipeline_adds_the_term_only_when_weighted_and_learning(tmp_path):
    from tests.tiny_scenes import tiny_hazy_scene, tiny_pipeline

    scene = tiny_hazy_scene(tmp_path / "s", layout="street", haze="patchy", seed=4)

    def pipeline(out: str, *extra: str):
        return tiny_pipeline(scene, tmp_path / out, *extra)

    off = pipeline("off")
    learning = off.hold_steps + 1
    assert "path_extinction" not in off.train_loss(learning).metrics
    on = pipeline("on", "--pipeline.lambda-path-extinction", "1")
    assert "path_extinction" not in on.train_loss(0).metrics  # the medium's hold
    assert on.hold_steps < learning < on.freeze_step
    res = on.train_loss(learning)
    assert float(res.metrics["path_extinction"]) > 0.0
    assert "path_extinction" not in on.train_loss(on.freeze_step).metrics  # frozen
