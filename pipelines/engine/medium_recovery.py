"""Medium recovery: how close a model's transmittance T and in-scattering S are to the truth.

Restoration PSNR alone cannot tell a wrong split between scene and medium from a right one: the
composite I = J T + S can match the hazy views while T and S are both off and their errors cancel.
Where a dataset carries the true maps (``gt_transmittance_file_path``, ``gt_scattering_file_path``,
written by ``td-synth``) this protocol reports, per view and as means over views:

- ``t_mae`` / ``s_mae``: mean absolute error of T (and of S, averaged over RGB);
- ``t_mae_by_true_t``: T's error over the pixels of each visibility bin of the *true* T (the same
  pixels for every method);
- ``t_mae_true_depth`` / ``s_mae_true_depth``: the same errors with the model's medium marched to
  the dataset's *true* depth (``gt_depth_file_path``) instead of its own rendered depth, so that
  the medium's error is told apart from the error of the depth it is marched to (a short rendered
  depth alone gives too little haze with a perfect medium);
- ``inverted_psnr``: PSNR against the clean reference of J = (I - S) / T inverted from the hazy
  input with the model's own T and S (how good the medium alone is as a dehazer), and
  ``true_inverted_psnr``, the same with the true maps: the ceiling the data allow.

The same true T also splits restoration (``observable_scores``, for every method): pixels whose
true T is at least ``OBSERVABLE_T`` carry their clean colour to the camera; below it (sky and far
background behind dense haze) the clean reference is not in the photo at all, so any method can
only guess it, and those pixels can dominate a whole-image PSNR.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import torch
from torch import Tensor

from components.data.images import read_map
from pipelines.engine.datamanager import DataManager
from pipelines.engine.metrics import psnr

REFERENCE_T_KEY = "gt_transmittance_file_path"
"""Per-frame key of a dataset's true transmittance maps (written by ``td-synth``)."""
REFERENCE_S_KEY = "gt_scattering_file_path"
"""Per-frame key of a dataset's true in-scattering maps (written by ``td-synth``)."""
REFERENCE_DEPTH_KEY = "gt_depth_file_path"
"""Per-frame key of a dataset's true z-depth maps in metres (written by ``td-synth``)."""
T_BINS: tuple[tuple[str, float, float], ...] = (("high", 0.7, 2.0), ("mid", 0.4, 0.7), ("low", -1.0, 0.4))
"""(name, lower bound exclusive, upper bound inclusive) on the true transmittance."""
INVERT_T_FLOOR = 0.05
"""T is clamped here before dividing (as single-image dehazing does): where the haze is nearly
opaque the inversion only amplifies noise, for the truth as for a model."""
OBSERVABLE_T = INVERT_T_FLOOR
"""True T below which a pixel's clean colour is taken as not observed: under 5 % of it reaches the
camera, less than 13 levels of an 8-bit photo (the inversion's floor, for the same reason)."""


def reference_map(dm: DataManager, key: str, idx: int, size: tuple[int, int]) -> Tensor | None:
    """The dataset's map ``key`` of view ``idx`` as [H, W, C] float32 at ``size`` = (H, W), or None."""
    paths = dm.scene.extra_paths.get(key)
    if not paths or paths[idx] is None:
        return None
    arr = np.asarray(read_map(paths[idx]), dtype=np.float32)  # [h, w] or [h, w, C]
    if arr.shape[:2] != size:
        arr = cv2.resize(arr, (size[1], size[0]), interpolation=cv2.INTER_AREA)
    t = torch.from_numpy(np.ascontiguousarray(arr))
    return (t[..., None] if t.dim() == 2 else t).to(dm.device)


def reference_depth(dm: DataManager, idx: int, size: tuple[int, int]) -> Tensor | None:
    """View ``idx``'s true camera z-depth [H, W, 1] in the run's normalised frame (the dataset's map
    is in metres), or None where the dataset has none."""
    z = reference_map(dm, REFERENCE_DEPTH_KEY, idx, size)  # [H, W, 1] metres
    return None if z is None else z * dm.scene.transform.scale


