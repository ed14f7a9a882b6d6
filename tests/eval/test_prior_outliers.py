"""benchmarks/prior_outliers.py: the shares on a view built by hand, then the script on a tiny
trained run."""

from __future__ import annotations

import torch

from pipelines.tridehaze.priors import ViewPrior
from tests.eval.diagnosis_script import load_benchmark, run_diagnosis


def test_far_outliers_are_all_in_the_trimmed_set(monkeypatch):
    """A tenth of the prior's pixels at 3x the true depth, the render on the truth: the trimmed
    fifth holds every outlier, and they make half of it."""
    mod = load_benchmark(monkeypatch, "prior_outliers")
    g = torch.Generator().manual_seed(0)
    true_z = 1.0 + 4.0 * torch.rand(20, 30, generator=g)  # [H, W]
    depth = torch.full_like(true_z, float("nan"))
    valid = torch.rand(20, 30, generator=g) < 0.5
    depth[valid] = true_z[valid]
    idx = valid.flatten().nonzero()[:, 0]
    bad = idx[torch.randperm(len(idx), generator=g)[: len(idx) // 10]]
    depth.view(-1)[bad] = 3.0 * true_z.view(-1)[bad]
    prior = ViewPrior(depth=depth, depth_valid=valid)
    shares = mod._view_shares(prior, true_z, true_z.clone())
    assert abs(shares["outliers"] - len(bad) / len(idx)) < 1e-6
    assert shares["outliers_caught"] == 1.0
    assert 0.45 < shares["outliers_in_trim"] <= 0.5
    assert shares["render_off"] == 0.0


def test_on_a_tiny_courtyard_run(courtyard_run, tmp_path):
    out = tmp_path / "po"
    row = run_diagnosis("prior_outliers.py", [courtyard_run], out)
    assert row["views"] > 0
    for key in ("outliers", "outliers_in_trim", "outliers_caught", "render_off", "render_off_in_trim"):
        assert 0.0 <= row[key] <= 1.0, key
    assert "prior pixels" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
