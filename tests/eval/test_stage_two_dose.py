"""benchmarks/stage_two_dose.py: Stage II arms summarised by set, setting and seed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "stage_two_dose.py"


def pairs(seed: str, changes: dict[str, float]) -> list[dict]:
    """A stage_two_arm pairs list: every scene's base at 20 dB, continued by its change."""
    return [
        {"seed": seed, "scene": s, "base": {"psnr": 20.0}, "continued": {"psnr": 20.0 + d}}
        for s, d in changes.items()
    ]


def test_mean_and_where_it_comes_from(tmp_path):
    a = tmp_path / "a.json"
    a.write_text(
        json.dumps(pairs("seed42", {"x": 1.0, "y": 0.01, "z": -0.1}) + pairs("seed7", {"x": 0.3, "y": 0.0}))
    )
    b = tmp_path / "b.json"
    b.write_text(json.dumps(pairs("seed42", {"x": -0.05, "y": 0.05})))
    out = tmp_path / "dose"
    cmd = [sys.executable, str(SCRIPT), "--arms", f"bench:0.3={a}", f"hold:0.5={b}", "--output", str(out)]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    rows = json.loads(out.with_suffix(".json").read_text())
    by = {(r["set"], r["value"], r["seed"]): r for r in rows}
    r = by[("bench", "0.3", "seed42")]
    assert r["mean_change"] == pytest.approx(0.91 / 3)
    assert (r["runs"], r["up"], r["down"]) == (3, 1, 1)  # y's +0.01 is a tie at 0.02
    assert (r["best_scene"], r["worst_scene"]) == ("x", "z")
    assert r["best"] == pytest.approx(1.0) and r["worst"] == pytest.approx(-0.1)
    assert r["mean_without_best"] == pytest.approx(-0.09 / 2)  # the mean is one scene's
    assert by[("bench", "0.3", "seed7")]["mean_change"] == pytest.approx(0.15)
    assert by[("hold", "0.5", "seed42")]["mean_change"] == pytest.approx(0.0)
    assert "| bench | 0.3 | seed42 | 3 | +0.30 | 1 / 1 |" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0


def test_a_malformed_arm_is_refused(tmp_path):
    cmd = [sys.executable, str(SCRIPT), "--arms", "bench=x.json", "--output", str(tmp_path / "o")]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode != 0 and "expected SET:VALUE=PAIRS_JSON" in done.stderr
    assert "Traceback" not in done.stderr


def test_a_missing_pairs_file_is_refused(tmp_path):
    cmd = [
        sys.executable,
        str(SCRIPT),
        "--arms",
        f"bench:0.3={tmp_path / 'none.json'}",
        "--output",
        str(tmp_path / "o"),
    ]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode != 0 and "no file" in done.stderr and "pairs.json" in done.stderr
    assert "Traceback" not in done.stderr and not (tmp_path / "o.json").exists()
