"""benchmarks/depth_diagnosis.py on a tiny trained run: the model's T error is the run's own, and the
true-T bins partition the test pixels."""

from __future__ import annotations

from pathlib import Path

import torch

from pipelines.engine.run_loader import load_run
from tests.eval.diagnosis_script import load_benchmark, run_diagnosis


def _model_t_mae(config: Path, monkeypatch) -> float:
    """Mean |T_model - T_true| over the test views' pixels, from the run itself."""
    reference_views = load_benchmark(monkeypatch, "reference_views").reference_views
    run = load_run(config)
    errors = []
    with torch.no_grad():
        for view in reference_views(run.datamanager):
            T = run.pipeline.render(view.camera)["transmittance"][..., 0]  # [H, W]
            errors.append((T - view.true_t[..., 0]).abs().flatten())
    return float(torch.cat(errors).mean())


def test_on_a_tiny_courtyard_run(courtyard_run, tmp_path, monkeypatch):
    config = courtyard_run  # the run's config.yml
    out = tmp_path / "dd"
    row = run_diagnosis("depth_diagnosis.py", [config], out)
    expected = _model_t_mae(config, monkeypatch)
    assert expected > 0.01 and abs(row["t_mae_model"] - expected) < 1e-5
    assert row["depth_ratio_p10"] <= row["depth_ratio_median"] <= row["depth_ratio_p90"]
    assert 0.0 <= row["t_mae_depth_only"] <= 1.0
    shares = [b["share"] for b in row["bins"]]
    assert shares and abs(sum(shares) - 1.0) < 0.05  # bins under 10 pixels are left out
    assert "end depth / true" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
