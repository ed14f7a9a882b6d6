"""benchmarks/medium_along_rays.py: the trained medium's optical depth along the rays against the
generator's own medium, by quarter of the path."""

from __future__ import annotations

import math

from tests.eval.diagnosis_script import run_diagnosis
from tests.export.tiny_run import train_tiny
from tests.tiny_scenes import tiny_hazy_scene


def test_a_scaled_true_medium_reads_as_its_scale_in_every_quarter(tmp_path):
    """A run whose medium is the generator's own with its extinction x2 and light x0.5 (the
    ``reference`` backend) reads 2 in each quarter of the path and 0.5 for the light."""
    scene = tiny_hazy_scene(
        tmp_path / "scene", layout="courtyard", haze="patchy", seed=2, num_views=6, width=40, height=30,
        samples=16, num_points=300, test_every=3,
    )  # fmt: skip
    config = train_tiny(
        scene, tmp_path / "runs", "--device", "cpu", "--pipeline.medium.backend", "reference",
        "--pipeline.medium.reference-scale", "2", "0.5", steps=2,
    )  # fmt: skip
    out = tmp_path / "along"
    row = run_diagnosis("medium_along_rays.py", [config], out)
    assert row["pixels"] > 100
    for q in row["optical_depth_ratio_by_quarter"]:
        assert math.isclose(q, 2.0, rel_tol=1e-4)
    assert math.isclose(row["optical_depth_ratio"], 2.0, rel_tol=1e-4)
    assert math.isclose(row["light_ratio"], 0.5, rel_tol=1e-3)
    assert "by quarter of the path" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
