"""The iteration-cost benchmark runs end to end on a tiny scene and writes its table files."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_iteration_cost_benchmark_smoke(tmp_path):
    out = tmp_path / "iteration_cost"
    cmd = [sys.executable, str(REPO / "benchmarks" / "iteration_cost.py"), "--width", "48", "--height", "36",
           "--points", "300", "--views", "4", "--rounds", "1", "--steps", "1", "--out", str(out)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    data = json.loads(out.with_suffix(".json").read_text())
    names = [r["variant"] for r in data["rows"]]
    assert names[0] == "vanilla-gs" and any("every pixel" in n for n in names)
    assert data["rows"][0]["ratio_to_vanilla"] == 1.0
    assert all(r["median_s"] > 0 for r in data["rows"])
    assert out.with_suffix(".csv").is_file()
    assert "x vanilla" in proc.stdout
