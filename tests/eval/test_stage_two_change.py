"""benchmarks/stage_two_change.py: a run scored at its freeze checkpoint and at its end."""

from __future__ import annotations

import math

import pytest

from tests.eval.diagnosis_script import run_diagnosis
from tests.export.tiny_run import train_tiny


@pytest.fixture(scope="module")
def saved_at_freeze(tmp_path_factory):
    """A tiny generated courtyard (true maps) trained 5 steps, the freeze at step 3, a checkpoint
    every 3 steps (3 and 5) and one every step (the last two, 4 and 5, and the freeze, which the
    rotation keeps; then removed, as a run trained before session 65 may have lost it)."""
    from tests.tiny_scenes import tiny_hazy_scene

    root = tmp_path_factory.mktemp("stage_two")
    scene = tiny_hazy_scene(
        root / "scene", layout="courtyard", seed=3, num_views=6, width=40, height=30, samples=16,
        num_points=300, test_every=3,
    )  # fmt: skip
    every3 = train_tiny(scene, root / "every3", "--device", "cpu", "--steps-per-save", "3", steps=5)
    every1 = train_tiny(scene, root / "every1", "--device", "cpu", "--steps-per-save", "1", steps=5)
    ckpts = every1.parent / "checkpoints"
    assert sorted(p.name for p in ckpts.iterdir()) == [f"step-000000{i}.ckpt" for i in (3, 4, 5)]
    (ckpts / "step-0000003.ckpt").unlink()
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


def test_a_run_continued_from_its_freeze_reproduces_itself(tmp_path):
    """benchmarks/stage_two_arm.py: a run continued from its freeze checkpoint with no change ends
    where it ended (the premise of pairing Stage II changes that way); with a change it still runs."""
    import json
    import subprocess
    import sys

    from tests.eval.diagnosis_script import REPO
    from tests.tiny_scenes import tiny_hazy_scene

    scene = tiny_hazy_scene(
        tmp_path / "courtyard", layout="courtyard", seed=3, num_views=6, width=40, height=30, samples=16,
        num_points=300, test_every=3,
    )  # fmt: skip
    bench = tmp_path / "bench"
    config = train_tiny(scene, bench / "seed42" / "runs", "--device", "cpu", "--steps-per-save", "3", steps=5)
    subprocess.run(
        [sys.executable, "-m", "tridehaze_plugin.cli.eval", "--load-config", str(config), "--lpips", "off", "--no-images"],
        check=True, capture_output=True,
    )  # fmt: skip
    for name, extra in (("same", ""), ("held", "--pipeline.stage-two-holds-haze")):
        out = tmp_path / name
        cmd = [sys.executable, str(REPO / "benchmarks" / "stage_two_arm.py"), "--base", str(bench), "--output", str(out),
               "--jobs", "1", f"--train-args={extra}"]  # fmt: skip
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr[-2000:]
        (row,) = json.loads((out / "pairs.json").read_text())
        assert row["scene"] == "courtyard" and row["seed"] == "seed42"
        if name == "same":
            assert row["continued"] == row["base"]
        else:
            assert "stage_two_holds_haze: true" in (out / "seed42" / "courtyard" / "config.yml").read_text()


def test_a_pair_without_a_true_scattering_map_prints():
    """Real photos hazed by td-synth carry a true T but no true S: the pair prints ``-`` there (it
    raised a TypeError after the runs, on the hazed real sets)."""
    import sys

    from tests.eval.diagnosis_script import REPO

    sys.path.insert(0, str(REPO / "benchmarks"))
    from stage_two_arm import pair_line

    row = {
        "seed": "seed7", "scene": "real-beer",
        "base": {"psnr": 20.0, "t_mae": 0.1, "s_mae": None},
        "continued": {"psnr": 20.5, "t_mae": 0.09, "s_mae": None},
    }  # fmt: skip
    line = pair_line(row)
    assert "20.00 -> 20.50 (+0.50)" in line and "T MAE 0.100 -> 0.090" in line and "S MAE - -> -" in line
