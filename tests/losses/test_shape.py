"""The needle penalty (`--pipeline.lambda-elongation`): zero for spheres and discs, grows with a
needle's excess, shortens it; in the pipeline only when weighted."""

from __future__ import annotations

import math

import pytest
import torch

from components.losses.shape import elongation_penalty


def _log(*scales: float) -> torch.Tensor:
    return torch.tensor([scales], dtype=torch.float32).log()  # [1, 3]


@pytest.mark.parametrize("scales", [(1.0, 1.0, 1.0), (1.0, 1.0, 1e-4), (5.0, 1.0, 1.0), (10.0, 1.0, 0.01)])
def test_zero_within_the_ratio_and_for_discs(scales):
    assert elongation_penalty(_log(*scales), 10.0).item() == pytest.approx(0.0, abs=1e-6)


def test_excess_in_log_space_whatever_the_axis_order():
    for order in ((100.0, 1.0, 0.5), (0.5, 100.0, 1.0), (1.0, 0.5, 100.0)):
        assert elongation_penalty(_log(*order), 10.0).item() == pytest.approx(math.log(10.0), rel=1e-5)


def test_mean_over_gaussians_and_empty_model():
    both = torch.cat([_log(100.0, 1.0, 1.0), _log(1.0, 1.0, 1.0)])  # [2, 3]
    assert elongation_penalty(both, 10.0).item() == pytest.approx(math.log(10.0) / 2, rel=1e-5)
    empty = torch.zeros(0, 3, requires_grad=True)
    loss = elongation_penalty(empty, 10.0)
    loss.backward()
    assert loss.item() == 0.0 and empty.grad is not None


def test_gradient_shortens_the_long_axis_and_widens_the_middle_one():
    log_scales = _log(100.0, 1.0, 0.1).requires_grad_(True)
    elongation_penalty(log_scales, 10.0).backward()
    g = log_scales.grad[0]
    assert g[0] > 0 and g[1] < 0 and g[2] == 0  # descent: largest down, middle up, thinnest untouched


def test_pipeline_adds_the_term_only_when_weighted(tmp_path):
    """``--pipeline.lambda-elongation``: no term when off; on, the penalty of the model's scales
    (one needle among spheres) in the step's metrics, and its gradient shortens the needle."""
    from tests.tiny_scenes import tiny_hazy_scene, tiny_pipeline

    scene = tiny_hazy_scene(tmp_path / "s", layout="street", haze="homogeneous", seed=4)

    def pipeline(out: str, *extra: str):
        return tiny_pipeline(scene, tmp_path / out, *extra)

    assert "elongation" not in pipeline("off").train_loss(0).metrics
    on = pipeline("on", "--pipeline.lambda-elongation", "1")
    log_scales = on.model.params["log_scales"]
    with torch.no_grad():
        log_scales[:] = math.log(0.01)  # spheres: no penalty
        log_scales[0] = torch.tensor([0.0, math.log(0.01), math.log(0.01)])  # one needle, ratio 100
    res = on.train_loss(0)
    n = log_scales.shape[0]
    assert float(res.metrics["elongation"]) == pytest.approx(math.log(10.0) / n, rel=1e-4)
    res.loss.backward()
    assert float(log_scales.grad[0, 0]) > 0.0  # descent shortens the needle's long axis
