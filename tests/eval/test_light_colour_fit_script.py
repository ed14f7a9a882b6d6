"""benchmarks/light_colour_fit.py: what the light colour fit reads on a trained run, against the truth."""

from __future__ import annotations

import torch

from tests.eval.diagnosis_script import load_benchmark, tiny_field_run


def test_on_a_tiny_field_run(tmp_path, monkeypatch):
    """With the true T, the fit reads the true light's colour (the tiny scene's few points let
    through); both lights and both fits are reported, and the table and plot are written."""
    import pipelines.tridehaze.light_colour_fit as fit

    monkeypatch.setattr(fit, "MIN_POINTS", 5)
    monkeypatch.setattr(fit, "MIN_VIEWS", 2)
    mod = load_benchmark(monkeypatch, "light_colour_fit")
    _, config, _ = tiny_field_run(tmp_path)
    torch.set_grad_enabled(False)
    try:
        row = mod.diagnose(config)
    finally:
        torch.set_grad_enabled(True)
    assert row["fit_true_t_points"] >= 5 and row["fit_model_t"] is not None
    true_chroma = fit.chroma(torch.tensor(row["light_true"]))
    torch.testing.assert_close(fit.chroma(torch.tensor(row["fit_true_t"])), true_chroma, atol=0.02, rtol=0)
    assert all(0.0 < c <= 1.0 for c in row["light_model"]) and row["light_spread"] >= 0.0
    table = mod.markdown([row])
    assert "| fit's standard error (model T) |" in table and "| scene | 42 |" in table
    mod.plot([row], tmp_path / "fit.png")
    assert (tmp_path / "fit.png").stat().st_size > 0
