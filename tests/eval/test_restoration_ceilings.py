"""benchmarks/restoration_ceilings.py: the haze-free copy of a set, the true-medium inversion of
its test photos, and arms of td-bench restoration side by side."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.tiny_scenes import tiny_hazy_scene

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "benchmarks" / "restoration_ceilings.py"


def _result(folder: Path, seed: int, scene: str, method: str, psnr: float) -> None:
    path = folder / f"seed{seed}" / "results" / scene / f"{method}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"status": "ok", "restoration": {"psnr": psnr}, "medium": {"t_mae": 0.05}}))


def test_clean_copy_inversion_and_arms(tmp_path):
    hazy = tmp_path / "set"
    tiny_hazy_scene(hazy / "room", layout="room", haze="uniform", seed=3, num_views=4, test_every=2)
    clean = tmp_path / "clean"
    proc = subprocess.run([sys.executable, str(SCRIPT), "--set-dir", str(hazy), "--make-clean-set", str(clean)],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    meta = json.loads((clean / "room" / "transforms.json").read_text())
    assert all(
        "gt_transmittance_file_path" not in f and "gt_scattering_file_path" not in f for f in meta["frames"]
    )
    photo = meta["frames"][0]["file_path"]
    assert (clean / "room" / photo).read_bytes() == (hazy / "room" / "clean" / Path(photo).name).read_bytes()
    assert (clean / "room" / "points3d.ply").is_file()

    base, ceil = tmp_path / "base", tmp_path / "ceil"
    _result(base, 42, "room", "tri-dehaze", 15.0)
    _result(base, 7, "room", "tri-dehaze", 16.0)
    _result(ceil, 42, "room", "vanilla-gs", 25.0)
    out = tmp_path / "ceilings"
    cmd = [sys.executable, str(SCRIPT), "--set-dir", str(hazy), "--arms", f"default={base}:tri-dehaze",
           f"clean-photos={ceil}:vanilla-gs", "--output", str(out)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (row,) = json.loads(out.with_suffix(".json").read_text())
    assert row["arms"]["default"]["psnr"] == 15.5 and row["arms"]["default"]["spread"] == 1.0
    assert row["arms"]["clean-photos"]["psnr"] == 25.0 and row["arms"]["clean-photos"]["spread"] is None
    # no sky in a room: the true medium inverts the image formation up to 8-bit rounding
    assert row["true_inversion_best"][1] > 35.0, row["true_inversion"]
    assert out.with_suffix(".md").is_file() and out.with_suffix(".png").is_file()


def test_a_bad_arm_is_a_usage_error(tmp_path):
    cmd = [sys.executable, str(SCRIPT), "--set-dir", str(tmp_path), "--arms", f"a={tmp_path / 'no'}:tri-dehaze",
           "--output", str(tmp_path / "x")]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "existing folder" in proc.stderr and "Traceback" not in proc.stderr
