"""benchmarks/dcp_bound_split.py: a trained medium's T error where the dark-channel bound is tight."""

from __future__ import annotations

import math

import torch

from tests.eval.diagnosis_script import load_benchmark, run_diagnosis


def _module(monkeypatch):
    return load_benchmark(monkeypatch, "dcp_bound_split")


def test_split_of_a_known_view(monkeypatch):
    """Uniform haze T = 0.5, light 0.8; one black clean pixel in a bright picture. The 3x3 patches that
    hold it have a tight bound (1 - 0.95 * 0.5 = 0.525 against 0.5); the others a loose one."""
    mod = _module(monkeypatch)
    H, W, light = 6, 7, 0.8
    clean = torch.full((H, W, 3), 0.6)
    clean[1, 1] = 0.0
    t_true = torch.full((H, W, 1), 0.5)
    s_true = light * (1 - t_true).expand(H, W, 3)
    image = clean * t_true + s_true
    t_model = t_true - 0.1  # too much haze everywhere, the in-scattering kept
    sums = mod.split_sums(image, t_model, s_true, t_true, s_true, patch=3)
    assert sums["tight_n"] == 9 and sums["loose_n"] == H * W - 9  # centres within 1 px of (1, 1)
    assert math.isclose(sums["tight_err"] / 9, -0.1, abs_tol=1e-5)
    assert math.isclose(sums["loose_abs"] / (H * W - 9), 0.1, abs_tol=1e-5)
    # the true-light bound (0.525) is above the model's 0.4 on the tight pixels only
    assert math.isclose(sums["viol_true"], 9 * (0.525 - 0.4), rel_tol=1e-4)
    # the model's own light S / (1 - 0.4) is dimmer, so its bound is lower: 1 - 0.95 * 0.5 * 0.8 / (0.4 / 0.6)
    own = 1 - 0.95 * 0.5 * light / (0.4 / 0.6)
    assert math.isclose(sums["viol_own"], 9 * max(own - 0.4, 0.0), abs_tol=1e-4)
    ratio = mod.light_ratio(t_model, s_true, t_true, s_true)
    assert torch.allclose(ratio, torch.full_like(ratio, 0.5 / 0.6))


def test_on_a_tiny_run(courtyard_run, tmp_path):
    config = courtyard_run
    out = tmp_path / "split"
    row = run_diagnosis("dcp_bound_split.py", [config], out)
    assert 0.0 < row["tight_share"] < 1.0
    for key in ("tight_mae", "loose_mae"):
        assert 0.0 <= row[key] <= 1.0
    assert -1.0 <= row["bias"] <= 1.0 and row["light_ratio"] > 0.0
    share = row["tight_share"]
    assert math.isclose(
        row["bias"], share * row["tight_bias"] + (1 - share) * row["loose_bias"], abs_tol=1e-5
    )
    assert "T bias all / tight / loose" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
