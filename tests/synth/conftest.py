"""Small generated datasets shared by the synth tests (module-scoped: generated once)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch

from components.synth.generate import SceneConfig, generate_scene

TINY = SceneConfig(
    output_dir=Path("unused"),
    layout="courtyard",
    haze="patchy",
    num_views=9,
    width=40,
    height=30,
    samples=32,
    supersample=1,
    num_points=300,
)
"""A few seconds' worth of scene: enough views for a train/test split, tiny images."""


def make_tiny(root: Path, **overrides) -> Path:
    generate_scene(replace(TINY, output_dir=root, **overrides))
    return root


@pytest.fixture(scope="package")
def tiny_dataset(tmp_path_factory) -> Path:
    return make_tiny(tmp_path_factory.mktemp("synth") / "tiny")


@pytest.fixture(autouse=True)
def one_torch_thread():
    """Small tensors run fastest on one thread (and shared CI cores make two threads spin)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
