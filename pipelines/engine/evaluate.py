"""Evaluation protocols on a split: restoration, reconstruction and visibility-binned metrics.

- **Restoration**: the clean render against haze-free references (``clean_file_path``, a
  ``clean/`` folder, or Blender-style clean test images); only views that have one count.
- **Reconstruction**: the composite (hazy) render against the hazy input views; only for methods
  with a medium (a haze-agnostic method's render *is* its reconstruction of the hazy input, so its
  plain render is compared with the input instead and flagged ``composite: false``), and only for
  views whose input is hazy (Blender-style test views are clean references).
- **Baselines**: the same restoration scores for the hazy test photo itself and for the photo
  dehazed on its own by the dark channel prior (``image_baselines``): what no 3D gives.
- **Binned**: restoration PSNR / SSIM over pixels grouped by transmittance, High T > 0.7,
  Mid 0.4 < T <= 0.7, Low T <= 0.4 (the paper's bins). PSNR comes from the MSE pooled over all
  pixels of a bin across views (a bin that is tiny in one view does not dominate), SSIM is the
  mean of the SSIM map over the bin's pixels. The transmittance is the model's own where it has a
  medium, else the dataset's ``gt_transmittance`` maps where they exist (``source`` says which).
- **Observable**: where the dataset has true T maps, restoration PSNR over the pixels whose
  clean colour reaches the camera (true T >= 5 %) and their share, for every method: what a
  whole-image PSNR mixes with pixels the photos do not show (``medium_recovery``).

LPIPS (AlexNet) is computed when its weights are installed (``components.metrics.lpips``);
otherwise it is reported as null with the reason, never replaced by a look-alike.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import torch
from torch import Tensor

from components.data.cameras import Cameras
from pipelines.engine.contract import Pipeline
from pipelines.engine.datamanager import DataManager
from pipelines.engine.image_baselines import BASELINES, baseline_images
from pipelines.engine.medium_recovery import (
    OBSERVABLE_T,
    REFERENCE_S_KEY,
    REFERENCE_T_KEY,
    MediumAccumulator,
    observable_scores,
    reference_depth,
    reference_map,
)
from pipelines.engine.metrics import psnr, ssim, ssim_map

BINS: tuple[tuple[str, float, float], ...] = (("high", 0.7, 2.0), ("mid", 0.4, 0.7), ("low", -1.0, 0.4))
"""(name, lower bound exclusive, upper bound inclusive) on the transmittance T."""
BinSource = Literal["auto", "model", "reference", "none"]
LpipsFn = Callable[[Tensor, Tensor], "Tensor | None"]
"""LPIPS of two [H, W, 3] images in [0, 1]; None where it cannot be computed (e.g. too small)."""


@dataclass
class BinAccumulator:
    """Pooled squared error and SSIM-map sums per transmittance bin."""

    sq_err: dict[str, float] = field(default_factory=lambda: {b[0]: 0.0 for b in BINS})
    ssim_sum: dict[str, float] = field(default_factory=lambda: {b[0]: 0.0 for b in BINS})
    pixels: dict[str, int] = field(default_factory=lambda: {b[0]: 0 for b in BINS})

    def add(self, pred: Tensor, target: Tensor, trans: Tensor) -> dict[str, dict[str, float | None]]:
        """pred/target [H, W, 3], trans [H, W, 1]; returns this view's own binned numbers."""
        err = ((pred.clamp(0, 1) - target) ** 2).mean(-1)  # [H, W]
        smap = ssim_map(pred, target)  # [H, W]
        t = trans[..., 0]
        view: dict[str, dict[str, float | None]] = {}
        for name, lo, hi in BINS:
            mask = (t > lo) & (t <= hi)
            n = int(mask.sum())
            se, ss = float(err[mask].sum()), float(smap[mask].sum())
            self.sq_err[name] += se
            self.ssim_sum[name] += ss
            self.pixels[name] += n
            view[name] = _bin_numbers(se, ss, n, t.numel())
        return view

    def report(self, source: str | None) -> dict[str, Any] | None:
        """The report's ``binned`` block (None where no view had a transmittance to bin by)."""
        if source is None:
            return None
        bins = {"high": "T > 0.7", "mid": "0.4 < T <= 0.7", "low": "T <= 0.4"}
        return {"source": source, "bins": bins, **self.result()}

    def result(self) -> dict[str, dict[str, float | None]]:
        total = max(sum(self.pixels.values()), 1)
        return {n: _bin_numbers(self.sq_err[n], self.ssim_sum[n], self.pixels[n], total) for n, _, _ in BINS}


