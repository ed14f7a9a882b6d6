"""td-bench probe's tables: counts by truth and verdict, the fast-vs-tri-dehaze target, mistake costs."""

from __future__ import annotations

from pathlib import Path

from pipelines.experiments.probe_bench import confusion, mistake_costs, restoration_table
from pipelines.experiments.probe_set import scene_set


def _row(scene, truth, haze, right, sparse=False, split="held-out"):
    return {
        "scene": scene,
        "truth": truth,
        "haze": haze,
        "backend_right": right,
        "sparse": sparse,
        "split": split,
    }


ROWS = [
    _row("a", "none", "none", True),
    _row("b", "none", "unsure", False),
    _row("c", "homogeneous", "homogeneous", True),
    _row("d", "varying", "unsure", True),
    _row("d+sparse", "varying", "varying", True, sparse=True),
]


def test_confusion_counts_each_verdict_and_backend_accuracy():
    table = confusion(ROWS)
    assert "| none (2) | 1 | 0 | 0 | 1 | 1/2 (50%) |" in table
    assert "| homogeneous (1) | 0 | 1 | 0 | 0 | 1/1 (100%) |" in table
    assert "| varying (2) | 0 | 0 | 1 | 1 | 2/2 (100%) |" in table


def test_restoration_target_and_mistake_cost():
    ok = {"status": "ok"}
    results = {
        ("c", "fast"): {**ok, "restoration": {"psnr": 19.0}, "cpu_seconds": 50.0},
        ("c", "tri-dehaze"): {**ok, "restoration": {"psnr": 20.0}, "cpu_seconds": 300.0},
        ("d", "fast"): {**ok, "restoration": {"psnr": 17.0}, "cpu_seconds": 150.0},
        ("d", "tri-dehaze"): {**ok, "restoration": {"psnr": 19.0}, "cpu_seconds": 300.0},
        ("b", "fast"): {**ok, "restoration": {"psnr": 15.0}},
        ("b", "fast-none"): {**ok, "restoration": {"psnr": 25.0}},
    }
    md, rows = restoration_table(ROWS, results)
    by = {r["scene"]: r for r in rows}
    assert set(by) == {"c", "d"}  # hazy scenes with their own seed cloud only
    assert by["c"]["within_target"] is True and by["c"]["time_ratio"] == 50 / 300
    assert by["d"]["within_target"] is False and by["d"]["gap_db"] == -2.0  # too slow and too far
    md, costs = mistake_costs(ROWS, results)
    assert costs == [{"scene": "b", "truth": "none", "probe": "unsure", "psnr_probe": 15.0, "psnr_right": 25.0,
                      "cost_db": 10.0}]  # fmt: skip


def test_scene_set_has_a_held_back_part_from_other_generators(tmp_path: Path):
    scenes = scene_set(tmp_path, None)
    held = {s.family for s in scenes if s.split == "held-out"}
    cal = {s.family for s in scenes if s.split == "calibration"}
    assert held == {"sunlit"} and cal == {"synth"}  # no real sets without their folder
    assert {s.truth for s in scenes if s.split == "held-out"} == {"none", "homogeneous", "varying"}
    assert sum(s.sparse for s in scenes) == len(scenes) // 2  # each scene also with a degraded cloud
