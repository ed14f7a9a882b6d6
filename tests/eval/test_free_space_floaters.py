"""benchmarks/free_space_floaters.py: the Gaussians in free space in front of the true surfaces."""

from __future__ import annotations

import torch

from tests.eval.diagnosis_script import load_benchmark, run_diagnosis, tiny_field_run


def test_groups_weigh_colour_by_opacity(monkeypatch):
    mod = load_benchmark(monkeypatch, "free_space_floaters")
    mask = torch.tensor([True, True, False])
    opacity = torch.tensor([0.25, 0.75, 0.5])
    rgb = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.3, 0.3, 0.3]])
    g = mod._group(mask, opacity, rgb)
    assert g["count"] == 2 and abs(g["opacity"] - 0.5) < 1e-6
    assert torch.allclose(torch.tensor(g["rgb"]), torch.tensor([0.25, 0.0, 0.75]))
    assert abs(g["saturation"] - 1.0) < 1e-6
    assert mod._group(torch.zeros(3, dtype=torch.bool), opacity, rgb)["opacity"] is None


def test_on_a_tiny_field_run(tmp_path):
    _, config, _ = tiny_field_run(tmp_path)
    out = tmp_path / "floaters"
    row = run_diagnosis("free_space_floaters.py", [config], out)
    f, o = row["floaters"], row["others"]
    assert f["count"] + o["count"] == row["gaussians"] > 0
    for share in row["alpha_share_by_true_t"]:
        assert share is None or 0.0 <= share <= 1.0 + 1e-6
    assert any(s is not None for s in row["alpha_share_by_true_t"])
    rule = row["rendered_rule"]
    assert 0.0 <= rule["precision"] <= 1.0 and 0.0 <= rule["recall_by_opacity"] <= 1.0 + 1e-6
    assert "alpha share from floaters" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