def _bin_numbers(sq_err: float, ssim_sum: float, n: int, total: int) -> dict[str, float | None]:
    if n == 0:
        return {"psnr": None, "ssim": None, "fraction": 0.0}
    mse = sq_err / n
    return {
        "psnr": 100.0 if mse <= 1e-10 else -10.0 * math.log10(mse),
        "ssim": ssim_sum / n,
        "fraction": n / total,
    }


def _mean(rows: list[dict[str, float | None]]) -> dict[str, Any] | None:
    if not rows:
        return None
    out: dict[str, Any] = {}
    for key in ("psnr", "ssim", "lpips"):
        vals = [r[key] for r in rows if r.get(key) is not None]
        out[key] = sum(vals) / len(vals) if vals else None
    out["views"] = len(rows)
    return out


def _scores(pred: Tensor, target: Tensor, lpips_fn: LpipsFn | None) -> dict[str, float | None]:
    lp = lpips_fn(pred.clamp(0, 1), target) if lpips_fn is not None else None
    return {
        "psnr": float(psnr(pred, target)),
        "ssim": float(ssim(pred, target)),
        "lpips": None if lp is None else float(lp),
    }


def _baseline_scores(hazy: Tensor, reference: Tensor, lpips_fn: LpipsFn | None) -> dict[str, Any]:
    """Restoration scores of the single-image baselines of one hazy test photo."""
    return {k: _scores(im, reference, lpips_fn) for k, im in baseline_images(hazy).items()}


@dataclass
class ViewRender:
    """What a per-view callback receives (e.g. to write side-by-side images)."""

    index: int
    name: str
    outputs: dict[str, Tensor]
    hazy_input: Tensor | None  # [H, W, 3] the hazy photo, None where the view's input is clean
    reference: Tensor | None  # [H, W, 3] haze-free reference
    true_transmittance: Tensor | None = None  # [H, W, 1] the dataset's, where it has one
    true_scattering: Tensor | None = None  # [H, W, 3] the dataset's, where it has one


@torch.no_grad()
def evaluate(
    pipeline: Pipeline,
    dm: DataManager,
    split: str = "test",
    *,
    lpips_fn: LpipsFn | None = None,
    bins: BinSource = "auto",
    on_view: Callable[[ViewRender], None] | None = None,
) -> dict[str, Any]:
    """All protocols on ``split``; the dict has the stable keys documented in docs/evaluation.md."""
    indices = dm.scene.indices(split)
    names = dm.scene.names()
    medium = pipeline.composites_medium
    binned = BinAccumulator()
    recovery = MediumAccumulator()
    bin_source: str | None = None
    per_view: list[dict[str, Any]] = []
    for idx in indices:
        camera = dm.camera(idx)
        out = pipeline.render(camera)
        clean_ref = dm.clean_image(idx)
        hazy_in = dm.hazy_image(idx)
        row: dict[str, Any] = {"name": names[idx]}
        if clean_ref is not None:
            row["restoration"] = _scores(out["clean"], clean_ref, lpips_fn)
            trans, source = _bin_transmittance(bins, medium, out, dm, idx)
            if trans is not None:
                bin_source = source
                row["binned"] = binned.add(out["clean"], clean_ref, trans)
            if hazy_in is not None:
                row["baselines"] = _baseline_scores(hazy_in, clean_ref, lpips_fn)
        observable, true_t, true_s = _truth(dm, idx, out["clean"], clean_ref, medium)
        if observable is not None:
            row["observable"] = observable
        if true_t is not None:
            at_depth = _medium_at_true_depth(pipeline, dm, idx, camera, tuple(true_t.shape[:2]))
            row["medium"] = recovery.add(
                out["transmittance"], out["scattering"], true_t, true_s, hazy_in, clean_ref, at_depth
            )
        if hazy_in is not None:
            row["reconstruction"] = _scores(out["hazy"], hazy_in, lpips_fn)
        per_view.append(row)
        if on_view is not None:
            on_view(ViewRender(idx, names[idx], out, hazy_in, clean_ref, true_t, true_s))
    recon = _mean(_column(per_view, "reconstruction"))
    if recon is not None:
        recon["composite"] = medium
    return {
        "split": split,
        "views": len(indices),
        "restoration": _mean(_column(per_view, "restoration")),
        "reconstruction": recon,
        "binned": binned.report(bin_source),
        "medium": recovery.result(),
        "observable": _mean_observable(_column(per_view, "observable")),
        "baselines": {k: _mean(_column(per_view, "baselines", k)) for k in BASELINES}
        if any("baselines" in row for row in per_view)
        else None,
        "per_view": per_view,
    }


