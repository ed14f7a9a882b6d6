"""Short tri-dehaze runs stay finite with degenerate Gaussians, cameras inside the fog and sky-only
views (float32 throughout).

* Degenerate Gaussians are appended to a freshly set-up pipeline through the model's public
  ``replace_params`` (in front of every training camera, so every step sees them): zero, tiny,
  huge and float32-overflowing scales, needles, zero and non-normalised quaternions, opacity
  exactly 0 and 1, centres at, just around and behind the near plane. Densification runs during
  the short run, so they are also cloned, split and pruned.
* Cameras inside the fog: a generated indoor scene so thick that even the nearest wall keeps
  T < 0.02, and a learned medium re-initialised to an extinction in which every camera is embedded
  (T at its floor on every pixel), trained with the strongest compensation (TGC, T_min 1e-4).
* Sky-only views: views of a generated scene that look straight up (no geometry at all: the
  ground truth depth is the far bound), mixed into the training views or as the only ones.

Each run asserts: one step's loss and every parameter's gradient finite, no skipped non-finite
step (except the one case that must be skipped, a scale of +inf), finite float32 parameters,
finite float32 renders of every view and 0 < T <= 1.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from rich.console import Console

from components.data.cameras import ViewIntrinsics
from components.rasterizers.base import resolve_backend
from components.synth.generate import camera_poses, write_view
from components.synth.layouts import make_layout
from components.synth.medium import make_medium
from components.synth.render import apply_medium, render_clean
from components.synth.trajectories import look_at
from components.synth.writer import frame_entry, write_json
from pipelines.engine.optimizers import Optimizers
from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import TINY, tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args

STEPS = 12
PER_CAMERA = 8
"""Degenerate Gaussians placed in front of each training camera."""
DENSIFY = (
    "--pipeline.densify.refine-start", "4", "--pipeline.densify.refine-every", "4",
    "--pipeline.densify.refine-stop", str(STEPS), "--pipeline.densify.grow-grad2d", "0",
)  # fmt: skip
"""Refine at steps 4, 8 and 12, cloning or splitting every Gaussian with a gradient (and pruning)."""


# ------------------------------------------------------------------------------------- scenes
def _sky_views(root: Path, layout_name: str, haze: str, seed: int, n: int) -> list[str]:
    """Append ``n`` views looking straight up (from the first cameras' positions) to the generated
    scene in ``root``, rendered with the same layout and medium; returns their image paths."""
    meta = json.loads((root / "transforms.json").read_text())
    layout = make_layout(layout_name, seed)
    medium = make_medium(haze, layout.medium_context(), seed)
    _, poses = camera_poses(layout, "auto", TINY["num_views"])
    K = ViewIntrinsics.from_fov(TINY["width"], TINY["height"], 60.0)
    names = []
    for j, c2w in enumerate(poses[:n]):
        eye = c2w[:3, 3]
        up = look_at(eye, eye + np.array([0.0, 0.0, 1.0]))
        view = render_clean(layout, up, K, 1)
        assert not bool(view.hit.any()) and bool((view.t_end == layout.far).all())  # sky only: far bound
        hz = apply_medium(view, medium, TINY["samples"])
        files = write_view(root, f"sky{j}", view, hz)  # depth: the far bound's z
        meta["frames"].append(frame_entry(up, files))
        names.append(files["file_path"])
    meta["train_filenames"] += names
    write_json(root / "transforms.json", meta)
    return names


def _only_sky_for_training(src: Path, dst: Path, sky: list[str]) -> Path:
    """The same dataset with the sky-only views as the whole training split (the rest for testing)."""
    shutil.copytree(src, dst)
    meta = json.loads((dst / "transforms.json").read_text())
    meta["test_filenames"] = [f["file_path"] for f in meta["frames"] if f["file_path"] not in sky]
    meta["train_filenames"] = list(sky)
    write_json(dst / "transforms.json", meta)
    return dst


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("degenerate")
    street = tiny_hazy_scene(root / "street", layout="street", haze="homogeneous", seed=6, test_every=4)
    fog = tiny_hazy_scene(root / "fog", layout="room", haze="dense", beta_scale=12.0, seed=2, test_every=4)
    # the clean cloud: SfM-like outliers far along their rays would make big seed Gaussians whose
    # tails cover the sky views, and the test is about the views, not the cloud
    sky = tiny_hazy_scene(
        root / "sky", layout="field", haze="homogeneous", seed=3, test_every=4, seed_cloud="clean"
    )
    names = _sky_views(sky, "field", "homogeneous", seed=3, n=3)
    return {
        "street": street,
        "fog": fog,
        "sky": sky,
        "sky_names": names,
        "sky_only": _only_sky_for_training(sky, root / "sky_only", names),
    }


# ----------------------------------------------------------------------------------- training
def _trainer(scene: Path, out: Path, device: torch.device, *extra: str, backend: str = "torch") -> Trainer:
    cfg = parse_args([
        "tri-dehaze", "--data", str(scene), "--output-dir", str(out), "--max-steps", str(STEPS),
        "--device", str(device),
        "--pipeline.freeze-step", "6", "--pipeline.medium-hold-fraction", "0", "--pipeline.rasterizer.backend",
        backend, "--steps-per-save", "100", "--no-eval-at-end", "--threads", "1", *extra,
    ])  # fmt: skip
    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.setup()
    return trainer


def _check_one_step(trainer: Trainer) -> None:
    """Loss and every parameter's gradient of one step are finite (nothing is updated)."""
    pipe = trainer.pipeline
    trainer.optimizers.zero_grad()
    res = pipe.train_loss(0)
    assert res.loss.dtype == torch.float32
    assert torch.isfinite(res.loss.detach()), float(res.loss.detach())
    res.loss.backward()
    for name, p in pipe.named_parameters():
        if p.grad is not None:
            assert torch.isfinite(p.grad).all(), f"non-finite gradient of {name}"
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh0"):
        assert pipe.model.params[name].grad is not None, name
    trainer.optimizers.zero_grad()


def _assert_sound(trainer: Trainer, metrics: dict, skipped: int = 0, open_sky: bool = False) -> None:
    """``open_sky``: uncovered pixels see the medium to infinity, where T is exactly 0."""
    assert metrics.get("skipped_nonfinite_steps", 0) == skipped
    pipe = trainer.pipeline
    for name, p in pipe.named_parameters():
        assert p.dtype == torch.float32, name
        assert torch.isfinite(p).all(), f"non-finite parameter {name}"
    for idx in range(len(trainer.datamanager.scene)):
        out = pipe.render(trainer.datamanager.camera(idx))
        for name, t in out.items():
            assert t.dtype == torch.float32, name
            assert torch.isfinite(t).all(), f"non-finite {name} render of view {idx}"
        T = out["transmittance"]
        assert (float(T.min()) >= 0 if open_sky else float(T.min()) > 0) and float(T.max()) <= 1


# ------------------------------------------------------------------------- degenerate Gaussians
Edit = Callable[[dict[str, torch.Tensor], torch.Tensor, torch.Tensor, float, torch.Generator], None]
"""``edit(rows, R, eye, extent, gen)`` makes ``rows`` (PER_CAMERA new Gaussians of one camera) degenerate;
``R`` [3, 3] is the camera's OpenCV camera-to-world rotation (column 2 looks forward), ``eye`` its
centre, ``gen`` the random generator to draw from."""


def _scales(rows, R, eye, ext, gen):
    v = [-120.0, math.log(1e-7 * ext), math.log(1e8 * ext), math.log(1e30 * ext)]  # 0 exactly ... overflow
    rows["log_scales"][:4] = torch.tensor(v, device=eye.device)[:, None]
    rows["log_scales"][4:] = torch.tensor([math.log(10 * ext), -120.0, -120.0], device=eye.device)  # needles
    rows["quats"][4:] = torch.randn(PER_CAMERA - 4, 4, generator=gen).to(eye.device)


def _rotations(rows, R, eye, ext, gen):
    rows["quats"][:3] = 0.0
    rows["quats"][3:6] = torch.randn(3, 4, generator=gen).to(eye.device) * 1e6
    rows["quats"][6:] = torch.randn(PER_CAMERA - 6, 4, generator=gen).to(eye.device) * 1e-8
    anisotropic = torch.tensor([0.1, 0.01, 0.001], device=eye.device)
    rows["log_scales"][:] = torch.log(anisotropic * ext)  # anisotropic: rotation matters


def _opacities(rows, R, eye, ext, gen):
    rows["opacity_logits"][::2] = -120.0  # sigmoid: exactly 0 in float32
    rows["opacity_logits"][1::2] = 40.0  # exactly 1


def _near_plane(rows, R, eye, ext, gen):
    # camera z of the centres (near plane 0.01), up to float32 rounding of the world coordinates
    z = torch.tensor([0.0, 0.01, 0.0101, 0.0099, 0.02, 1e-6, -0.01, -1.0], device=eye.device)
    rows["means"] = eye + z[:, None] * R[:, 2]


def _everything(rows, R, eye, ext, gen):
    parts = []
    for edit in (_scales, _rotations, _opacities, _near_plane):
        part = {k: v.clone() for k, v in rows.items()}
        edit(part, R, eye, ext, gen)
        parts.append(part)
    rows.update({k: torch.cat([p[k] for p in parts]) for k in rows})


def _infinite_scale(rows, R, eye, ext, gen):
    rows["log_scales"][:] = 90.0  # exp(90) = +inf in float32


@torch.no_grad()
def _inject(trainer: Trainer, edit: Edit) -> int:
    """Append degenerate Gaussians in front of every training camera; rebuild the optimizers."""
    pipe, dm, device = trainer.pipeline, trainer.datamanager, trainer.device
    model = pipe.model
    new: dict[str, list[torch.Tensor]] = {k: [] for k in model.param_names}
    gen = torch.Generator().manual_seed(0)  # on the cpu: the same Gaussians on every device
    for idx in dm.train_indices:
        c2w = dm.camera(idx).camtoworlds[0]
        R, eye = c2w[:3, :3], c2w[:3, 3]
        pick = torch.randint(model.num_gaussians, (PER_CAMERA,), generator=gen).to(device)
        rows = {k: model.params[k].detach()[pick].clone() for k in model.param_names}
        depth = torch.linspace(0.3, 1.0, PER_CAMERA, device=device)[:, None]
        side = torch.linspace(-0.2, 0.2, PER_CAMERA, device=device)[:, None]
        rows["means"] = eye + depth * R[:, 2] + side * depth * R[:, 0]  # in view
        rows["opacity_logits"][:] = 2.0
        edit(rows, R, eye, pipe.scene_extent, gen)
        for k in new:
            new[k].append(rows[k])
    n = model.num_gaussians
    model.replace_params({k: torch.cat([model.params[k].detach(), *v]) for k, v in new.items()})
    trainer.optimizers = Optimizers(pipe.param_groups(), trainer.config.optimizer, trainer.config.max_steps)
    return model.num_gaussians - n


def test_degenerate_values_are_what_they_claim_in_float32(device):
    """The parameter values used below give exactly the degenerate Gaussians they are named after."""
    assert float(torch.exp(torch.tensor(-120.0, device=device))) == 0.0
    assert float(torch.sigmoid(torch.tensor(-120.0, device=device))) == 0.0
    assert float(torch.sigmoid(torch.tensor(40.0, device=device))) == 1.0
    assert math.isinf(float(torch.exp(torch.tensor(90.0, device=device))))


CASES = {
    "zero, tiny, huge, overflowing scales and needles": (_scales, 0),
    "zero and non-normalised quaternions": (_rotations, 0),
    "opacity exactly 0 and 1": (_opacities, 0),
    "centres at, around and behind the near plane": (_near_plane, 0),
    "scale +inf (exp overflow): every step skipped by the guard": (_infinite_scale, STEPS),
}


@pytest.mark.parametrize("case", list(CASES))
def test_degenerate_gaussians_train_finitely(scenes, tmp_path, device, case):
    edit, skipped = CASES[case]
    trainer = _trainer(scenes["street"], tmp_path, device, *DENSIFY)
    assert _inject(trainer, edit) == PER_CAMERA * len(trainer.datamanager.train_indices)
    if skipped:  # the gradient through an infinite scale is not finite: the step guard's case
        before = {k: v.clone() for k, v in trainer.pipeline.model.params.items()}
        _assert_sound(trainer, trainer.train().metrics, skipped=skipped)
        for k, v in trainer.pipeline.model.params.items():
            torch.testing.assert_close(v.detach(), before[k], rtol=0, atol=0)  # nothing was applied
        return
    _check_one_step(trainer)
    _assert_sound(trainer, trainer.train().metrics)


@pytest.mark.parametrize("backend", ["torch", "cpu"])
def test_all_degenerate_kinds_at_once(scenes, tmp_path, device, backend):
    if resolve_backend("auto") != "cpu" and backend == "cpu":
        pytest.skip("cpu rasterizer extension not available")
    trainer = _trainer(scenes["street"], tmp_path, device, *DENSIFY, backend=backend)
    _inject(trainer, _everything)
    _check_one_step(trainer)
    _assert_sound(trainer, trainer.train().metrics)


# --------------------------------------------------------------------------- cameras in the fog
def test_cameras_inside_generated_fog(scenes, tmp_path, device):
    """Every view, nearest wall included, is nearly opaque: the cameras stand inside the fog."""
    gt = [np.load(p) for p in sorted((scenes["fog"] / "gt_transmittance").glob("*.npy"))]
    assert max(float(t.max()) for t in gt) < 0.02
    trainer = _trainer(
        scenes["fog"], tmp_path, device, "--pipeline.gradient-policy", "tgc", "--pipeline.t-min", "1e-4"
    )
    _check_one_step(trainer)
    _assert_sound(trainer, trainer.train().metrics)


def test_cameras_embedded_in_an_opaque_learned_medium(scenes, tmp_path, device):
    """The learned medium re-initialised so thick that T sits at its floor on every pixel of every view."""
    trainer = _trainer(
        scenes["street"], tmp_path, device, "--pipeline.gradient-policy", "tgc", "--pipeline.t-min", "1e-4"
    )
    pipe = trainer.pipeline
    pipe.medium.initialize(1e3, torch.tensor([0.7, 0.7, 0.7], device=device))
    floor = pipe.config.composite.t_floor
    for idx in trainer.datamanager.train_indices:
        T = pipe.render(trainer.datamanager.camera(idx))["transmittance"]
        assert float(T.max()) <= 1.01 * floor
    _check_one_step(trainer)
    _assert_sound(trainer, trainer.train().metrics)


# ---------------------------------------------------------------------------------- sky-only views
def _sky_indices(trainer: Trainer, names: list[str]) -> list[int]:
    all_names = trainer.datamanager.scene.names()
    return [all_names.index(n) for n in names]


def test_sky_only_views_among_the_training_views(scenes, tmp_path, device):
    trainer = _trainer(scenes["sky"], tmp_path, device)
    pipe = trainer.pipeline
    sky = _sky_indices(trainer, scenes["sky_names"])
    assert set(sky) <= set(trainer.datamanager.train_indices)
    far = pipe.compositor.far_bound(pipe.medium)
    for idx in sky:  # only the tails of the big seed Gaussians (distant trees) reach into these views
        out = pipe.render(trainer.datamanager.camera(idx))
        assert float(out["alpha"].mean()) < 0.2
        assert float(pipe.compositor.end_depth(out["depth"], out["alpha"], far).mean()) > 0.8 * far
    _check_one_step(trainer)
    _assert_sound(trainer, trainer.train().metrics)


def test_training_on_sky_only_views(scenes, tmp_path, device):
    """Every training view sees nothing but sky; the test views (with geometry) still render finitely."""
    trainer = _trainer(scenes["sky_only"], tmp_path, device)
    assert sorted(trainer.datamanager.train_indices) == sorted(_sky_indices(trainer, scenes["sky_names"]))
    _check_one_step(trainer)
    _assert_sound(trainer, trainer.train().metrics)


def test_nothing_rendered_in_any_view(scenes, tmp_path, device):
    """Every opacity exactly 0: alpha = 0 on every pixel and the medium is marched to the far bound."""
    trainer = _trainer(scenes["sky"], tmp_path, device)
    pipe = trainer.pipeline
    with torch.no_grad():
        pipe.model.params["opacity_logits"].fill_(-120.0)
    far = pipe.compositor.far_bound(pipe.medium)
    for idx in range(len(trainer.datamanager.scene)):
        out = pipe.render(trainer.datamanager.camera(idx))
        assert float(out["alpha"].abs().max()) == 0.0
        end = pipe.compositor.end_depth(out["depth"], out["alpha"], far)
        torch.testing.assert_close(end, torch.full_like(end, far), rtol=1e-6, atol=0)
    _check_one_step(trainer)
    _assert_sound(trainer, trainer.train().metrics)


@pytest.mark.parametrize("medium", ["triplane", "gaussian-bound"])
def test_nothing_rendered_with_the_background_at_infinity(scenes, tmp_path, device, medium):
    """Every opacity 0 and ``background infinite``: every pixel is the medium's light from infinity,
    the clean render shows that same light (no black background), T is 0, and training stays finite."""
    trainer = _trainer(
        scenes["sky"], tmp_path, device, "--pipeline.composite.background", "infinite",
        "--pipeline.medium.backend", medium,
    )  # fmt: skip
    pipe = trainer.pipeline
    with torch.no_grad():
        pipe.model.params["opacity_logits"].fill_(-120.0)
    for idx in range(len(trainer.datamanager.scene)):
        out = pipe.render(trainer.datamanager.camera(idx))
        assert float(out["transmittance"].abs().max()) == 0.0
        torch.testing.assert_close(out["clean"], out["hazy"], rtol=1e-5, atol=1e-5)
        assert float(out["clean"].mean()) > 0.1  # the light of the haze, not the black background
    _check_one_step(trainer)
    _assert_sound(trainer, trainer.train().metrics, open_sky=True)


def test_sky_views_train_with_the_background_at_infinity(scenes, tmp_path, device):
    trainer = _trainer(scenes["sky"], tmp_path, device, "--pipeline.composite.background", "infinite")
    _check_one_step(trainer)
    _assert_sound(trainer, trainer.train().metrics, open_sky=True)


@pytest.mark.parametrize("bound", ["two-sided", "lower", "lower-own-light"])
def test_dark_channel_bounds_train_soundly(scenes, tmp_path, device, bound):
    trainer = _trainer(scenes["sky"], tmp_path, device, "--pipeline.dcp-bound", bound)
    res = trainer.pipeline.train_loss(0)
    assert torch.isfinite(res.metrics["dcp"]) and float(res.metrics["dcp"]) >= 0.0
    _check_one_step(trainer)
    _assert_sound(trainer, trainer.train().metrics)


def test_dark_channel_bound_with_full_upper_weight_is_the_two_sided_loss(scenes, tmp_path, device):
    """``--pipeline.dcp-upper-weight`` reaches the loss: 1 turns the ``lower`` bound back into the
    two-sided loss (same scene, same seed, same first step)."""
    two = _trainer(scenes["sky"], tmp_path / "two", device, "--pipeline.dcp-bound", "two-sided")
    full = _trainer(
        scenes["sky"],
        tmp_path / "full",
        device,
        "--pipeline.dcp-bound",
        "lower",
        "--pipeline.dcp-upper-weight",
        "1.0",
    )
    bound = _trainer(scenes["sky"], tmp_path / "bound", device, "--pipeline.dcp-bound", "lower")
    for t in (two, full, bound):  # almost no haze: T is above the dark channel's estimate
        t.pipeline.medium.initialize(1e-4, torch.full((3,), 0.7))
    d_two, d_full, d_bound = (float(t.pipeline.train_loss(0).metrics["dcp"]) for t in (two, full, bound))
    assert d_two == pytest.approx(d_full, rel=1e-6)
    assert d_bound < d_two  # the pure bound drops the side above the estimate


def test_dark_channel_omega_reaches_the_own_light_bound(scenes, tmp_path, device):
    """``--pipeline.dcp-omega``: the ``lower-own-light`` bound 1 - omega min(I / L) falls as omega
    grows, so with the same medium (same scene, seed, first step) a larger omega pays less."""
    args = ("--pipeline.dcp-bound", "lower-own-light", "--pipeline.lambda-dcp", "1.0")
    losses = []
    for omega in ("0.9", "0.95", "1.0"):
        t = _trainer(scenes["sky"], tmp_path / omega, device, *args, "--pipeline.dcp-omega", omega)
        t.pipeline.medium.initialize(3.0, torch.full((3,), 0.7))  # dense: T under every bound
        losses.append(float(t.pipeline.train_loss(0).metrics["dcp"]))
    assert losses[0] > losses[1] > losses[2] >= 0.0


def test_stage_two_holds_the_haze_only_when_asked(scenes, tmp_path, device, monkeypatch):
    """``--pipeline.stage-two-holds-haze``: in Stage II the depth the medium is marched to carries no
    gradient (tri-dehaze's composite otherwise lets the Gaussians move along the rays)."""
    for held in (False, True):
        args = ("--pipeline.stage-two-holds-haze",) if held else ()
        pipe = _trainer(scenes["sky"], tmp_path / str(held), device, *args).pipeline
        seen: list[bool] = []
        march = pipe.medium.render_view

        def spy(compositor, camera, depth, alpha, *rest, march=march, seen=seen):
            seen.append(depth.requires_grad)
            return march(compositor, camera, depth, alpha, *rest)

        monkeypatch.setattr(pipe.medium, "render_view", spy)
        grads = []
        for step in (0, 7):  # Stage I, Stage II (the freeze at step 6)
            seen.clear()
            pipe.train_loss(step)  # the step's own view is marched last (after any fit at the freeze)
            grads.append(seen[-1])
        assert grads == [True, not held]


def test_dark_channel_weighting_by_transmittance_reaches_the_loss(scenes, tmp_path, device):
    """``--pipeline.dcp-weighting transmittance``: each pixel's penalty times its rendered T, so
    with the haze dense (every T < 1) the term is smaller than the uniform one but not zero."""
    args = ("--pipeline.dcp-bound", "lower", "--pipeline.lambda-dcp", "1.0")
    uniform = _trainer(scenes["sky"], tmp_path / "u", device, *args)
    weighted = _trainer(
        scenes["sky"], tmp_path / "w", device, *args, "--pipeline.dcp-weighting", "transmittance"
    )
    for t in (uniform, weighted):
        t.pipeline.medium.initialize(5.0, torch.full((3,), 0.7))  # dense: T far below the estimate
    d_u = float(uniform.pipeline.train_loss(0).metrics["dcp"])
    res = weighted.pipeline.train_loss(0)
    d_w, mean_t = float(res.metrics["dcp"]), float(res.metrics["mean_T"])
    assert d_u > 0.0 and 0.0 < d_w < d_u
    assert mean_t < 0.9
    _check_one_step(weighted)


def test_light_anchor_pulls_the_medium_light_to_the_airlight_in_stage_one_only(scenes, tmp_path, device):
    """``--pipeline.lambda-light``: off, no anchor term; on, a term that is the squared distance of the
    scattered light to the view's dark-channel airlight, whose gradient step moves the light towards
    it; gone after the medium freezes."""
    off = _trainer(scenes["sky"], tmp_path / "off", device)
    assert "light_anchor" not in off.pipeline.train_loss(0).metrics
    on = _trainer(scenes["sky"], tmp_path / "on", device, "--pipeline.lambda-light", "1.0")
    pipe = on.pipeline
    with torch.no_grad():
        pipe.medium.initialize(0.5, torch.full((3,), 0.2))  # far dimmer than any airlight of the views
    res = pipe.train_loss(0)
    first = float(res.metrics["light_anchor"])
    assert first > 0.01
    on.optimizers.zero_grad()
    res.loss.backward()
    on.optimizers.step()
    assert float(pipe.train_loss(0).metrics["light_anchor"]) < first  # same view, one step later
    assert "light_anchor" not in pipe.train_loss(pipe.freeze_step).metrics
