"""Three diagnoses on td-synth data that read the generator's answer (never methods):
``--pipeline.medium-start reference`` starts the trainable medium fitted to the true medium,
``--pipeline.march-to true-depth`` ends the training rays' march at the true depth, and
``--pipeline.medium-learns-from true-depth`` lets the medium learn only from pixels whose rendered
depth is right."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch
from rich.console import Console

from components.medium.reference import true_medium
from pipelines.engine.medium_recovery import reference_depth
from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args
from tridehaze_plugin.errors import ConfigError


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("patchy") / "scene"
    tiny_hazy_scene(
        root, layout="street", haze="patchy", seed=3, num_views=4, width=40, height=30,
        samples=128, num_points=200, test_every=2,
    )  # fmt: skip
    return root


def _trainer(data: Path, out: Path, *extra: str) -> Trainer:
    argv = [
        "tri-dehaze", "--data", str(data), "--output-dir", str(out), "--max-steps", "2",
        "--device", "cpu", "--pipeline.rasterizer.backend", "torch", "--steps-per-save", "100", *extra,
    ]  # fmt: skip
    trainer = Trainer(parse_args(argv), console=Console(quiet=True))
    trainer.setup()
    return trainer


def _log_beta_error(field, data: Path, trainer: Trainer) -> float:
    truth = true_medium(field.config, field.bounds, data, trainer.datamanager.scene.transform)
    gen = torch.Generator().manual_seed(1)
    x = field.bounds_center + (torch.rand(2048, 3, generator=gen) * 2 - 1) * field.bounds_half  # [P, 3]
    d = torch.nn.functional.normalize(torch.randn(2048, 3, generator=gen), dim=-1)  # [P, 3]
    with torch.no_grad():
        got, want = field(x, d).beta, truth(x, d).beta
    return float((got.clamp_min(1e-6).log() - want.clamp_min(1e-6).log()).abs().mean())


def test_reference_start_fits_the_true_medium(scene, tmp_path):
    fitted = _trainer(scene, tmp_path / "a", "--pipeline.medium-start", "reference")
    info = fitted.pipeline.init_info
    assert info["reference_start_log_beta_mae"] < 0.1 and info["reference_start_light_mae"] < 0.05
    err = _log_beta_error(fitted.pipeline.medium, scene, fitted)
    dark = _trainer(scene, tmp_path / "b")  # the dark channel's uniform start
    assert err < 0.1 < _log_beta_error(dark.pipeline.medium, scene, dark)


def test_march_to_true_depth(scene, tmp_path):
    trainer = _trainer(scene, tmp_path / "c", "--pipeline.march-to", "true-depth")
    pipe, dm = trainer.pipeline, trainer.datamanager
    idx = list(dm.train_indices)[0]
    cam = dm.camera(idx)
    out = pipe._rasterize(cam, None, pipe.background)
    med = pipe._medium_to_true_depth(idx, cam, out)
    size = (int(cam.height[0]), int(cam.width[0]))
    T, S = pipe.medium_at_depth(cam, reference_depth(dm, idx, size))
    torch.testing.assert_close(med.transmittance, T, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(med.scattering, S, rtol=1e-4, atol=1e-5)
    rendered = pipe._medium(cam, out)  # the default march ends elsewhere
    assert float((rendered.transmittance.detach() - T).abs().max()) > 1e-3
    trainer.train()  # and trains


def test_march_to_true_depth_needs_the_maps(scene, tmp_path):
    copy = tmp_path / "photos"
    shutil.copytree(scene, copy)
    meta = json.loads((copy / "transforms.json").read_text())
    for frame in meta["frames"]:
        frame.pop("gt_depth_file_path", None)
    (copy / "transforms.json").write_text(json.dumps(meta))
    trainer = _trainer(copy, tmp_path / "d", "--pipeline.march-to", "true-depth")
    with pytest.raises(ConfigError, match="true depth maps"):
        trainer.train()


def test_medium_learns_only_from_pixels_at_the_true_depth(scene, tmp_path):
    trainer = _trainer(scene, tmp_path / "e", "--pipeline.medium-learns-from", "true-depth")
    pipe, dm = trainer.pipeline, trainer.datamanager
    idx = list(dm.train_indices)[0]
    cam = dm.camera(idx)
    med = pipe._medium(cam, pipe._rasterize(cam, None, pipe.background))
    trusted, share = pipe._trusted_medium(idx, med)
    torch.testing.assert_close(trusted.transmittance, med.transmittance)  # the forward pass is unchanged
    torch.testing.assert_close(trusted.scattering, med.scattering)
    z = reference_depth(dm, idx, tuple(med.end_depth.shape[:2])).clamp_max(
        pipe.compositor.far_bound(pipe.medium)
    )
    want = ((med.end_depth.detach() - z).abs() <= 0.05 * z).float()  # [H, W, 1]
    assert 0.0 < float(want.mean()) < 1.0, "the tiny scene must have both kinds of pixel"
    (grad_t,) = torch.autograd.grad(trusted.transmittance.sum(), med.transmittance, retain_graph=True)
    torch.testing.assert_close(grad_t, want)  # the gradient passes the trusted pixels only
    (grad_s,) = torch.autograd.grad(trusted.scattering.sum(), med.scattering)
    torch.testing.assert_close(grad_s, want.expand_as(grad_s))
    assert float(share) == pytest.approx(float(want.mean()))
    trainer.train()  # and trains