def _column(per_view: list[dict[str, Any]], *keys: str) -> list[Any]:
    """``row[k1][k2]...`` of every per-view row that has it."""
    out = []
    for row in per_view:
        node: Any = row
        for k in keys:
            node = node.get(k) if isinstance(node, dict) else None
        if node is not None:
            out.append(node)
    return out


def _truth(
    dm: DataManager, idx: int, clean: Tensor, reference: Tensor | None, medium: bool
) -> tuple[dict[str, float | None] | None, Tensor | None, Tensor | None]:
    """From the dataset's true maps of view ``idx``: the observable-pixel scores of the clean render
    [H, W, 3] (every method), and the true T [H, W, 1] and S [H, W, 3] for the medium protocol
    (methods with a medium only; None where the dataset has none)."""
    size: tuple[int, int] = tuple(clean.shape[:2])  # type: ignore[assignment]
    true_t = reference_map(dm, REFERENCE_T_KEY, idx, size)
    observable = None
    if reference is not None and true_t is not None:
        observable = observable_scores(clean, reference, true_t)
    if not medium:
        return observable, None, None
    return observable, true_t, reference_map(dm, REFERENCE_S_KEY, idx, size)


def _medium_at_true_depth(
    pipeline: Pipeline, dm: DataManager, idx: int, camera: Cameras, size: tuple[int, int]
) -> tuple[Tensor, Tensor] | None:
    """The model's T [H, W, 1] and S [H, W, 3] marched to view ``idx``'s true depth; None without a
    depth map or a medium."""
    true_z = reference_depth(dm, idx, size)  # [H, W, 1] in the run's frame
    return None if true_z is None else pipeline.medium_at_depth(camera, true_z)


def _mean_observable(rows: list[dict[str, float | None]]) -> dict[str, Any] | None:
    """Mean over views of the observable-pixel PSNR (views with such pixels) and share."""
    if not rows:
        return None
    vals = [r["psnr"] for r in rows if r["psnr"] is not None]
    return {
        "psnr": sum(vals) / len(vals) if vals else None,
        "share": sum(r["share"] for r in rows) / len(rows),  # type: ignore[misc]
        "t_floor": OBSERVABLE_T,
        "views": len(rows),
    }


def _bin_transmittance(
    bins: BinSource, medium: bool, out: dict[str, Tensor], dm: DataManager, idx: int
) -> tuple[Tensor | None, str | None]:
    if bins == "none":
        return None, None
    if bins in ("auto", "model") and medium:
        return out["transmittance"], "model"
    if bins in ("auto", "reference"):
        size = tuple(out["clean"].shape[:2])
        ref = reference_map(dm, REFERENCE_T_KEY, idx, size)  # type: ignore[arg-type]
        if ref is not None:
            return ref, "reference"
    return None, None


def evaluate_split(pipeline: Pipeline, dm: DataManager, split: str = "test") -> dict[str, float | int]:
    """The quick numbers ``td-train`` prints and saves at the end (PSNR / SSIM, no LPIPS)."""
    report = evaluate(pipeline, dm, split, bins="none")
    result: dict[str, float | int] = {"split_views": report["views"]}
    for name in ("reconstruction", "restoration"):
        if report[name] is not None:
            result[f"{name}_psnr"] = report[name]["psnr"]
            result[f"{name}_ssim"] = report[name]["ssim"]
    return result
