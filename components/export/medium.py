"""The medium of a run as a compact grid file plus colour-mapped slices of its extinction.

``medium.npz`` (``numpy.load``), for a field medium (tri-plane, voxel, MLP, ...):

| key | shape | meaning |
|---|---|---|
| ``beta`` | [R, R, R] float32 | extinction at cell centres, ``beta[i, j, k]`` at grid point (i, j, k) |
| ``grid_to_world`` | [4, 4] | homogeneous map from (i, j, k) to a point in the export frame |
| ``light`` | [D, r, r, r, 3] float16 | medium light seen along each of ``light_dirs`` on a coarser grid |
| ``light_dirs`` | [D, 3] | unit view directions (export frame) of ``light`` |
| ``light_grid_to_world`` | [4, 4] | as ``grid_to_world`` for the light grid |
| ``bounds_center``, ``bounds_half_size`` | [3] | the field's box in the run's normalised world |
| ``transform_rotation``, ``transform_translation``, ``transform_scale`` | | the run's dataparser similarity ``x_norm = s (R x + t)`` |
| ``frame`` | str | ``original`` (dataset units) or ``normalized`` |
| ``beta_unit`` | str | extinction per unit length of that frame |

The grid covers the field's box, which is axis-aligned in the normalised world; points outside it
read the boundary value (the field clamps). In the ``original`` frame beta is multiplied by the
transform's scale (optical depth is frame independent: ``beta_orig d_orig = beta_norm d_norm``).

A ``gaussian-bound`` medium has no field: its per-Gaussian extinction and light are written instead
(``beta_per_gaussian`` [N], ``light_per_gaussian`` [N, 3], ``background_beta``, ``background_light``),
in the same order as the Gaussians of the PLY.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from components.data.images import write_bytes_atomic, write_image_atomic
from components.data.scene import SceneTransform
from components.gaussians.model import GaussianModel
from components.medium.base import GaussianMediumValues, MediumField

LIGHT_DIRS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)
"""Directions at which the (direction-dependent) medium light is sampled, in the export frame."""

SLICE_SIZE = 256
"""Longest side of a slice PNG (nearest-neighbour upsampling of the grid)."""


def _grid_points(center: np.ndarray, half: np.ndarray, res: int) -> tuple[np.ndarray, np.ndarray]:
    """Cell centres [res^3, 3] (i slowest) and the normalised-frame grid_to_world [4, 4]."""
    lo = center - half
    step = 2 * half / res
    idx = (np.arange(res) + 0.5)[:, None] * step[None, :] + lo[None, :]  # [res, 3]
    gx, gy, gz = np.meshgrid(idx[:, 0], idx[:, 1], idx[:, 2], indexing="ij")
    pts = np.stack([gx, gy, gz], -1).reshape(-1, 3)
    g2w = np.eye(4)
    g2w[:3, :3] = np.diag(step)
    g2w[:3, 3] = lo + 0.5 * step
    return pts, g2w


def _to_frame_matrix(transform: SceneTransform | None) -> np.ndarray:
    """[4, 4] map from the normalised world to the export frame (identity when ``transform`` is None)."""
    m = np.eye(4)
    if transform is None:
        return m
    R = transform.rotation.detach().cpu().double().numpy()
    t = transform.translation.detach().cpu().double().numpy()
    s = float(transform.scale)
    m[:3, :3] = R.T / s  # x = R^T (x_n / s - t)
    m[:3, 3] = -R.T @ t
    return m


@torch.no_grad()
def _evaluate(
    field, pts: np.ndarray, dirs: np.ndarray, chunk: int = 1 << 16
) -> tuple[np.ndarray, np.ndarray]:
    """beta [P], light [P, 3] of ``field`` at normalised-frame points with one direction [3]."""
    dev = field.bounds_center.device
    betas, lights = [], []
    d = torch.as_tensor(dirs, dtype=torch.float32, device=dev)
    for i in range(0, len(pts), chunk):
        x = torch.as_tensor(pts[i : i + chunk], dtype=torch.float32, device=dev)
        out = field(x, d.expand(len(x), 3))
        betas.append(out.beta.float().cpu().numpy())
        lights.append(out.light.float().cpu().numpy())
    return np.concatenate(betas), np.concatenate(lights)


def colorize(values: np.ndarray, vmax: float) -> np.ndarray:
    """[H, W] >= 0 -> uint8 RGB with the turbo colour map over [0, vmax]."""
    norm = np.clip(values / max(vmax, 1e-12), 0, 1)
    bgr = cv2.applyColorMap((norm * 255 + 0.5).astype(np.uint8), cv2.COLORMAP_TURBO)
    return np.ascontiguousarray(bgr[..., ::-1])


def _upsample(img: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    s = max(1, SLICE_SIZE // max(h, w))
    return cv2.resize(img, (w * s, h * s), interpolation=cv2.INTER_NEAREST)


def write_slices(beta: np.ndarray, out_dir: Path, vmax: float) -> list[str]:
    """Three axis-aligned mid slices of ``beta [R, R, R]`` as PNGs; returns their file names.

    ``extinction_xy.png`` is the slice at the middle z (rows: y, columns: x), likewise ``xz`` (mid
    y) and ``yz`` (mid x); axes are those of the grid (the normalised world), row 0 = low values.
    """
    r = beta.shape[0] // 2
    slices = {
        "extinction_xy.png": beta[:, :, r].T,  # [y, x]
        "extinction_xz.png": beta[:, r, :].T,  # [z, x]
        "extinction_yz.png": beta[r, :, :].T,  # [z, y]
    }
    for name, arr in slices.items():
        write_image_atomic(out_dir / name, _upsample(colorize(arr, vmax)))
    return list(slices)


def export_medium(
    medium: MediumField,
    out_dir: Path,
    transform: SceneTransform | None,
    resolution: int = 64,
    light_resolution: int = 16,
    model: GaussianModel | None = None,
) -> dict[str, Any]:
    """Write ``medium.npz`` (+ slice PNGs for a field) to ``out_dir``; returns a summary.

    ``transform`` None keeps the normalised frame; otherwise the run's dataparser transform,
    whose inverse maps the grid into the dataset's own world. ``model``: the scene's Gaussians,
    where a medium living on them (``gaussian_values``) is read from.
    """
    frame = "normalized" if transform is None else "original"
    scale = 1.0 if transform is None else float(transform.scale)
    tr = transform or SceneTransform.identity()
    common = {
        "bounds_center": medium.bounds_center.detach().cpu().numpy().astype(np.float64),
        "bounds_half_size": medium.bounds_half.detach().cpu().numpy().astype(np.float64),
        "transform_rotation": tr.rotation.detach().cpu().double().numpy(),
        "transform_translation": tr.translation.detach().cpu().double().numpy(),
        "transform_scale": np.float64(tr.scale),
        "frame": np.array(frame),
        "beta_unit": np.array(f"1 / {'dataset' if frame == 'original' else 'normalised'} unit"),
    }
    values = medium.gaussian_values(model) if model is not None else None
    if values is not None:  # gaussian-bound: per-Gaussian values, no field
        return _export_per_gaussian(values, common, scale, out_dir)
    return _export_field(
        medium, common, scale, _to_frame_matrix(transform), resolution, light_resolution, out_dir
    )


def _export_per_gaussian(
    values: GaussianMediumValues, common: dict[str, Any], scale: float, out_dir: Path
) -> dict[str, Any]:
    beta = values.beta.numpy() * scale
    arrays = {
        **common,
        "kind": np.array("gaussian-bound"),
        "beta_per_gaussian": beta.astype(np.float32),
        "light_per_gaussian": values.light.numpy().astype(np.float16),
        "background_beta": np.float32(values.background_beta * scale),
        "background_light": values.background_light.numpy().astype(np.float32),
    }
    _save_npz(out_dir / "medium.npz", arrays)
    return {
        "kind": "gaussian-bound",
        "files": ["medium.npz"],
        "beta_median": float(np.median(beta)),
        "beta_max": float(beta.max(initial=0.0)),
    }


def _export_field(
    medium: MediumField, common: dict[str, Any], scale: float, to_frame: np.ndarray,
    resolution: int, light_resolution: int, out_dir: Path,
) -> dict[str, Any]:  # fmt: skip
    """The field sampled on a resolution^3 grid (extinction) and a coarser one per light direction."""
    center, half = common["bounds_center"], common["bounds_half_size"]
    pts, g2w = _grid_points(center, half, resolution)
    beta, _ = _evaluate(medium, pts, np.array([0.0, 0.0, 1.0]))
    beta = beta.reshape(resolution, resolution, resolution) * scale
    lpts, lg2w = _grid_points(center, half, light_resolution)
    rot_to_frame = to_frame[:3, :3] * scale  # pure rotation R^T
    light = []
    for d in LIGHT_DIRS:
        d_norm = rot_to_frame.T @ d  # export-frame direction -> normalised frame (R d)
        _, lt = _evaluate(medium, lpts, d_norm)
        light.append(lt.reshape(light_resolution, light_resolution, light_resolution, 3))
    arrays = {
        **common,
        "kind": np.array("field"),
        "beta": beta.astype(np.float32),
        "grid_to_world": to_frame @ g2w,
        "light": np.stack(light).astype(np.float16),
        "light_dirs": LIGHT_DIRS.copy(),
        "light_grid_to_world": to_frame @ lg2w,
    }
    _save_npz(out_dir / "medium.npz", arrays)
    vmax = float(np.percentile(beta, 99.5)) if beta.size else 1.0
    pngs = write_slices(beta, out_dir, vmax)
    return {
        "kind": "field",
        "files": ["medium.npz", *pngs],
        "resolution": resolution,
        "light_resolution": light_resolution,
        "beta_min": float(beta.min()),
        "beta_median": float(np.median(beta)),
        "beta_max": float(beta.max()),
        "slice_range": [0.0, vmax],
        "beta_unit": str(arrays["beta_unit"]),
    }


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    bio = io.BytesIO()
    np.savez_compressed(bio, **arrays)
    write_bytes_atomic(path, bio.getvalue())
