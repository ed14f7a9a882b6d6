"""benchmarks/seed_agreement.py: whether the clean render's error is bias or seed noise."""

from __future__ import annotations

import json
import math

import numpy as np

from tests.eval.diagnosis_script import REPO, load_benchmark


def test_noise_averages_out_and_bias_does_not(monkeypatch):
    mod = load_benchmark(monkeypatch, "seed_agreement")
    rng = np.random.default_rng(0)
    ref = rng.uniform(0.2, 0.8, (40, 50, 3))
    noise = [rng.normal(0.0, 0.05, ref.shape) for _ in range(2)]
    indep = mod.view_agreement([ref + n for n in noise], ref)
    # two independent errors of one size: the average halves the squared error (+3 dB)
    assert abs(indep["ensemble"] - np.mean(indep["psnr"]) - 10 * math.log10(2)) < 0.2
    assert abs(indep["error_corr"]) < 0.05
    bias = rng.normal(0.0, 0.05, ref.shape)
    shared = mod.view_agreement([ref + bias, ref + bias + 0.1 * noise[0]], ref)
    assert shared["error_corr"] > 0.95
    assert shared["ensemble"] - np.mean(shared["psnr"]) < 0.1


def test_t_errors_and_scene_groups(monkeypatch, tmp_path):
    mod = load_benchmark(monkeypatch, "seed_agreement")
    true_t = np.full((4, 5), 0.5)
    out = mod.t_errors([true_t + 0.1, true_t - 0.1], true_t)
    assert np.allclose(out["t_mae"], [0.1, 0.1]) and out["t_mae_ensemble"] < 1e-12
    assert mod.t_errors([true_t], None) == {"t_mae": [None], "t_mae_ensemble": None}
    a = tmp_path / "arm/seed42/runs/room/tri-dehaze/tri-dehaze/config.yml"
    b = tmp_path / "arm/seed7/runs/room/tri-dehaze/tri-dehaze/config.yml"
    c = tmp_path / "arm/seed7/runs/street/tri-dehaze/tri-dehaze/config.yml"
    assert mod.group_by_scene([a, b, c]) == {"room": [a, b], "street": [c]}


def test_on_two_seeds_of_a_tiny_run(tmp_path):
    import subprocess
    import sys

    from tests.export.tiny_run import train_tiny
    from tests.tiny_scenes import tiny_hazy_scene

    scene = tiny_hazy_scene(
        tmp_path / "scene", layout="field", haze="height", seed=2, num_views=6, width=40, height=30,
        samples=16, num_points=300, test_every=3,
    )  # fmt: skip
    configs = [
        train_tiny(scene, tmp_path / f"s{s}" / "runs" / "field", "--seed", str(s), steps=4) for s in (1, 2)
    ]
    out = tmp_path / "agreement"
    cmd = [sys.executable, str(REPO / "benchmarks" / "seed_agreement.py"), "--runs", *map(str, configs)]
    proc = subprocess.run([*cmd, "--output", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = json.loads(out.with_suffix(".json").read_text())
    assert len(rows) == 1 and rows[0]["seeds"] == [1, 2]
    m = rows[0]["mean"]
    assert len(m["psnr"]) == 2 and all(math.isfinite(p) for p in m["psnr"])
    assert math.isfinite(m["ensemble"]) and -1.0 <= m["error_corr"] <= 1.0
    assert m["t_mae_ensemble"] is not None
    assert "averaged render" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
    # one run per scene is not enough: a clear refusal
    one = subprocess.run([*cmd[:-1], "--output", str(tmp_path / "one")], capture_output=True, text=True)
    assert one.returncode != 0 and "no scene has two runs" in one.stderr
