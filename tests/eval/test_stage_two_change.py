"""benchmarks/stage_two_change.py: a run scored at its freeze checkpoint and at its end."""

from __future__ import annotations

import math

import pytest

from tests.eval.diagnosis_script import run_diagnosis
from tests.export.tiny_run import train_tiny


@pytest.fixture(scope="module")
def saved_at_freeze(tmp_path_factory):
    """A tiny generated courtyard (true maps) trained 5 steps, the freeze at step 3, a checkpoint
    every step (the last two kept: 4 and 5, so not the freeze) and one every 3 steps (3 and 5)."""
    from tests.tiny_scenes import tiny_hazy_scene

    root = tmp_path_factory.mktemp("stage_two")
    scene = tiny_hazy_scene(
        root / "scene", layout="courtyard", seed=3, num_views=6, width=40, height=30, samples=16,
        num_points=300, test_every=3,
    )  # fmt: skip
    every3 = train_tiny(scene, root / "every3", "--device", "cpu", "--steps-per-save", "3", steps=5)
    every1 = train_tiny(scene, root / "every1", "--device", "cpu", "--steps-per-save", "1", steps=5)
    return every3, every1


def test_freeze_and_end_scored_with_the_medium_unchanged(saved_at_freeze, tmp_path):
    out = tmp_path / "stage_two"
    row = run_diagnosis("stage_two_change.py", [saved_at_freeze[0]], out)
    assert (row["freeze_step"], row["end_step"]) == (3, 5)
    for stage in ("freeze", "end"):
        assert math.isfinite(row[f"{stage}_psnr"]) and 0.0 <= row[f"{stage}_t_mae"] <= 1.0
    # Stage II freezes the medium: T marched to the true depth is the same at both checkpoints
    assert row["freeze_t_mae_true_depth"] == pytest.approx(row["end_t_mae_true_depth"], abs=1e-6)
    assert "restoration freeze -> end" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0


def test_a_run_without_the_freeze_checkpoint_is_reported_empty(saved_at_freeze, tmp_path):
    out = tmp_path / "no_freeze"
    row = run_diagnosis("stage_two_change.py", [saved_at_freeze[1]], out)
    assert row["freeze_psnr"] is None and row["end_step"] == 5
    assert "| - -> " in out.with_suffix(".md").read_text()
