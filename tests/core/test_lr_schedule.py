"""Learning-rate schedules: the engine's decay of the means, a pipeline's own scales
(:meth:`Pipeline.lr_scales`), and Tri-DehazeGS's medium decay between its hold and its freeze."""

from __future__ import annotations

import math

import pytest
import torch
from rich.console import Console
from torch import nn

from pipelines.engine.optimizers import OptimizerConfig, Optimizers
from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args


def _lrs(opt: Optimizers) -> dict[str, float]:
    return {name: o.param_groups[0]["lr"] for name, o in opt.optimizers.items()}


def test_scales_multiply_their_groups_and_unnamed_groups_return_to_base():
    groups = {
        "means": (nn.Parameter(torch.zeros(3)), 1.0),
        "medium.features": (nn.Parameter(torch.zeros(3)), 0.01),
        "sh0": (nn.Parameter(torch.zeros(3)), 0.5),
    }
    opt = Optimizers(groups, OptimizerConfig(means_lr_final_ratio=0.01), max_steps=100)
    opt.schedule(50, {"medium.features": 0.25, "means": 2.0, "not-a-group": 3.0})
    lrs = _lrs(opt)
    assert lrs["medium.features"] == pytest.approx(0.0025)
    assert lrs["means"] == pytest.approx(2.0 * 0.1)  # its own scale on top of the decay (0.01^0.5)
    assert lrs["sh0"] == 0.5
    opt.schedule(100)
    assert _lrs(opt) == pytest.approx({"means": 0.01, "medium.features": 0.01, "sh0": 0.5})


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return tiny_hazy_scene(tmp_path_factory.mktemp("lr") / "s", layout="street", haze="homogeneous", seed=4)


def _trainer(scene, out, *extra: str) -> Trainer:
    cfg = parse_args([
        "tri-dehaze", "--data", str(scene), "--output-dir", str(out), "--max-steps", "40",
        "--device", "cpu", "--pipeline.rasterizer.backend", "torch", "--steps-per-save", "100",
        "--no-eval-at-end", "--threads", "1", *extra,
    ])  # fmt: skip
    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.setup()
    return trainer


def test_medium_decays_from_the_hold_to_the_freeze(scene, tmp_path):
    pipe = _trainer(scene, tmp_path / "on", "--pipeline.medium-lr-final-ratio", "0.1").pipeline
    hold, freeze = pipe.hold_steps, pipe.freeze_step
    assert 0 < hold < freeze < 40
    names = set(pipe.medium.param_groups())
    assert names and all(n.startswith("medium.") for n in names)
    assert pipe.lr_scales(hold - 1) == {}  # held: the medium does not learn
    assert pipe.lr_scales(hold) == pytest.approx(dict.fromkeys(names, 1.0))
    mid = (hold + freeze) / 2
    if float(mid).is_integer():
        assert pipe.lr_scales(int(mid)) == pytest.approx(dict.fromkeys(names, math.sqrt(0.1)))
    last = pipe.lr_scales(freeze - 1)
    expect = 0.1 ** ((freeze - 1 - hold) / (freeze - hold))
    assert last == pytest.approx(dict.fromkeys(names, expect))
    assert pipe.lr_scales(freeze) == {}  # frozen
    off = _trainer(scene, tmp_path / "off").pipeline
    assert all(off.lr_scales(s) == {} for s in (0, hold, freeze - 1, freeze))


def test_the_trainer_applies_the_pipeline_scales(scene, tmp_path):
    trainer = _trainer(scene, tmp_path / "t", "--pipeline.medium-lr-final-ratio", "0.1")
    pipe = trainer.pipeline
    step = pipe.freeze_step - 1
    trainer.optimizers.schedule(step, pipe.lr_scales(step))
    for name, (_, base) in pipe.medium.param_groups().items():
        got = trainer.optimizers.optimizers[name].param_groups[0]["lr"]
        assert got == pytest.approx(base * pipe.lr_scales(step)[name])
        assert got < base


def test_needle_penalty_term_only_when_weighted(scene, tmp_path):
    off = _trainer(scene, tmp_path / "n0").pipeline
    assert "elongation" not in off.train_loss(0).metrics
    on = _trainer(scene, tmp_path / "n1", "--pipeline.lambda-elongation", "1").pipeline
    log_scales = on.model.params["log_scales"]
    with torch.no_grad():
        log_scales[:] = math.log(0.01)  # spheres: no penalty
        log_scales[0] = torch.tensor([0.0, math.log(0.01), math.log(0.01)])  # one needle, ratio 100
    res = on.train_loss(0)
    n = log_scales.shape[0]
    assert float(res.metrics["elongation"]) == pytest.approx(math.log(10.0) / n, rel=1e-4)
    res.loss.backward()
    assert float(log_scales.grad[0, 0]) > 0.0  # descent shortens the needle's long axis
