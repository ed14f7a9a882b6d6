"""``--pipeline.scene-from CKPT``: a run starts from, and holds, an earlier run's Gaussians, so
only the medium learns (a diagnosis: the medium fitted behind a haze-free capture's scene)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene, tiny_trainer
from tridehaze_plugin.errors import ConfigError


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("scene_transplant")
    a = tiny_hazy_scene(root / "a", layout="street", haze="patchy", seed=3, num_views=4, test_every=2)
    b = tiny_hazy_scene(root / "b", layout="room", haze="uniform", seed=5, num_views=4, test_every=2)
    return a, b


def _trainer(method: str, data: Path, out: Path, steps: int, *extra: str) -> Trainer:
    return tiny_trainer(data, out, "--steps-per-save", "100", "--pipeline.medium-hold-fraction", "0", *extra,
                        max_steps=steps, method=method)  # fmt: skip


def _gaussians(trainer: Trainer) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in trainer.pipeline.model.state_dict().items()}


@pytest.fixture(scope="module")
def source(scenes, tmp_path_factory) -> tuple[Path, dict[str, torch.Tensor]]:
    """A vanilla-gs run (grown past its seed cloud) whose last checkpoint the tests load."""
    first = _trainer("vanilla-gs", scenes[0], tmp_path_factory.mktemp("source"), 12,
                     "--pipeline.densify.refine-start", "2", "--pipeline.densify.refine-every", "2")  # fmt: skip
    first.train()
    ckpt = sorted((first.run_dir / "checkpoints").glob("step-*.ckpt"))[-1]
    return ckpt, _gaussians(first)


def test_the_gaussians_are_loaded_and_held_while_the_medium_learns(scenes, source, tmp_path):
    ckpt, learnt = source
    run = _trainer("tri-dehaze", scenes[0], tmp_path / "held", 8, "--pipeline.scene-from", str(ckpt))
    assert run.pipeline.init_info["scene_from_step"] == 12
    assert run.pipeline.init_info["scene_from_gaussians"] == len(learnt["params.means"])
    for k, v in _gaussians(run).items():
        torch.testing.assert_close(v, learnt[k], rtol=0, atol=0)
    medium = {k: v.detach().clone() for k, v in run.pipeline.medium.state_dict().items()}
    run.train()
    for k, v in _gaussians(run).items():  # held for the whole run: no update, growth or pruning
        torch.testing.assert_close(v, learnt[k], rtol=0, atol=0)
    after = run.pipeline.medium.state_dict()
    assert any(not torch.equal(medium[k], after[k]) for k in after), "the medium must learn"


def test_geometry_only_lets_the_colours_learn(scenes, source, tmp_path):
    ckpt, learnt = source
    run = _trainer("tri-dehaze", scenes[0], tmp_path / "geo", 8, "--pipeline.scene-from", str(ckpt),
                   "--pipeline.scene-from-holds", "geometry")  # fmt: skip
    run.train()
    now = _gaussians(run)
    for k in ("params.means", "params.quats", "params.log_scales", "params.opacity_logits"):
        torch.testing.assert_close(now[k], learnt[k], rtol=0, atol=0)
    assert not torch.equal(now["params.sh0"], learnt["params.sh0"]), "the colours must learn"


def test_a_checkpoint_of_other_data_or_another_model_is_refused(scenes, source, tmp_path):
    ckpt, _ = source
    with pytest.raises(ConfigError, match="normalised the world differently"):
        _trainer("tri-dehaze", scenes[1], tmp_path / "other", 2, "--pipeline.scene-from", str(ckpt))
    with pytest.raises(ConfigError, match="do not fit this model"):
        _trainer("tri-dehaze", scenes[0], tmp_path / "sh", 2, "--pipeline.model.sh-degree", "1",
                 "--pipeline.scene-from", str(ckpt))  # fmt: skip
    empty = tmp_path / "empty.ckpt"
    payload = torch.load(ckpt, weights_only=True)
    payload["pipeline"] = {k: v for k, v in payload["pipeline"].items() if not k.startswith("model.")}
    torch.save(payload, empty)
    with pytest.raises(ConfigError, match="holds no Gaussians"):
        _trainer("tri-dehaze", scenes[0], tmp_path / "empty", 2, "--pipeline.scene-from", str(empty))
