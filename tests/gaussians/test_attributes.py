"""Per-Gaussian attributes added by other components follow densification and checkpoints."""

from __future__ import annotations

import pytest
import torch

from components.gaussians.densify import Densifier, DensifyConfig
from tests.gaussians.test_densify import _check_optimizer_consistency, _fake_output, _model, _optimizers


def test_attribute_is_cloned_split_and_pruned_with_its_gaussian():
    model = _model([0.001, 0.5, 0.001, 0.001], [0.9, 0.9, 0.9, 0.001])
    tags = torch.arange(4, dtype=torch.float32)[:, None].repeat(1, 4)  # row i holds i
    model.add_attribute("medium", tags, lr=1e-3)
    assert "medium" in model.param_names and model.param_groups()["medium"][1] == 1e-3
    opts = _optimizers(model)
    with torch.no_grad():  # undo the optimizer's nudge so rows stay exact tags
        model.params["medium"].copy_(tags)
    cfg = DensifyConfig(refine_start=0, refine_every=1, grow_grad2d=0.01, grow_scale3d=0.1)
    dens = Densifier(cfg, scene_extent=1.0, max_steps=100)
    # Gaussian 0 (small) is cloned, 1 (big) split, 3 (transparent) pruned
    dens.collect(_fake_output(torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 0.0], [0.0, 0.0]])))
    dens.step(0, model, opts)
    rows = model.attribute("medium")[:, 0].round().long().tolist()
    assert sorted(rows) == [0, 0, 1, 1, 2]
    assert model.attribute("medium").shape == (model.num_gaussians, 4)
    _check_optimizer_consistency(model, opts)


def test_attribute_checks_and_checkpoint_resize():
    model = _model([0.1, 0.1], [0.5, 0.5])
    with pytest.raises(ValueError, match="rows"):
        model.add_attribute("medium", torch.zeros(3, 4), lr=1e-3)
    model.add_attribute("medium", torch.ones(2, 4), lr=1e-3)
    with pytest.raises(KeyError):
        model.add_attribute("medium", torch.ones(2, 4), lr=1e-3)
    big = _model([0.1] * 5, [0.5] * 5)
    big.add_attribute("medium", torch.full((5, 4), 7.0), lr=1e-3)
    model.load_state_dict(big.state_dict())
    assert model.num_gaussians == 5 and torch.equal(model.attribute("medium"), torch.full((5, 4), 7.0))
