"""Tiny trained runs shared by the export and camera-path render tests (trained once per session)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from tests.export.tiny_run import make_scene, train_tiny


@pytest.fixture(autouse=True, scope="module")
def _one_torch_thread():
    """These runs are tiny: one thread is faster than two fighting other jobs for a shared CPU
    (measured 0.8 s vs 23 s for the tri-dehaze run on the busy 2-core machine). Restored after each
    module, so tests elsewhere keep torch's default."""
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


@pytest.fixture(scope="session")
def tiny_hazy_scene(tmp_path_factory) -> Path:
    return make_scene(tmp_path_factory.mktemp("export_scene") / "scene")


@pytest.fixture(scope="session")
def tri_run(tiny_hazy_scene, tmp_path_factory) -> Path:
    """config.yml of a 6-step tri-dehaze run (tri-plane medium)."""
    return train_tiny(tiny_hazy_scene, tmp_path_factory.mktemp("tri_run"))


@pytest.fixture(scope="session")
def plain_run(tiny_hazy_scene, tmp_path_factory) -> Path:
    """config.yml of a 3-step vanilla-gs run (no medium)."""
    return train_tiny(tiny_hazy_scene, tmp_path_factory.mktemp("plain_run"), method="vanilla-gs", steps=3)


@pytest.fixture(scope="session")
def bound_run(tiny_hazy_scene, tmp_path_factory) -> Path:
    """config.yml of a 3-step tri-dehaze run with the gaussian-bound medium."""
    out = tmp_path_factory.mktemp("bound_run")
    return train_tiny(tiny_hazy_scene, out, "--pipeline.medium.backend", "gaussian-bound", steps=3)
