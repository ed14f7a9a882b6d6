"""Tiny generated hazy scenes for end-to-end tests (a few seconds to make, seconds to train on)."""

from __future__ import annotations

from pathlib import Path

from components.synth.generate import SceneConfig, generate_scene

TINY = {"num_views": 5, "width": 32, "height": 24, "samples": 8, "supersample": 1, "num_points": 200}
"""Defaults every test overrides only where it needs to."""


def tiny_hazy_scene(root: Path, **overrides) -> Path:
    """Generate a scene into ``root`` with :data:`TINY` settings plus ``overrides``; returns ``root``."""
    generate_scene(SceneConfig(output_dir=root, **{**TINY, **overrides}))
    return root


def tiny_trainer(scene: Path, output_dir: Path, *extra: str, max_steps: int = 40, method: str = "tri-dehaze"):
    """The set-up trainer (``method``) of a short CPU run on ``scene`` (torch rasterizer, one
    thread, no evaluation), with ``extra`` command-line options; nothing trained yet."""
    from rich.console import Console

    from pipelines.engine.trainer import Trainer
    from tridehaze_plugin.cli.train import parse_args

    cfg = parse_args([
        method, "--data", str(scene), "--output-dir", str(output_dir), "--max-steps", str(max_steps),
        "--device", "cpu", "--pipeline.rasterizer.backend", "torch", "--no-eval-at-end",
        "--threads", "1", *extra,
    ])  # fmt: skip
    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.setup()
    return trainer


def tiny_pipeline(scene: Path, output_dir: Path, *extra: str, max_steps: int = 40):
    """The set-up pipeline of :func:`tiny_trainer`."""
    return tiny_trainer(scene, output_dir, *extra, max_steps=max_steps).pipeline
