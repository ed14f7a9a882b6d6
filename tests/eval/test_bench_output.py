"""benchmarks/bench_output.py: the small numeric helpers every diagnosis shares."""

from __future__ import annotations

import math

from tests.eval.diagnosis_script import load_benchmark


def test_psnr_of_mse_is_peak_one_and_finite_at_zero(monkeypatch):
    mod = load_benchmark(monkeypatch, "bench_output")
    assert math.isclose(mod.psnr_of_mse(0.01), 20.0)
    assert math.isclose(mod.psnr_of_mse(1.0), 0.0, abs_tol=1e-12)
    assert math.isclose(mod.psnr_of_mse(0.0), 120.0)  # the 1e-12 floor, not infinity


def test_mean_or_none_skips_missing_values(monkeypatch):
    mod = load_benchmark(monkeypatch, "bench_output")
    assert mod.mean_or_none([1.0, None, 3.0]) == 2.0
    assert mod.mean_or_none([None, None]) is None
    assert mod.mean_or_none([]) is None
    assert mod.mean_or_none(None) is None
