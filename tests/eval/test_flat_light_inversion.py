"""benchmarks/flat_light_inversion.py: the test views inverted with the learnt and a flat light."""

from __future__ import annotations

import math

from tests.eval.diagnosis_script import run_diagnosis, tiny_field_run


def test_on_a_tiny_field_run(tmp_path):
    _, config, _ = tiny_field_run(tmp_path)
    out = tmp_path / "flat"
    row = run_diagnosis("flat_light_inversion.py", [config], out)
    learnt, flat = row["inverted_learnt"], row["inverted_flat"]
    assert len(learnt) == len(flat) == len(row["clean_offset"]) > 0
    assert all(math.isfinite(x) for x in learnt + flat)
    assert learnt != flat  # the flat light changes the in-scattering, so the inversion
    assert all(len(o) == 3 and all(abs(c) <= 1.0 for c in o) for o in row["clean_offset"])
    assert row["light_spread"] is not None and row["light_spread"] >= 0.0
    assert "inverted PSNR, learnt light -> flat" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
