"""Checkpoint rotation keeps the newest few, and never a milestone (a stage boundary)."""

from __future__ import annotations

from pipelines.engine.checkpoint import checkpoint_path, save_checkpoint


def test_rotation_keeps_the_newest_and_every_protected_checkpoint(tmp_path):
    freeze = checkpoint_path(tmp_path, 3)
    for step in (2, 3, 4, 6, 8):
        save_checkpoint(checkpoint_path(tmp_path, step), {"step": step}, keep=2, protected=[freeze])
    names = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert names == ["step-0000003.ckpt", "step-0000006.ckpt", "step-0000008.ckpt"]
    save_checkpoint(checkpoint_path(tmp_path, 9), {"step": 9}, keep=2)  # unprotected: rotated as before
    names = sorted(p.name for p in (tmp_path / "checkpoints").iterdir())
    assert names == ["step-0000008.ckpt", "step-0000009.ckpt"]
