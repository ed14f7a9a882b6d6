"""``--pipeline.flatten-one-light``: at the freeze, a run judged one light gets one light for every
ray (its mean over the training pixels); other runs keep the learnt light."""

from __future__ import annotations

import json

import pytest
import torch

from components.medium.base import FieldBounds, MediumConfig
from pipelines.tridehaze.light_flattening import LightFlattening
from tests.tiny_scenes import tiny_hazy_scene, tiny_trainer


def _field():
    bounds = FieldBounds(torch.zeros(3), torch.ones(3))
    cfg = MediumConfig(backend="triplane", light="mlp", light_space="global", resolution=8)
    return cfg.setup(bounds=bounds)


def test_a_flat_light_is_the_same_for_every_point_and_direction_and_survives_a_checkpoint():
    field = _field()
    with torch.no_grad():  # a light that clearly depends on the direction
        field.heads.light_head[-1].weight.normal_(0, 1.0)
    x = torch.rand(64, 3) * 2 - 1  # [P, 3]
    d = torch.nn.functional.normalize(torch.randn(64, 3), dim=-1)  # [P, 3]
    assert float(field(x, d).light.detach().std(dim=0).max()) > 0.01
    beta = field(x, d).beta.detach()
    field.flatten_light(torch.tensor([0.6, 0.7, 0.8]))
    light = field(x, d).light
    torch.testing.assert_close(light, torch.tensor([[0.6, 0.7, 0.8]]).expand(64, 3))
    torch.testing.assert_close(field(x, d).beta, beta)  # the extinction is untouched
    rays = field.sample_rays(x[:8, None, :].expand(8, 4, 3), d[:8])  # the march's per-ray path
    torch.testing.assert_close(rays.light, torch.tensor([0.6, 0.7, 0.8]).expand(8, 4, 3))
    again = _field()
    again.load_state_dict(field.state_dict())
    torch.testing.assert_close(again(x, d).light, light)
    old = {k: v for k, v in field.state_dict().items() if not k.endswith("flat_light")}
    before = _field()
    before.load_state_dict(old)  # a checkpoint from before: the learnt light
    assert float(before(x, d).light.detach().std(dim=0).max()) > 0.0


def test_fields_without_heads_cannot_flatten():
    cfg = MediumConfig(backend="none")
    field = cfg.setup(bounds=FieldBounds(torch.zeros(3), torch.ones(3)))
    assert not field.recolours_light  # the pipeline leaves the flattening off for it
    with pytest.raises(NotImplementedError, match="cannot flatten"):
        field.flatten_light(torch.ones(3))


def test_the_decision_is_taken_once_and_says_why():
    flat = LightFlattening(True, step=10)
    assert not flat.due(9) and flat.due(10)
    assert flat.decide(False, None, torch.ones(3), 0.05) is None and not flat.due(11)
    assert "not judged one light" in flat.decisions[0].message
    seen = LightFlattening(True, step=10, seen_share=0.2)
    assert seen.decide(True, 0.45, torch.ones(3), 0.02) is None  # opaque haze shows the light
    assert "45% of the pixels see it through opaque haze" in seen.decisions[0].message
    other = LightFlattening(True, step=10, seen_share=0.2)
    light = other.decide(True, 0.01, torch.tensor([0.5, 0.6, 0.7]), 0.02)
    torch.testing.assert_close(light, torch.tensor([0.5, 0.6, 0.7]))
    assert other.decisions[0].data["flat_light"] == pytest.approx([0.5, 0.6, 0.7])
    json.dumps(other.decisions[0].data, allow_nan=False)
    resumed = LightFlattening(True, step=10)
    resumed.load_state_dict(other.state_dict())
    assert not resumed.due(12)
    assert not LightFlattening(False, step=10).due(12)


def test_a_run_judged_one_light_trains_on_with_one_light(tmp_path):
    scene = tiny_hazy_scene(
        tmp_path / "room", layout="room", haze="uniform", seed=5, num_views=4, test_every=2
    )
    trainer = tiny_trainer(
        scene,
        tmp_path / "run",
        "--pipeline.flatten-one-light",
        "--pipeline.light-isotropy-cv",
        "1.0",
        "--pipeline.medium-hold-fraction",
        "0",
        "--steps-per-save",
        "100",
        max_steps=8,
    )  # fmt: skip  (every spread counts as one light here)
    trainer.train()
    pipe = trainer.pipeline
    assert pipe.light_isotropy.judged_one_light()
    assert pipe.light_flat.seen_share == pipe.config.flatten_seen_share == 0.2  # the gate is wired
    lines = [json.loads(x) for x in (trainer.run_dir / "logs" / "decisions.jsonl").read_text().splitlines()]
    flat = [x for x in lines if "flat_light" in x]
    assert len(flat) == 1 and flat[0]["flat_light"] is not None and flat[0]["step"] >= pipe.freeze_step
    d = torch.nn.functional.normalize(torch.randn(32, 3), dim=-1)
    x = pipe.medium.bounds_center + torch.zeros(32, 3)
    light = pipe.medium(x, d).light.detach()
    torch.testing.assert_close(light, torch.tensor(flat[0]["flat_light"]).expand(32, 3))
