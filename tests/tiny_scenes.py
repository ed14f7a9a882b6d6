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
