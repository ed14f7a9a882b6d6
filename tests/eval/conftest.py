"""Tiny trained runs (48x36 views: large enough for LPIPS' AlexNet) shared by the evaluation tests."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

from components.metrics import lpips as lp
from tests.export.tiny_run import make_scene, train_tiny


@pytest.fixture(autouse=True, scope="module")
def _one_torch_thread():
    """Tiny runs: one thread beats two fighting other jobs on a shared CPU (restored afterwards)."""
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


@pytest.fixture(scope="session")
def need_lpips() -> None:
    """LPIPS weights: a failure in CI (the install step provides them), a skip elsewhere."""
    if not lp.lpips_available("alex"):
        if os.environ.get("CI"):
            pytest.fail(f"LPIPS weights missing in CI: the install step must run `{lp.PIP_HINT}`")
        pytest.skip(f"LPIPS weights not installed ({lp.PIP_HINT})")


@pytest.fixture(scope="session")
def eval_scene(tmp_path_factory) -> Path:
    return make_scene(tmp_path_factory.mktemp("eval_scene") / "scene", width=48, height=36)


@pytest.fixture(scope="session")
def tri_run(eval_scene, tmp_path_factory) -> Path:
    return train_tiny(eval_scene, tmp_path_factory.mktemp("eval_tri"), steps=6)


@pytest.fixture(scope="session")
def plain_run(eval_scene, tmp_path_factory) -> Path:
    return train_tiny(eval_scene, tmp_path_factory.mktemp("eval_plain"), method="vanilla-gs", steps=4)
