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


@pytest.fixture(scope="session")
def courtyard_run(tmp_path_factory) -> Path:
    """A generated hazy courtyard with true maps and seed points, 4 steps on the CPU: the run the
    diagnoses of ``benchmarks/`` are tried on."""
    from tests.tiny_scenes import tiny_hazy_scene

    root = tmp_path_factory.mktemp("courtyard")
    scene = tiny_hazy_scene(
        root / "scene", layout="courtyard", seed=3, num_views=6, width=40, height=30, samples=16,
        num_points=300, test_every=3,
    )  # fmt: skip
    return train_tiny(scene, root / "runs", "--device", "cpu", steps=4)
