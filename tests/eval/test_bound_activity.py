"""benchmarks/bound_activity.py: where the own-light dark-channel bound holds a trained medium."""

from __future__ import annotations

import math

import torch

from tests.eval.diagnosis_script import load_benchmark, run_diagnosis


def _known_view(t_model: float):
    """Uniform haze T = 0.5 under light 0.8, a black clean pixel in every 3x3 patch (the bound is
    tight: omega 1 gives the true T), the model's T ``t_model`` under the same light."""
    H, W, light, t = 6, 9, 0.8, 0.5
    clean = torch.full((H, W, 3), 0.6)
    clean[1::3, 1::3] = 0.0
    t_true = torch.full((H, W, 1), t)
    s_true = light * (1 - t_true).expand(H, W, 3)
    t_mod = torch.full((H, W, 1), t_model)
    s_mod = light * (1 - t_mod).expand(H, W, 3)
    return clean * t_true + s_true, t_mod, s_mod, t_true, s_true


def test_bounds_of_a_known_view(monkeypatch):
    mod = load_benchmark(monkeypatch, "bound_activity")
    at_truth = mod.view_maps(*_known_view(0.5))
    torch.testing.assert_close(at_truth["own_1"], torch.full((6, 9), 0.5), atol=1e-5, rtol=0)
    torch.testing.assert_close(at_truth["true_1"], torch.full((6, 9), 0.5), atol=1e-5, rtol=0)
    # omega 0.95 lies (1 - omega)(1 - T) = 0.025 above the truth on a black patch
    torch.testing.assert_close(at_truth["own_095"], torch.full((6, 9), 0.525), atol=1e-5, rtol=0)
    assert bool((at_truth["active"] == 1).all())  # the truth sits under the 0.95 bound: held
    thin = mod.view_maps(*_known_view(0.6))  # 0.075 above the bound: the photos, not the bound
    assert bool((thin["active"] == 0).all())


def test_on_a_tiny_run(courtyard_run, tmp_path):
    out = tmp_path / "activity"
    row = run_diagnosis("bound_activity.py", [courtyard_run], out)
    shares = [row[f"{b}_share"] for b in ("dense", "mid", "thin")]
    assert math.isclose(sum(shares), 1.0, abs_tol=1e-6)
    for b, share in zip(("dense", "mid", "thin"), shares, strict=True):
        if share:
            assert row[f"{b}_own_1"] <= row[f"{b}_own_095"] + 1e-6  # a larger omega: a lower bound
            assert 0.0 <= row[f"{b}_active"] <= 1.0 and 0.0 <= row[f"{b}_model"] <= 1.0
    assert "held by the 0.95 bound" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
