"""The registered baselines: dcp-gs trains on dark-channel dehazed views; tri-dehaze-constant."""

from __future__ import annotations

import numpy as np
import torch

from components.data.loader import load_scene
from components.losses.dcp import dehaze, estimate_dcp
from pipelines.engine.datamanager import DataManager
from tests.export.tiny_run import train_tiny
from tridehaze_plugin.cli.train import parse_args


def _pipeline(method: str, scene):
    cfg = parse_args([method, "--data", str(scene), "--pipeline.depth-prior", "none"])
    dm = DataManager(load_scene(cfg.dataset), torch.device("cpu"))
    return cfg, dm, cfg.pipeline.setup(dm, seed=0, max_steps=10)


def test_dcp_gs_fits_dehazed_views(eval_scene):
    cfg, dm, pipe = _pipeline("dcp-gs", eval_scene)
    assert cfg.pipeline.input_dehaze == "dcp" and not pipe.composites_medium
    assert "dehazed" in pipe.describe()
    for idx in dm.train_indices:
        hazy = dm.image(idx).numpy()
        expect = dehaze(hazy, estimate_dcp(hazy))  # [H, W, 3]
        got = pipe.training_target(idx).numpy()
        assert np.abs(got - expect).max() <= 0.5 / 255 + 1e-6  # stored as uint8
        assert np.abs(got - hazy).mean() > 0.02  # the haze was taken out
    _, dm2, plain = _pipeline("vanilla-gs", eval_scene)
    idx = dm2.train_indices[0]
    assert torch.equal(plain.training_target(idx), dm2.image(idx))


def test_constant_baseline_is_tri_dehaze_with_a_constant_medium(eval_scene, tmp_path):
    tri, _, _ = _pipeline("tri-dehaze", eval_scene)
    const, _, pipe = _pipeline("tri-dehaze-constant", eval_scene)
    assert const.pipeline.medium.backend == "constant" and pipe.composites_medium
    const.pipeline.medium.backend = tri.pipeline.medium.backend
    assert const.pipeline == tri.pipeline  # nothing else differs
    for method in ("dcp-gs", "tri-dehaze-constant"):
        cfg_path = train_tiny(eval_scene, tmp_path / method, method=method, steps=3)
        assert (cfg_path.parent / "checkpoints").is_dir()
