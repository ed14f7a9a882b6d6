"""benchmarks/paired_restoration.py: two arms of td-bench restoration paired by scene and seed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _result(folder: Path, seed: int, scene: str, psnr: float, t_mae: float, status: str = "ok") -> None:
    path = folder / f"seed{seed}" / "results" / scene / "tri-dehaze.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    result = {"status": status, "restoration": {"psnr": psnr, "ssim": 0.5}, "observable": {"psnr": psnr + 1},
              "medium": {"t_mae": t_mae, "s_mae": 0.05}, "reconstruction": {"psnr": 30.0}, "train_seconds": 100.0}  # fmt: skip
    path.write_text(json.dumps(result))


def test_pairs_by_scene_and_seed_and_calls_a_scene_only_when_every_seed_agrees(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for seed, (pa, pb) in {42: (15.0, 16.0), 7: (15.5, 16.5)}.items():
        _result(a, seed, "room", pa, 0.10)
        _result(b, seed, "room", pb, 0.08)  # better at both seeds
    _result(a, 42, "street", 18.0, 0.07), _result(b, 42, "street", 17.0, 0.08)  # worse at one,
    _result(a, 7, "street", 18.0, 0.07), _result(b, 7, "street", 18.5, 0.06)  # better at the other
    _result(a, 42, "field", 12.0, 0.1), _result(b, 42, "field", 11.0, 0.1, status="failed")  # not paired
    _result(a, 7, "court", 12.0, 0.1)  # only in one arm
    out = tmp_path / "cmp"
    cmd = [sys.executable, str(REPO / "benchmarks" / "paired_restoration.py"), "--arms", f"ref={a}", f"new={b}",
           "--output", str(out)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    data = json.loads(out.with_suffix(".json").read_text())
    rows = [r for r in data if "scene" in r]
    assert sorted((r["scene"], r["seed"]) for r in rows) == [
        ("room", 7),
        ("room", 42),
        ("street", 7),
        ("street", 42),
    ]
    assert data[-1]["verdicts"] == {"room": "better", "street": "mixed"}
    means = {m["seed"]: m for m in data[-1]["seed_means"]}
    assert means[42]["psnr"] == [16.5, 16.5] and means[7]["psnr"] == [16.75, 17.5]
    assert means[7]["t_mae"][1] == 0.07
    assert "better: 1, worse: 0, mixed: 1" in proc.stdout
    assert out.with_suffix(".png").is_file() and out.with_suffix(".md").is_file()


def test_a_missing_arm_folder_is_a_usage_error(tmp_path):
    cmd = [sys.executable, str(REPO / "benchmarks" / "paired_restoration.py"), "--arms", f"a={tmp_path}",
           f"b={tmp_path / 'missing'}", "--output", str(tmp_path / "x")]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "existing folder" in proc.stderr and "Traceback" not in proc.stderr
