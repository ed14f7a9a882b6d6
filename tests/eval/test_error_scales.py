"""benchmarks/error_scales.py: the clean render's error split by spatial scale."""

from __future__ import annotations

import math

import numpy as np

from tests.eval.diagnosis_script import load_benchmark, run_diagnosis, tiny_field_run


def test_smooth_and_fine_errors_are_told_apart(monkeypatch):
    mod = load_benchmark(monkeypatch, "error_scales")
    rng = np.random.default_rng(0)
    ref = rng.uniform(0.2, 0.8, (60, 80, 3)).astype(np.float32)
    yy, xx = np.mgrid[0:60, 0:80]
    smooth = (0.1 * np.sin(xx / 25.0) * np.cos(yy / 20.0))[..., None].astype(np.float32)  # broad
    fine = rng.normal(0.0, 0.1, ref.shape).astype(np.float32)  # pixel noise
    t = np.full((60, 80), 0.5, np.float32)
    t[:, :8] = 0.01  # a hidden strip
    s = mod.view_scores(ref + smooth, ref, t, t + 0.05)
    n = mod.view_scores(ref + fine, ref, t, t)
    # a broad error is nearly gone once its 16-px low-pass is removed; pixel noise is not
    assert s["fine_16"] > s["psnr"] + 5.0
    assert s["fine_4"] > s["fine_8"] > s["fine_16"]  # a narrower low-pass leaves less of it
    assert n["fine_16"] < n["psnr"] + 0.5
    assert s["hidden_share"] == 0.1
    assert s["seen"] is not None and s["hidden"] is not None
    assert abs(s["t_bias_seen"] - 0.05) < 1e-6
    # an affine cast per channel is what the oracle takes out exactly
    cast = mod.view_scores(0.9 * ref + 0.05, ref, None, t)
    assert cast["affine"] > 60.0 and cast["psnr"] < 40.0
    assert cast["seen"] is None and cast["t_bias_seen"] is None


def test_a_cast_shared_by_every_view_is_taken_out(monkeypatch):
    mod = load_benchmark(monkeypatch, "error_scales")
    rng = np.random.default_rng(1)
    shared = np.array([0.1, -0.05, 0.02], np.float32)
    noise = [rng.normal(0.0, 0.01, (20, 30, 3)).astype(np.float32) for _ in range(3)]
    before = [mod._psnr(n + shared) for n in noise]
    after = mod.cast_removed([n + shared for n in noise])
    assert all(a > b + 15.0 for a, b in zip(after, before, strict=True))
    assert all(abs(a - mod._psnr(n)) < 0.1 for a, n in zip(after, noise, strict=True))
    assert mod.cast_removed([]) == []


def test_on_a_tiny_field_run(tmp_path):
    _, config, _ = tiny_field_run(tmp_path)
    out = tmp_path / "scales"
    row = run_diagnosis("error_scales.py", [config], out)
    assert len(row["views"]) > 0
    m = row["mean"]
    assert all(math.isfinite(m[k]) for k in ("psnr", "fine_4", "fine_8", "fine_16", "affine", "run_cast"))
    assert m["hidden_share"] is not None and 0.0 <= m["hidden_share"] <= 1.0
    assert "error finer than" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
