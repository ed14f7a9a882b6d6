"""benchmarks/sky_split.py: restoration split into sky and surfaces by the true depth."""

from __future__ import annotations

import math

import torch

from tests.eval.diagnosis_script import load_benchmark, run_diagnosis, tiny_field_run


def _module(monkeypatch):
    return load_benchmark(monkeypatch, "sky_split")


def test_regions_add_up_and_psnr_of_known_errors(monkeypatch):
    mod = _module(monkeypatch)
    clean = torch.zeros(4, 5, 3)
    ref = torch.zeros(4, 5, 3)
    sky = torch.zeros(4, 5, dtype=torch.bool)
    sky[0] = True  # 5 sky pixels, each off by 0.1 in every channel
    ref[0] = 0.1
    ref[1:, :, 0] = 0.01  # 15 surface pixels, off by 0.01 in one channel
    sums = mod.region_sums(clean, ref, sky)
    assert sums["sky"][1] == 5 and sums["surface"][1] == 15 and sums["all"][1] == 20
    assert math.isclose(sums["all"][0], sums["sky"][0] + sums["surface"][0], rel_tol=1e-6)
    assert math.isclose(mod.psnr_of(sums["sky"]), 20.0, abs_tol=1e-4)  # MSE 0.01
    assert math.isclose(mod.psnr_of(sums["surface"]), -10 * math.log10(1e-4 / 3), abs_tol=1e-3)
    assert mod.psnr_of((0.0, 0)) is None
    assert mod.arm_of("/x/holds/seed7/runs/field/tri-dehaze/tri-dehaze") == "holds"
    assert mod.arm_of("/x/outputs/myrun") == "myrun"


def test_on_a_tiny_field_run(tmp_path):
    """The sky share is the true depth's, and the whole picture's error is the two regions' sum."""
    _, config, share = tiny_field_run(tmp_path)
    out = tmp_path / "sky"
    row = run_diagnosis("sky_split.py", [config], out)
    assert 0.05 < share < 0.95  # the field shows both
    assert math.isclose(row["sky_share"], share, abs_tol=1e-6)
    for key in ("t0=0", "t0=0.1"):
        p = row["psnr"][key]
        mse = {k: 10 ** (-p[k] / 10) for k in ("all", "sky", "surface")}
        assert math.isclose(mse["all"], share * mse["sky"] + (1 - share) * mse["surface"], rel_tol=1e-3)
    assert 0.0 <= row["sky_t_model"] <= 1.0 and 0.0 <= row["sky_t_true"] <= 1.0
    assert "sky T model / true" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
