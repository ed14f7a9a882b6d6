"""benchmarks/arm_table.py: several td-bench restoration arms side by side."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.eval.test_paired_restoration import _result

REPO = Path(__file__).resolve().parents[2]


def _run(*args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, str(REPO / "benchmarks" / "arm_table.py"), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def test_rows_only_where_every_arm_finished_and_means_per_seed(tmp_path):
    arms = [tmp_path / n for n in ("a", "b", "c")]
    for k, arm in enumerate(arms):
        _result(arm, 42, "room", 15.0 + k, 0.10 - 0.01 * k)
        _result(arm, 42, "street", 18.0 + 2 * k, 0.07)
        _result(arm, 7, "room", 16.0 + k, 0.09)
    _result(arms[0], 7, "street", 17.0, 0.1)  # missing in b and c: no row
    _result(arms[2], 42, "field", 12.0, 0.1)  # only in c
    _result(arms[1], 7, "field", 11.0, 0.1, status="failed")
    out = tmp_path / "gap"
    proc = _run("--arms", *(f"{a.name}={a}" for a in arms), "--output", str(out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    data = json.loads(out.with_suffix(".json").read_text())
    rows = [r for r in data if "scene" in r]
    assert sorted((r["scene"], r["seed"]) for r in rows) == [("room", 7), ("room", 42), ("street", 42)]
    street = next(r for r in rows if r["scene"] == "street")
    assert street["psnr"] == [18.0, 20.0, 22.0] and street["observable"] == [19.0, 21.0, 23.0]
    assert street["reconstruction"] == [30.0, 30.0, 30.0]
    assert data[-1]["arms"] == ["a", "b", "c"]
    means = {m["seed"]: m for m in data[-1]["seed_means"]}
    assert means[42]["scenes"] == 2 and means[42]["psnr"] == [16.5, 18.0, 19.5]
    assert means[7]["psnr"] == [16.0, 17.0, 18.0]
    assert "16.50 / 18.00 / 19.50" in proc.stdout
    assert out.with_suffix(".png").is_file() and out.with_suffix(".md").is_file()


def test_bad_arms_are_usage_errors(tmp_path):
    proc = _run("--arms", f"a={tmp_path}", f"b={tmp_path / 'missing'}", "--output", str(tmp_path / "x"))
    assert proc.returncode == 2 and "existing folder" in proc.stderr and "Traceback" not in proc.stderr
    proc = _run("--arms", f"a={tmp_path}", "--output", str(tmp_path / "x"))
    assert proc.returncode == 2 and "at least two arms" in proc.stderr
    empty = tmp_path / "empty"
    empty.mkdir()
    proc = _run("--arms", f"a={tmp_path}", f"b={empty}", "--output", str(tmp_path / "x"))
    assert proc.returncode == 2 and "finished in every arm" in proc.stderr and "Traceback" not in proc.stderr
