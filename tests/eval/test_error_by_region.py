"""benchmarks/error_by_region.py: what each region of the test views would be worth if perfect."""

from __future__ import annotations

import math

import torch

from tests.eval.diagnosis_script import load_benchmark, run_diagnosis, tiny_field_run


def test_region_masks_partition_the_view(monkeypatch):
    mod = load_benchmark(monkeypatch, "error_by_region")
    true_t = torch.tensor([[0.01, 0.2, 0.5], [0.8, 1.0, 0.01]])
    sky = torch.tensor([[False, False, False], [False, False, True]])
    masks = mod.region_masks(true_t, sky)
    total = sum(m.long() for m in masks.values())
    assert torch.equal(total, torch.ones_like(total))  # every pixel in exactly one region
    assert masks["sky"][1, 2] and masks["hidden"][0, 0] and masks["T<0.3"][0, 1]
    assert masks["T<0.7"][0, 2] and masks["T>=0.7"][1, 0] and masks["T>=0.7"][1, 1]


def test_on_a_tiny_field_run(tmp_path):
    """Shares are the truth's and add up to one; making a region exact never lowers the PSNR."""
    _, config, sky = tiny_field_run(tmp_path)
    out = tmp_path / "regions"
    row = run_diagnosis("error_by_region.py", [config], out)
    regions = row["regions"]
    assert 0.05 < sky < 0.95
    assert math.isclose(regions["sky"]["share"], sky, abs_tol=1e-6)
    assert math.isclose(sum(g["share"] for g in regions.values()), 1.0, abs_tol=1e-9)
    for g in regions.values():
        assert g["gain_if_perfect"] >= -1e-9  # removing error never lowers PSNR
        if g["share"] > 0:
            assert 0.0 <= g["t_model"] <= 1.0 and 0.0 <= g["t_true"] <= 1.0 and g["depth_ratio"] > 0
    assert regions["sky"]["gain_if_perfect"] > 0.0
    assert "| region | share |" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
