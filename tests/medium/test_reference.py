"""The ``reference`` medium: the generator's true medium in the run's frame, for diagnosis.

Marched to the dataset's true depth it must give the dataset's true T and S (the generator wrote
them with the same physics); it learns nothing; a dataset without the generator's record is a
clear user error.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch

from components.medium.base import MediumConfig
from pipelines.engine.medium_recovery import REFERENCE_S_KEY, REFERENCE_T_KEY, reference_depth, reference_map
from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args
from tridehaze_plugin.errors import ConfigError

# homogeneous haze integrates exactly with any number of samples (docs: components/synth/march.py);
# the patchy preset differs by the march's discretisation (16 samples on coarse rays, 128 in the
# generator) and the 8-bit-free float maps leave nothing else
TOLERANCE = {"homogeneous": (2e-3, 2e-3), "patchy": (1.5e-2, 1.5e-2)}


@pytest.fixture(scope="module", params=["homogeneous", "patchy"])
def scene(request, tmp_path_factory) -> tuple[str, Path]:
    root = tmp_path_factory.mktemp(request.param) / "scene"
    tiny_hazy_scene(
        root, layout="street", haze=request.param, seed=3, num_views=4, width=40, height=30,
        samples=128, num_points=200, test_every=2,
    )  # fmt: skip
    return request.param, root


def _trainer(
    data: Path, out: Path, device: torch.device, steps: int = 1, extra: tuple[str, ...] = ()
) -> Trainer:
    from rich.console import Console

    argv = [
        "tri-dehaze", "--data", str(data), "--output-dir", str(out), "--max-steps", str(steps),
        "--device", str(device), "--pipeline.medium.backend", "reference",
        "--pipeline.rasterizer.backend", "torch", "--pipeline.freeze-step", "2",
        "--pipeline.medium-hold-fraction", "0", "--steps-per-save", "100", *extra,
    ]  # fmt: skip
    trainer = Trainer(parse_args(argv), console=Console(quiet=True))
    trainer.setup()
    return trainer


def test_true_medium_at_true_depth(scene, tmp_path, device):
    haze, data = scene
    trainer = _trainer(data, tmp_path, device)
    dm, pipe = trainer.datamanager, trainer.pipeline
    tol_t, tol_s = TOLERANCE[haze]
    for idx in range(len(dm.scene)):
        cam = dm.camera(idx)
        size = (int(cam.height[0]), int(cam.width[0]))
        true_t = reference_map(dm, REFERENCE_T_KEY, idx, size)  # [H, W, 1]
        true_s = reference_map(dm, REFERENCE_S_KEY, idx, size)  # [H, W, 3]
        T, S = pipe.medium_at_depth(cam, reference_depth(dm, idx, size))
        assert float(true_t.mean()) < 0.9  # the test means something: there is haze
        assert float((T - true_t).abs().mean()) < tol_t, (haze, idx)
        assert float((S - true_s).abs().mean()) < tol_s, (haze, idx)


def test_learns_nothing_and_trains(scene, tmp_path, device):
    _, data = scene
    trainer = _trainer(data, tmp_path, device, steps=4)
    medium = trainer.pipeline.medium
    assert not list(medium.parameters()) and medium.param_groups() == {}
    cam = trainer.datamanager.camera(0)
    before = trainer.pipeline.render(cam)["transmittance"]
    trainer.train()
    after = trainer.pipeline.render(cam)
    for name, value in after.items():
        assert torch.isfinite(value).all(), name
    assert float(after["transmittance"].mean()) < 0.99  # the true haze is composited
    assert before.shape == after["transmittance"].shape


def test_needs_the_generator_record(scene, tmp_path, device):
    _, data = scene
    copy = tmp_path / "photos"
    shutil.copytree(data, copy)
    (copy / "synth_meta.json").unlink()
    with pytest.raises(ConfigError, match="synth_meta.json"):
        _trainer(copy, tmp_path / "out", device)
    (copy / "synth_meta.json").write_text("{not json")
    with pytest.raises(ConfigError, match="cannot read the generator's settings"):
        _trainer(copy, tmp_path / "out2", device)
    settings = {"layout": "street", "haze": "smog", "seed": 3}
    (copy / "synth_meta.json").write_text(json.dumps({"settings": settings}))
    with pytest.raises(ConfigError, match="unknown haze preset 'smog'"):
        _trainer(copy, tmp_path / "out3", device)


def test_scaled_true_medium(scene, tmp_path, device):
    """``reference-scale B L``: the true extinction times B and the true light times L (clamped)."""
    _, data = scene
    true = _trainer(data, tmp_path / "a", device).pipeline.medium
    scaled = _trainer(data, tmp_path / "b", device, extra=("--pipeline.medium.reference-scale", "1.6", "0.5"))
    gen = torch.Generator().manual_seed(0)
    x = (torch.rand(256, 3, generator=gen) * 2 - 1).to(device)  # [P, 3] in the normalised frame
    dirs = torch.nn.functional.normalize(torch.randn(256, 3, generator=gen), dim=-1).to(device)  # [P, 3]
    a, b = true(x, dirs), scaled.pipeline.medium(x, dirs)
    assert float(a.beta.max()) > 0 and float(a.light.min()) > 0  # a real medium to scale
    torch.testing.assert_close(b.beta, 1.6 * a.beta, rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(b.light, 0.5 * a.light, rtol=1e-5, atol=1e-7)
    bright = _trainer(data, tmp_path / "c", device, extra=("--pipeline.medium.reference-scale", "1", "10"))
    assert float(bright.pipeline.medium(x, dirs).light.max()) == 1.0  # a light is at most 1


def test_scale_needs_the_reference_backend():
    with pytest.raises(ConfigError, match="reference-scale scales the generator's true medium"):
        MediumConfig(backend="triplane", reference_scale=(2.0, 1.0)).check_values()
    with pytest.raises(ConfigError, match="reference-scale"):
        MediumConfig(backend="reference", reference_scale=(-1.0, 1.0)).check_values()
    MediumConfig(backend="reference", reference_scale=(0.5, 1.2)).check_values()
