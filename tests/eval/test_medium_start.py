"""benchmarks/medium_start.py on a tiny trained run: the light ratio reads 1 for a start at the true light."""

from __future__ import annotations

import torch

from pipelines.engine.medium_recovery import REFERENCE_S_KEY, REFERENCE_T_KEY, reference_map
from pipelines.engine.trainer import Trainer
from tests.eval.diagnosis_script import run_diagnosis
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args

LIGHT_T_MAX = 0.6  # benchmarks/medium_start.py's


def _true_light(trainer: Trainer) -> tuple[float, float, float]:
    """sum S / sum (1 - T) over the test views' pixels with true T below LIGHT_T_MAX."""
    dm = trainer.datamanager
    s_sum, w_sum = torch.zeros(3), torch.zeros(())
    for i in dm.test_indices:
        cam = dm.camera(i)
        size = (int(cam.height[0]), int(cam.width[0]))
        t = reference_map(dm, REFERENCE_T_KEY, i, size)[..., 0].cpu()  # [H, W]
        s = reference_map(dm, REFERENCE_S_KEY, i, size).cpu()  # [H, W, 3]
        m = t < LIGHT_T_MAX
        s_sum += s[m].sum(0)
        w_sum += (1.0 - t[m]).sum()
    light = (s_sum / w_sum).tolist()
    return (light[0], light[1], light[2])


def test_light_ratio_is_one_for_a_start_at_the_true_light(tmp_path):
    from rich.console import Console

    scene = tiny_hazy_scene(
        tmp_path / "scene", layout="courtyard", haze="homogeneous", seed=4, num_views=6, width=40,
        height=30, samples=16, num_points=300, test_every=3,
    )  # fmt: skip
    common = ["tri-dehaze", "--data", str(scene), "--output-dir", str(tmp_path / "runs"), "--max-steps", "4",
              "--device", "cpu", "--pipeline.rasterizer.backend", "torch", "--no-eval-at-end"]  # fmt: skip
    probe = Trainer(parse_args([*common, "--timestamp", "probe"]), console=Console(quiet=True))
    probe.setup()
    light = _true_light(probe)
    argv = [*common, "--timestamp", "run", "--pipeline.airlight", *(f"{v:.6f}" for v in light)]
    trainer = Trainer(parse_args(argv), console=Console(quiet=True))
    trainer.setup()
    trainer.train()
    config = next((tmp_path / "runs").rglob("run/config.yml"))
    out = tmp_path / "ms"
    row = run_diagnosis("medium_start.py", [config], out)
    assert abs(row["light_ratio_start"] - 1.0) < 1e-3
    assert 0.2 < row["light_ratio_trained"] < 5.0
    assert max(abs(a - b) for a, b in zip(row["light_start"], light, strict=True)) < 1e-5
    assert "light model / true" in out.with_suffix(".md").read_text()
    assert out.with_suffix(".png").stat().st_size > 0
