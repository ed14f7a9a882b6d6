"""A tiny trained run (generated hazy scene, a few tri-dehaze steps, ~5 s) for export and render tests."""

from __future__ import annotations

from pathlib import Path

from components.synth.generate import SceneConfig, generate_scene
from pipelines.engine.trainer import Trainer
from tridehaze_plugin.cli.train import parse_args


def make_scene(root: Path, num_views: int = 6, width: int = 40, height: int = 30) -> Path:
    generate_scene(
        SceneConfig(output_dir=root, layout="courtyard", haze="patchy", seed=2, num_views=num_views, width=width,
                    height=height, samples=16, supersample=1, num_points=300, test_every=3)
    )  # fmt: skip
    return root


def train_tiny(scene: Path, out: Path, *overrides: str, method: str = "tri-dehaze", steps: int = 6) -> Path:
    """Train and return the run's config.yml (with one torch thread: much faster for such a tiny run
    on a busy shared CPU; the previous setting is restored)."""
    import torch
    from rich.console import Console

    argv = [
        method, "--data", str(scene), "--output-dir", str(out), "--max-steps", str(steps),
        "--pipeline.warmup-steps", "3", "--pipeline.freeze-step", "3", "--pipeline.medium-hold-fraction", "0",
        "--pipeline.rasterizer.backend", "torch", "--no-eval-at-end", "--steps-per-save", "100",
        "--pipeline.model.sh-degree", "1", *overrides,
    ]  # fmt: skip
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        trainer = Trainer(parse_args(argv), console=Console(quiet=True))
        trainer.setup()
        trainer.train()
    finally:
        torch.set_num_threads(old)
    return trainer.run_dir / "config.yml"
