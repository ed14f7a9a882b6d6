"""A whole (tiny) training run through the engine: it learns, writes its run folder, and reloads."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from components.data.images import write_image_atomic
from components.data.ply import write_ply_points
from components.rasterizers.torch_reference import TorchRasterizer
from pipelines.engine.checkpoint import latest_checkpoint, load_checkpoint
from pipelines.engine.run_config import load_config
from pipelines.engine.trainer import Trainer
from tests.data.synth import GL_CV, ring_poses
from tridehaze_plugin.cli.train import parse_args
from tridehaze_plugin.errors import UserError

W, H, F = 48, 36, 40.0


def _render_truth(n_views: int, seed: int = 0):
    """Images of a known random Gaussian blob cloud seen from a ring of cameras (on the cpu: the ground
    truth written to disk is the same whichever device the runs train on)."""
    g = torch.Generator().manual_seed(seed)
    n = 300
    means = (torch.rand(n, 3, generator=g) - 0.5) * 1.6  # [N, 3]
    quats = torch.randn(n, 4, generator=g)
    scales = torch.full((n, 3), 0.08)
    opac = torch.full((n,), 0.8)
    colors = torch.rand(n, 3, generator=g)
    poses = ring_poses(n_views, radius=4.0, height=1.0)
    K = torch.tensor([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1.0]])
    rast = TorchRasterizer()
    images = []
    for c2w in poses:
        view = torch.linalg.inv(torch.from_numpy(c2w).float())[None]
        out = rast.rasterize(
            means, quats, scales, opac, colors, view, K[None], W, H, background=torch.zeros(3)
        )
        images.append((out.rgb[0].clamp(0, 1).numpy() * 255).round().astype(np.uint8))
    return poses, images, means.numpy(), (colors.numpy() * 255).astype(np.uint8)


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("tiny_scene")
    poses, images, pts, cols = _render_truth(9)
    frames = []
    for i, (c2w, img) in enumerate(zip(poses, images, strict=True)):
        write_image_atomic(root / "images" / f"v{i:02d}.png", img)
        frames.append({"file_path": f"images/v{i:02d}.png", "transform_matrix": (c2w @ GL_CV).tolist()})
    rng = np.random.default_rng(1)
    write_ply_points(root / "points.ply", pts + rng.normal(0, 0.05, pts.shape), cols)
    meta = {"fl_x": F, "fl_y": F, "cx": W / 2, "cy": H / 2, "w": W, "h": H, "ply_file_path": "points.ply"}
    (root / "transforms.json").write_text(json.dumps({**meta, "frames": frames}))
    return root


def _cfg(scene: Path, out: Path, device: torch.device, *extra: str):
    return parse_args(
        [
            "vanilla-gs",
            "--data",
            str(scene),
            "--output-dir",
            str(out),
            "--device",
            str(device),
            "--max-steps",
            "60",
            "--steps-per-save",
            "25",
            "--pipeline.rasterizer.backend",
            "torch",
            "--cache-dir",
            str(out / "cache"),
            "--timestamp",
            "run",
            *extra,
        ]
    )


def test_checkpoints_to_keep(tiny_scene, tmp_path, device):
    """``--checkpoints-to-keep 0`` keeps every checkpoint, to study how a run evolves (the default,
    2, is checked by the test below)."""
    cfg = _cfg(tiny_scene, tmp_path, device, "--checkpoints-to-keep", "0")
    run = Trainer(cfg).train().run_dir
    names = sorted(p.name for p in (run / "checkpoints").iterdir())
    assert names == ["step-0000025.ckpt", "step-0000050.ckpt", "step-0000060.ckpt"]


def test_training_learns_and_writes_run_folder(tiny_scene, tmp_path, device):
    cfg = _cfg(tiny_scene, tmp_path, device)
    trainer = Trainer(cfg)
    result = trainer.train()
    run = result.run_dir
    assert run == tmp_path / tiny_scene.name / "vanilla-gs" / "run"
    for rel in ("config.yml", "dataparser_transforms.json", "logs/metrics.jsonl", "eval/metrics.json"):
        assert (run / rel).is_file(), rel
    rows = [json.loads(x) for x in (run / "logs" / "metrics.jsonl").read_text().splitlines()]
    assert rows[0]["step"] == 10 and rows[-1]["step"] == 60
    # it learns: the loss at the end is clearly below the loss at the start
    assert rows[-1]["loss"] < 0.8 * rows[0]["loss"], (rows[0]["loss"], rows[-1]["loss"])
    metrics = json.loads((run / "eval" / "metrics.json").read_text())
    assert metrics["split_views"] == 2 and np.isfinite(metrics["reconstruction_psnr"])
    assert 0 < metrics["reconstruction_ssim"] <= 1
    # checkpoints: step 50 and the final one, atomic (no temporaries left)
    ckpts = sorted(p.name for p in (run / "checkpoints").iterdir())
    assert ckpts == ["step-0000050.ckpt", "step-0000060.ckpt"]
    # reload: config equals, weights load safely and render the same image
    assert load_config(run / "config.yml") == cfg
    # --load-config re-runs a saved config, command-line flags still override it
    again = parse_args(["--load-config", str(run / "config.yml"), "--max-steps", "3", "--seed", "7"])
    assert (again.max_steps, again.seed) == (3, 7)
    assert again.pipeline == cfg.pipeline and again.dataset == cfg.dataset
    payload = load_checkpoint(latest_checkpoint(run))
    assert payload["step"] == 60
    fresh = Trainer(load_config(run / "config.yml"))
    fresh.setup()
    fresh.pipeline.load_state_dict(payload["pipeline"])
    cam = fresh.datamanager.camera(0)
    torch.testing.assert_close(fresh.pipeline.render(cam)["clean"], trainer.pipeline.render(cam)["clean"])
    assert fresh.run_dir != run  # a new run never reuses (or overwrites) an existing folder


def test_same_seed_same_result(tiny_scene, tmp_path, device):
    r1 = Trainer(_cfg(tiny_scene, tmp_path / "a", device, "--max-steps", "15")).train()
    r2 = Trainer(_cfg(tiny_scene, tmp_path / "b", device, "--max-steps", "15")).train()
    assert r1.metrics["train_loss"] == pytest.approx(r2.metrics["train_loss"], rel=1e-5)


def test_truncated_checkpoint_is_a_clear_error(tiny_scene, tmp_path, device):
    result = Trainer(_cfg(tiny_scene, tmp_path, device, "--max-steps", "5")).train()
    ckpt = latest_checkpoint(result.run_dir)
    data = ckpt.read_bytes()
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(UserError, match="corrupt, truncated"):
        load_checkpoint(bad)


def test_render_writes_every_view_of_the_split(tiny_scene, tmp_path, device):
    from components.data.images import read_image
    from tridehaze_plugin.cli.render import main as render_main

    result = Trainer(_cfg(tiny_scene, tmp_path, device, "--max-steps", "5")).train()
    out = tmp_path / "renders"
    render_main(
        [
            "--load-config",
            str(result.run_dir / "config.yml"),
            "--device",
            str(device),
            "--split",
            "train",
            "--outputs",
            "clean,depth",
            "--output-dir",
            str(out),
            "--raw",
        ]
    )
    clean = sorted(p.name for p in (out / "clean").glob("*.png"))
    assert clean == [f"v{i:02d}.png" for i in range(1, 8)]  # every view but the held-out v00 and v08
    assert read_image(out / "clean" / "v01.png").shape == (H, W, 3)
    depth = np.load(out / "depth" / "v01.npy")
    assert depth.shape == (H, W) and np.isfinite(depth).all() and depth.max() > 0
    with pytest.raises(
        UserError, match="this method renders: clean, hazy, transmittance, scattering, depth, alpha"
    ):
        render_main(
            ["--load-config", str(result.run_dir / "config.yml"), "--device", str(device), "--outputs", "sky"]
        )


def test_native_tiny_images_train_and_evaluate(tmp_path, device):
    """Photos 5x4 pixels on disk (accepted: only --downscale may not go below 8 pixels): the SSIM
    window, the dark channel and the medium fit themselves to the image."""
    from tests.tiny_scenes import tiny_hazy_scene

    scene = tiny_hazy_scene(tmp_path / "tiny", width=5, height=4, num_views=6, test_every=3)
    cfg = parse_args(["tri-dehaze", "--data", str(scene), "--output-dir", str(tmp_path / "out"), "--device",
                      str(device), "--max-steps", "3", "--pipeline.rasterizer.backend", "torch", "--timestamp", "run",
                      "--cache-dir", str(tmp_path / "cache")])  # fmt: skip
    metrics = Trainer(cfg).train().metrics
    assert (
        metrics["steps"] == 3
        and np.isfinite(metrics["restoration_psnr"])
        and np.isfinite(metrics["train_ssim"])
    )