def invert(hazy: Tensor, transmittance: Tensor, scattering: Tensor) -> Tensor:
    """J = (I - S) / max(T, floor), clamped to [0, 1]; hazy/scattering [H, W, 3], T [H, W, 1]."""
    return ((hazy - scattering) / transmittance.clamp_min(INVERT_T_FLOOR)).clamp(0.0, 1.0)


def observable_scores(pred: Tensor, reference: Tensor, true_t: Tensor) -> dict[str, float | None]:
    """Restoration PSNR over the pixels whose clean colour reaches the camera (true T >=
    ``OBSERVABLE_T``) and their share of the view; pred/reference [H, W, 3], true_t [H, W, 1].
    The PSNR is None where no pixel is observable."""
    mask = true_t[..., 0] >= OBSERVABLE_T  # [H, W]
    n = int(mask.sum())
    share = n / mask.numel()
    if n == 0:
        return {"psnr": None, "share": share}
    return {"psnr": float(psnr(pred[mask], reference[mask])), "share": share}


@dataclass
class MediumAccumulator:
    """Per-view medium errors, pooled into the means the report shows."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    bin_abs: dict[str, float] = field(default_factory=lambda: {b[0]: 0.0 for b in T_BINS})
    bin_pixels: dict[str, int] = field(default_factory=lambda: {b[0]: 0 for b in T_BINS})

    def add(
        self,
        model_t: Tensor,
        model_s: Tensor,
        true_t: Tensor,
        true_s: Tensor | None,
        hazy: Tensor | None,
        reference: Tensor | None,
        at_true_depth: tuple[Tensor, Tensor] | None = None,
    ) -> dict[str, Any]:
        """One view (T [H, W, 1], S / images [H, W, 3]); ``at_true_depth``: the model's T and S
        marched to the true depth, where the dataset has it. Returns the view's own numbers."""
        t_err = (model_t - true_t).abs()[..., 0]  # [H, W]
        row: dict[str, Any] = {"t_mae": float(t_err.mean()), "s_mae": None}
        for name, lo, hi in T_BINS:
            mask = (true_t[..., 0] > lo) & (true_t[..., 0] <= hi)
            self.bin_abs[name] += float(t_err[mask].sum())
            self.bin_pixels[name] += int(mask.sum())
        if true_s is not None:
            row["s_mae"] = float((model_s - true_s).abs().mean())
        if at_true_depth is not None:
            t_d, s_d = at_true_depth  # [H, W, 1], [H, W, 3]
            row["t_mae_true_depth"] = float((t_d - true_t).abs().mean())
            row["s_mae_true_depth"] = float((s_d - true_s).abs().mean()) if true_s is not None else None
        if hazy is not None and reference is not None:
            row["inverted_psnr"] = float(psnr(invert(hazy, model_t, model_s), reference))
            if true_s is not None:
                row["true_inverted_psnr"] = float(psnr(invert(hazy, true_t, true_s), reference))
        self.rows.append(row)
        return row

    def result(self) -> dict[str, Any] | None:
        if not self.rows:
            return None
        out: dict[str, Any] = {"views": len(self.rows)}
        for key in (
            "t_mae",
            "s_mae",
            "t_mae_true_depth",
            "s_mae_true_depth",
            "inverted_psnr",
            "true_inverted_psnr",
        ):
            vals = [r[key] for r in self.rows if r.get(key) is not None]
            out[key] = sum(vals) / len(vals) if vals else None
        out["t_mae_by_true_t"] = {
            name: (self.bin_abs[name] / self.bin_pixels[name]) if self.bin_pixels[name] else None
            for name, _, _ in T_BINS
        }
        out["bins"] = {"high": "true T > 0.7", "mid": "0.4 < true T <= 0.7", "low": "true T <= 0.4"}
        return out
