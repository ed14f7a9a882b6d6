"""benchmarks/light_isotropy_split.py: each run's logged light spread and the weight it chose."""

from __future__ import annotations

import json

from tests.eval.diagnosis_script import run_diagnosis
from tests.export.tiny_run import make_scene, train_tiny


def test_rows_follow_each_runs_decision(tmp_path):
    scene = make_scene(tmp_path / "scene")
    configs = {}
    for name, threshold in (("always", "1.0"), ("never", "0.0")):
        configs[name] = train_tiny(
            scene, tmp_path / name, "--pipeline.freeze-step", "6", "--pipeline.light-isotropy-cv", threshold,
            steps=8,
        )  # fmt: skip  # the decision at step 2, inside Stage I
    configs["gated"] = train_tiny(
        scene, tmp_path / "gated", "--pipeline.freeze-step", "6", "--pipeline.light-isotropy-cv", "1.0",
        "--pipeline.light-seen-share", "0.0", "--pipeline.light-seen-level", "0.15", steps=8,
    )  # fmt: skip  # one light, and gated by any pixel under T 0.15
    out = tmp_path / "split"
    run_diagnosis("light_isotropy_split.py", list(configs.values()), out)
    rows = {r["run"]: r for r in json.loads(out.with_suffix(".json").read_text())}
    for name, weight in (("always", 1.0), ("never", 0.1)):
        run_dir = configs[name].parent
        logged = [json.loads(x) for x in (run_dir / "logs" / "decisions.jsonl").read_text().splitlines()]
        logged = [r for r in logged if "light_cv" in r]
        row = rows[str(run_dir)]
        assert len(logged) == 1 and row["light_cv"] == logged[0]["light_cv"]
        assert row["dcp_weight"] == weight and row["decision_step"] == logged[0]["step"]
        assert row["restoration_psnr"] is None  # no td-eval ran
        assert row["opaque_share"] == logged[0]["opaque_0.05"] and 0.0 <= row["opaque_share"] <= 1.0
    gated = rows[str(configs["gated"].parent)]
    assert gated["seen_share"] == 0.0 and gated["seen_level"] == 0.15
    assert gated["dcp_weight"] == (0.1 if gated["opaque_share"] > 0.0 else 1.0)
    assert out.with_suffix(".png").stat().st_size > 0
    assert "| scene | set | seed | light spread (cv)" in out.with_suffix(".md").read_text()
