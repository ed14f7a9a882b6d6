"""The coarse-to-fine medium: the grid low-pass, its schedule, the fields' hook and the pipeline's use."""

from __future__ import annotations

import math

import pytest
import torch

import components.medium  # noqa: F401  (registers the backends)
from components.medium.band_limit import blur_grid, coarse_to_fine_sigma, gaussian_kernel
from components.medium.base import FieldBounds, MediumConfig
from tridehaze_plugin.errors import ConfigError

BOUNDS = FieldBounds(torch.zeros(3), torch.ones(3))


def test_kernel_is_normalised_and_three_sigma_wide():
    k = gaussian_kernel(2.0)
    assert len(k) == 2 * 6 + 1
    assert float(k.sum()) == pytest.approx(1.0, abs=1e-6)
    assert int(k.argmax()) == 6


@pytest.mark.parametrize("shape", [(3, 4, 16, 16), (1, 2, 6, 7, 8)])
def test_blur_keeps_a_constant_grid_and_the_mean_of_any(shape):
    const = torch.full(shape, 0.37)
    assert torch.allclose(blur_grid(const, 3.0), const, atol=1e-6)  # the border is replicated
    g = torch.randn(shape, generator=torch.Generator().manual_seed(0))
    out = blur_grid(g, 1.5)
    assert out.shape == g.shape
    # interior mean preserved to the border's share; the noise's variance falls
    assert float(out.std()) < 0.5 * float(g.std())


def test_blur_removes_a_checker_but_keeps_a_smooth_ramp():
    x = torch.arange(32.0)
    checker = ((x[:, None] + x[None, :]) % 2)[None, None]  # [1, 1, 32, 32] the finest pattern
    assert float(blur_grid(checker, 2.0)[..., 8:-8, 8:-8].std()) < 1e-3
    ramp = (x[:, None] / 31.0).expand(32, 32)[None, None]  # [1, 1, 32, 32] linear in one axis
    inner = (slice(None), slice(None), slice(8, -8), slice(8, -8))
    assert torch.allclose(blur_grid(ramp, 2.0)[inner], ramp[inner], atol=1e-5)


def test_zero_sigma_is_the_identity_and_the_gradient_is_blurred():
    g = torch.randn(1, 1, 12, 12, requires_grad=True)
    assert blur_grid(g, 0.0) is g
    blur_grid(g, 2.0)[0, 0, 6, 6].backward()
    grad = g.grad[0, 0]
    assert float(grad.sum()) == pytest.approx(1.0, abs=1e-5)  # one cell's value, spread out
    assert (grad > 0).sum() > 25 and float(grad.max()) < 0.1


def test_blur_rejects_a_flat_tensor():
    with pytest.raises(ValueError, match="grid"):
        blur_grid(torch.zeros(4, 4), 1.0)


def test_schedule_holds_then_falls_linearly_to_zero():
    assert coarse_to_fine_sigma(0, 100, 300, 4.0) == 4.0
    assert coarse_to_fine_sigma(100, 100, 300, 4.0) == 4.0
    assert coarse_to_fine_sigma(200, 100, 300, 4.0) == pytest.approx(2.0)
    assert coarse_to_fine_sigma(300, 100, 300, 4.0) == 0.0
    assert coarse_to_fine_sigma(5000, 100, 300, 4.0) == 0.0
    assert coarse_to_fine_sigma(150, 100, 300, 0.0) == 0.0  # off


@pytest.mark.parametrize("backend", ["triplane", "voxel"])
def test_grid_fields_band_limit_their_lookup(backend):
    torch.manual_seed(0)
    field = MediumConfig(backend=backend).setup(BOUNDS)
    assert field.band_limits
    with torch.no_grad():  # let the features show in beta
        field.heads.beta_head[-1].weight.normal_(0.0, 1.0)
    x = torch.rand(400, 3, generator=torch.Generator().manual_seed(1)) * 2 - 1  # [P, 3]
    d = torch.nn.functional.normalize(torch.randn(400, 3), dim=-1)
    sharp = field(x, d).beta
    field.set_band_limit(3.0)
    smooth = field(x, d).beta
    assert float(smooth.detach().std()) < 0.5 * float(sharp.detach().std())  # random features averaged away
    state = field.state_dict()
    assert float(state["band_sigma"]) == 3.0  # saved with a checkpoint
    field.set_band_limit(0.0)
    assert torch.equal(field(x, d).beta, sharp)
    del state["band_sigma"]  # a checkpoint from before the band limit loads as none
    field.load_state_dict(state)
    assert float(field.band_sigma) == 0.0


