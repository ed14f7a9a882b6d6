"""Short tri-dehaze runs stay finite at the extremes: no haze, near-opaque haze, T_min at both ends
of its range, scenes in tiny and huge units."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from rich.console import Console

from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args

STEPS = 12


def _scene(root: Path, haze: str, beta_scale: float = 1.0) -> Path:
    return tiny_hazy_scene(root, layout="street", haze=haze, beta_scale=beta_scale, seed=6, test_every=4)


def _rescaled(src: Path, dst: Path, scale: float) -> Path:
    """The same scene in other units: camera positions and seed points multiplied by ``scale``."""
    import shutil

    from components.data.ply import read_ply_points, write_ply_points

    shutil.copytree(src, dst)
    meta = json.loads((dst / "transforms.json").read_text())
    for f in meta["frames"]:
        m = np.array(f["transform_matrix"])
        m[:3, 3] *= scale
        f["transform_matrix"] = m.tolist()
    (dst / "transforms.json").write_text(json.dumps(meta))
    ply = dst / meta["ply_file_path"]
    pts, cols = read_ply_points(ply)
    write_ply_points(ply, pts * scale, cols)
    return dst


def _train(scene: Path, out: Path, device: torch.device, *extra: str):
    cfg = parse_args([
        "tri-dehaze", "--data", str(scene), "--output-dir", str(out), "--max-steps", str(STEPS),
        "--device", str(device),
        "--pipeline.freeze-step", "6", "--pipeline.medium-hold-fraction", "0", "--pipeline.rasterizer.backend",
        "torch", "--steps-per-save", "100", "--threads", "1", *extra,
    ])  # fmt: skip
    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.setup()
    result = trainer.train()
    return trainer, result


def _assert_sound(trainer, result):
    assert "skipped_nonfinite_steps" not in result.metrics
    for name, p in trainer.pipeline.named_parameters():
        assert torch.isfinite(p).all(), name
    out = trainer.pipeline.render(trainer.datamanager.camera(0))
    for name, t in out.items():
        assert torch.isfinite(t).all(), name
    T = out["transmittance"]
    assert float(T.min()) > 0 and float(T.max()) <= 1


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("extremes")
    return {
        "none": _scene(root / "none", "none"),
        "dense": _scene(root / "dense", "dense", beta_scale=6.0),
        "homogeneous": _scene(root / "homogeneous", "homogeneous"),
    }


@pytest.mark.parametrize(
    "case, extra",
    [
        ("none", ()),
        ("dense", ()),
        ("dense", ("--pipeline.t-min", "1e-4", "--pipeline.gradient-policy", "tgc")),
        ("homogeneous", ("--pipeline.t-min", "0.5")),
        ("homogeneous", ("--pipeline.t-min", "1")),
    ],
)
def test_short_runs_stay_finite(scenes, tmp_path, device, case, extra):
    _assert_sound(*_train(scenes[case], tmp_path, device, *extra))


def test_dense_haze_reaches_tiny_transmittance(scenes, tmp_path, device):
    trainer, result = _train(scenes["dense"], tmp_path, device)
    T = trainer.pipeline.render(trainer.datamanager.camera(0))["transmittance"]
    assert float(T.min()) < 0.05  # the generated fog is nearly opaque on far pixels


@pytest.mark.parametrize("scale", [1e-3, 1e3])
def test_units_do_not_change_the_result(scenes, tmp_path, device, scale):
    """Poses are normalised on load, so a scene in millimetres or kilometres trains identically."""
    ref_trainer, ref = _train(scenes["homogeneous"], tmp_path / "ref", device)
    other = _rescaled(scenes["homogeneous"], tmp_path / f"x{scale:g}", scale)
    trainer, res = _train(other, tmp_path / "out", device)
    _assert_sound(trainer, res)
    assert abs(res.metrics["reconstruction_psnr"] - ref.metrics["reconstruction_psnr"]) < 0.5
