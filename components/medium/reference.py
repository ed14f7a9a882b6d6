"""The generator's own medium (``--pipeline.medium.backend reference``): a diagnosis, never a method.

A td-synth dataset records its haze preset and seeds in ``synth_meta.json``; this field rebuilds
that medium and evaluates its true extinction and light in the run's normalised frame. It has no
parameters and learns nothing, so a run with it says how far the Gaussians get through the *true*
3D medium marched to their own rendered depth, which separates the medium's error from the
scene's (docs/results/medium_recovery.md, session 16). It reads the answer, so it only exists
for such measurements.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import torch
from torch import Tensor

from components.data.scene import SceneTransform
from components.medium.base import FieldBounds, MediumConfig, MediumField, MediumSample
from components.synth.layouts import make_layout
from components.synth.medium import Medium, make_medium
from tridehaze_plugin.errors import ConfigError
from tridehaze_plugin.registry import register

META_FILE = "synth_meta.json"


def generator_medium(root: Path) -> Medium:
    """The medium td-synth made the dataset at ``root`` with, rebuilt from its ``synth_meta.json``."""
    path = Path(root) / META_FILE
    fix = "use it on a dataset written by `td-synth scene` (its folder holds synth_meta.json)"
    if not path.is_file():
        raise ConfigError(
            "--pipeline.medium.backend reference needs the generator's medium", where=str(path), fix=fix
        )
    try:
        settings = json.loads(path.read_text())["settings"]
        layout, haze, seed = settings["layout"], settings["haze"], int(settings["seed"])
        beta_scale = float(settings.get("beta_scale", 1.0))
        return make_medium(haze, make_layout(layout, seed).medium_context(), seed, beta_scale)
    except (ValueError, KeyError, TypeError) as exc:  # unreadable, or an unknown layout / preset
        raise ConfigError(f"cannot read the generator's settings ({exc})", where=str(path), fix=fix) from None


class ReferenceField(MediumField):
    """The true extinction and light of a generated scene, in the run's frame (no parameters)."""

    _medium: Medium | None = None

    def bind_scene(self, root: Path, transform: SceneTransform) -> None:
        self._medium = generator_medium(root)
        # x_run = s (R x_world + t)  ->  x_world = R^T (x_run / s - t)
        self._rotation = transform.rotation.detach().to(torch.float64)  # [3, 3]
        self._translation = transform.translation.detach().to(torch.float64)  # [3]
        self._scale = float(transform.scale)

    def forward(self, x: Tensor, dirs: Tensor) -> MediumSample:  # x, dirs: [P, 3]
        if self._medium is None:
            raise RuntimeError("the reference medium is read from the dataset: call bind_scene() first")
        R, t = self._rotation.to(x.device), self._translation.to(x.device)
        world = (x.double() / self._scale - t) @ R  # [P, 3] (row vectors: R^T applied)
        view = dirs.double() @ R  # [P, 3]
        view = view / view.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        beta_scale, light_scale = self.config.reference_scale
        beta = self._medium.extinction(world) / self._scale * beta_scale  # [P] per unit of the run's frame
        light = (self._medium.light(world[:, None, :], view)[:, 0, :] * light_scale).clamp(0.0, 1.0)  # [P, 3]
        return MediumSample(beta.to(x.dtype), light.to(x.dtype))


register("medium", "reference", ReferenceField)


def true_medium(
    config: MediumConfig, bounds: FieldBounds, root: Path, transform: SceneTransform
) -> ReferenceField:
    """The generator's medium of the dataset at ``root`` (extinction and light at scale 1) in
    ``bounds`` of the run's frame: beside a trained field of ``config``, to compare or fit the two
    at the same points."""
    truth = ReferenceField(replace(config, backend="reference", reference_scale=(1.0, 1.0)), bounds)
    truth.bind_scene(root, transform)
    return truth