@pytest.mark.parametrize("backend", ["mlp", "fourier", "constant", "none"])
def test_fields_without_a_grid_say_so(backend):
    field = MediumConfig(backend=backend).setup(BOUNDS)
    assert not field.band_limits
    with pytest.raises(NotImplementedError, match="band-limit"):
        field.set_band_limit(1.0)


def test_pipeline_anneals_the_blur_over_the_medium_learning(tmp_path):
    from tests.tiny_scenes import tiny_hazy_scene, tiny_pipeline

    scene = tiny_hazy_scene(tmp_path / "s", layout="street", haze="patchy", seed=4)
    p = tiny_pipeline(scene, tmp_path / "on", "--pipeline.medium-coarse-to-fine", "3", max_steps=200)
    hold, freeze = p.hold_steps, p.freeze_step
    end = hold + round(0.5 * (freeze - hold))
    assert hold < end < freeze
    p.train_loss(hold)
    assert float(p.medium.band_sigma) == pytest.approx(3.0)
    mid = (hold + end) // 2
    p.train_loss(mid)
    assert float(p.medium.band_sigma) == pytest.approx(3.0 * (end - mid) / (end - hold))
    p.train_loss(end)
    assert float(p.medium.band_sigma) == 0.0
    off = tiny_pipeline(scene, tmp_path / "off", max_steps=200)
    off.train_loss(hold)
    assert float(off.medium.band_sigma) == 0.0
    assert math.isfinite(float(off.train_loss(mid).loss))


def test_pipeline_refuses_the_blur_on_a_medium_without_a_grid(tmp_path):
    from tests.tiny_scenes import tiny_hazy_scene, tiny_pipeline

    scene = tiny_hazy_scene(tmp_path / "s", layout="street", haze="patchy", seed=4)
    with pytest.raises(ConfigError, match="coarse-to-fine"):
        tiny_pipeline(
            scene,
            tmp_path / "mlp",
            "--pipeline.medium.backend",
            "mlp",
            "--pipeline.medium-coarse-to-fine",
            "2",
        )


def test_the_freeze_blur_holds_from_the_freeze_and_comes_back_with_a_checkpoint(tmp_path):
    from tests.tiny_scenes import tiny_hazy_scene, tiny_pipeline

    scene = tiny_hazy_scene(tmp_path / "s", layout="street", haze="patchy", seed=4)
    p = tiny_pipeline(scene, tmp_path / "on", "--pipeline.medium-freeze-blur", "1.5", max_steps=200)
    freeze = p.freeze_step
    p.train_loss(freeze - 1)
    assert float(p.medium.band_sigma) == 0.0  # Stage I learns unblurred
    beta_sharp = p.medium(*_probe_points(p)).beta.detach()
    p.train_loss(freeze)
    assert float(p.medium.band_sigma) == pytest.approx(1.5)
    beta_blurred = p.medium(*_probe_points(p)).beta.detach()
    assert not torch.allclose(beta_sharp, beta_blurred)  # the lookup is low-passed
    p.train_loss(freeze + 5)
    assert float(p.medium.band_sigma) == pytest.approx(1.5)
    resumed = tiny_pipeline(scene, tmp_path / "again", "--pipeline.medium-freeze-blur", "1.5", max_steps=200)
    resumed.load_state_dict(p.state_dict())
    assert float(resumed.medium.band_sigma) == pytest.approx(1.5)  # renders after training see it
    with pytest.raises(ConfigError, match="freeze-blur"):
        tiny_pipeline(
            scene, tmp_path / "mlp", "--pipeline.medium.backend", "mlp", "--pipeline.medium-freeze-blur", "1"
        )


def _probe_points(p) -> tuple[torch.Tensor, torch.Tensor]:
    """Points [P, 3] spread over the medium's box and view directions [P, 3]."""
    gen = torch.Generator().manual_seed(0)
    x = p.medium.bounds_center + (torch.rand(256, 3, generator=gen) * 2 - 1) * p.medium.bounds_half
    return x, torch.nn.functional.normalize(torch.randn(256, 3, generator=gen), dim=-1)
