"""benchmarks/light_colour.py: the haze light's colour (dark channel, truth, model) and the clean cast."""

from __future__ import annotations

import torch

from pipelines.tridehaze.light_colour_fit import mean_ray_light
from tests.eval.diagnosis_script import run_diagnosis, tiny_field_run


def test_mean_light_reads_only_hazy_pixels():
    """The script's mean light is the light colour fit's (pipelines/tridehaze/light_colour_fit.py)."""
    T = torch.tensor([[0.5, 0.9]])  # [1, 2]: the second pixel has 10 % haze
    S = torch.tensor([[[0.3, 0.35, 0.4], [0.5, 0.5, 0.5]]])  # [1, 2, 3]
    assert torch.allclose(mean_ray_light(T, S), torch.tensor([0.6, 0.7, 0.8]))
    assert mean_ray_light(torch.ones(1, 2), S) is None


def test_on_a_tiny_field_run(tmp_path):
    """Lights in (0, 1]; taking the mean cast out never lowers the PSNR (it minimises the error)."""
    _, config, _ = tiny_field_run(tmp_path)
    out = tmp_path / "colour"
    row = run_diagnosis("light_colour.py", [config], out)
    for key in ("airlight_dcp", "light_true", "light_model"):
        assert len(row[key]) == 3 and all(0.0 < c <= 1.0 for c in row[key]), key
    assert len(row["cast"]) == 3 and all(abs(c) < 1.0 for c in row["cast"])
    assert row["psnr_without_cast"] >= row["psnr"] - 1e-9
    assert "| clean colour cast (RGB) |" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
