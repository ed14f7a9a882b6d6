"""``--pipeline.medium-from CKPT``: a run starts from, and holds, an earlier run's medium."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from rich.console import Console

from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args
from tridehaze_plugin.errors import ConfigError


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("transplant")
    a = tiny_hazy_scene(root / "a", layout="street", haze="patchy", seed=3, num_views=4, test_every=2)
    b = tiny_hazy_scene(root / "b", layout="room", haze="uniform", seed=5, num_views=4, test_every=2)
    return a, b


def _trainer(data: Path, out: Path, steps: int, *extra: str) -> Trainer:
    argv = [
        "tri-dehaze", "--data", str(data), "--output-dir", str(out), "--max-steps", str(steps),
        "--device", "cpu", "--pipeline.rasterizer.backend", "torch", "--steps-per-save", "100",
        "--no-eval-at-end", "--pipeline.medium-hold-fraction", "0", *extra,
    ]  # fmt: skip
    trainer = Trainer(parse_args(argv), console=Console(quiet=True))
    trainer.setup()
    return trainer


def _medium_state(trainer: Trainer) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in trainer.pipeline.medium.state_dict().items()}


def test_the_medium_is_loaded_and_held(scenes, tmp_path):
    first = _trainer(scenes[0], tmp_path / "first", 6)
    before = _medium_state(first)
    first.train()
    learnt = _medium_state(first)
    assert any(not torch.equal(before[k], learnt[k]) for k in learnt), "the first run's medium must learn"
    ckpt = sorted((first.run_dir / "checkpoints").glob("step-*.ckpt"))[-1]

    second = _trainer(scenes[0], tmp_path / "second", 6, "--pipeline.medium-from", str(ckpt))
    assert second.pipeline.init_info["medium_from_step"] == 6
    for k, v in _medium_state(second).items():
        torch.testing.assert_close(v, learnt[k], rtol=0, atol=0)
    gaussians = second.pipeline.model.means.detach().clone()
    second.train()
    for k, v in _medium_state(second).items():  # held for the whole run
        torch.testing.assert_close(v, learnt[k], rtol=0, atol=0)
    assert not torch.equal(
        gaussians, second.pipeline.model.means.detach()[: len(gaussians)]
    )  # the scene learns


def test_another_datasets_medium_is_refused(scenes, tmp_path):
    first = _trainer(scenes[0], tmp_path / "first", 2)
    first.train()
    ckpt = sorted((first.run_dir / "checkpoints").glob("step-*.ckpt"))[-1]
    with pytest.raises(ConfigError, match="medium box differs"):
        _trainer(scenes[1], tmp_path / "other", 2, "--pipeline.medium-from", str(ckpt))
    with pytest.raises(ConfigError, match="not this run's medium"):
        _trainer(
            scenes[0],
            tmp_path / "res",
            2,
            "--pipeline.medium.resolution",
            "8",
            "--pipeline.medium-from",
            str(ckpt),
        )
    with pytest.raises(ConfigError, match="both replace the medium's start"):
        _trainer(scenes[0], tmp_path / "both", 2, "--pipeline.medium-start", "reference",
                 "--pipeline.medium-from", str(ckpt))  # fmt: skip


def test_a_checkpoint_from_before_the_band_limit_loads(scenes, tmp_path):
    """Checkpoints written before the grid's band-limit buffer existed lack it; it stays at 0."""
    first = _trainer(scenes[0], tmp_path / "first", 2)
    first.train()
    ckpt = sorted((first.run_dir / "checkpoints").glob("step-*.ckpt"))[-1]
    payload = torch.load(ckpt, weights_only=True)
    del payload["pipeline"]["medium.band_sigma"]
    old = tmp_path / "old.ckpt"
    torch.save(payload, old)
    second = _trainer(scenes[0], tmp_path / "second", 2, "--pipeline.medium-from", str(old))
    assert float(second.pipeline.medium.band_sigma) == 0.0
    torch.testing.assert_close(second.pipeline.medium.features, first.pipeline.medium.features)


def test_the_sources_one_light_verdict_comes_with_its_medium(scenes, tmp_path):
    """The held medium's spread is not the one its run read while learning; re-reading it flipped
    session 56's street-homogeneous fill. The source's decision is carried and not taken again."""
    first = _trainer(scenes[0], tmp_path / "first", 6)
    first.train()
    source = first.pipeline.light_isotropy
    assert float(source.decided) != -1.0, "the first run must have decided"
    ckpt = sorted((first.run_dir / "checkpoints").glob("step-*.ckpt"))[-1]
    payload = torch.load(ckpt, weights_only=True)
    payload["pipeline"]["light_isotropy.decided"] = torch.tensor(0.5, dtype=torch.float64)  # not one light
    planted = tmp_path / "planted.ckpt"
    torch.save(payload, planted)

    second = _trainer(scenes[0], tmp_path / "second", 6, "--pipeline.medium-from", str(planted))
    assert second.pipeline.init_info["medium_from_verdict"] is True
    second.train()
    verdict = second.pipeline.light_isotropy
    assert float(verdict.decided) == 0.5 and not verdict.judged_one_light()
    assert _verdicts_logged(first) == 1 and _verdicts_logged(second) == 0  # not decided again

    del payload["pipeline"]["light_isotropy.decided"]  # a checkpoint from before the verdict
    old = tmp_path / "old.ckpt"
    torch.save(payload, old)
    third = _trainer(scenes[0], tmp_path / "third", 6, "--pipeline.medium-from", str(old))
    assert third.pipeline.init_info["medium_from_verdict"] is False
    third.train()
    assert float(third.pipeline.light_isotropy.decided) != -1.0  # taken as usual


def _verdicts_logged(trainer: Trainer) -> int:
    """How many one-light decisions the run wrote to logs/decisions.jsonl."""
    path = trainer.run_dir / "logs" / "decisions.jsonl"
    lines = path.read_text().splitlines() if path.exists() else []  # no decisions: no file
    return sum("light_cv" in json.loads(line) for line in lines)
