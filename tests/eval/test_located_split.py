"""benchmarks/located_split.py: restoration where the photos locate the geometry and on the background."""

from __future__ import annotations

import numpy as np
import torch

from components.data.cameras import Cameras
from tests.eval.diagnosis_script import load_benchmark, run_diagnosis


def _module(monkeypatch):
    return load_benchmark(monkeypatch, "located_split")


def _camera(H: int, W: int) -> Cameras:
    one = torch.ones(1)
    return Cameras(torch.eye(4)[None], 10.0 * one, 10.0 * one, W / 2 * one, H / 2 * one, W * one, H * one)


def test_background_is_beyond_twice_the_farthest_seen_point(monkeypatch):
    """Seed points on the optical axis at z 1 .. 2: a depth beyond 2x their 98th percentile is
    background; a view that sees fewer than 10 points is all located."""
    mod = _module(monkeypatch)
    H, W = 8, 10
    points = torch.zeros(40, 3)
    points[:, 2] = torch.linspace(1.0, 2.0, 40)
    far = float(np.quantile(np.linspace(1.0, 2.0, 40), 0.98))
    z = torch.full((H, W), 1.5)
    z[:, :3] = 2.0 * far + 0.01  # just beyond
    z[:, 3] = 2.0 * far - 0.01  # just within
    bg = mod.background_mask(_camera(H, W), points, z)
    assert bg[:, :3].all() and not bg[:, 3:].any()
    assert not mod.background_mask(_camera(H, W), points[:5], z).any()


def test_masked_sums_and_psnr(monkeypatch):
    mod = _module(monkeypatch)
    ref = torch.zeros(2, 2, 3)
    img = ref.clone()
    img[0, 0] = 0.1  # error 0.1 in each channel of one pixel
    masks = {
        "a": torch.tensor([[True, False], [False, False]]),
        "b": torch.tensor([[False, True], [True, True]]),
    }
    sums = mod.masked_sums(img, ref, masks)
    assert np.isclose(sums["a"][0], 0.03) and sums["a"][1] == 1
    assert sums["b"] == (0.0, 3)
    assert np.isclose(mod.psnr_of(sums["a"]), 20.0)


def test_on_a_tiny_run(courtyard_run, tmp_path):
    config = courtyard_run
    row = run_diagnosis("located_split.py", [config], tmp_path / "split")
    assert 0.0 <= row["background_share"] <= 1.0 and row["method"] == config.parent.name
    for src in ("model", "dcp_2d"):
        assert 0.0 < row["psnr"][src]["all"] < 60.0
        assert row["psnr"][src]["located"] is not None
        if row["background_share"] == 0.0:
            assert row["psnr"][src]["background"] is None
