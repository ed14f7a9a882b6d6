"""Comparing two reconstructions of the same photos: camera centres up to a similarity transform.

A structure-from-motion result is defined only up to scale, rotation and translation, so camera
centres are compared after the least-squares similarity (Umeyama 1991) that maps one set onto the
other; the residual is reported relative to the reference's extent.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity (s, R, t) minimising sum |s R src_i + t - dst_i|^2; src, dst [N, 3], N >= 3."""
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"need two [N, 3] arrays with N >= 3, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)  # [3, 3]
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    var_s = (xs**2).sum() / len(src)
    s = float(np.trace(np.diag(D) @ S) / max(var_s, 1e-300))
    t = mu_d - s * R @ mu_s
    return s, R, t


@dataclass
class CameraAgreement:
    common: int
    """Images posed in both reconstructions."""
    rms: float
    """RMS distance between aligned and reference camera centres (reference units)."""
    max: float
    extent: float
    """Reference extent: RMS distance of its camera centres from their mean."""
    rotation_deg_median: float
    """Median over camera pairs of the angle between their relative rotations in the two
    reconstructions (needs no alignment, so it is meaningful even when the centres are nearly
    collinear and the aligning rotation is poorly determined)."""

    @property
    def relative_rms(self) -> float:
        return self.rms / max(self.extent, 1e-300)


def camera_poses(model: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Image name -> (camera centre [3], world-to-camera rotation [3, 3]) of a COLMAP model folder."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(model))
    out = {}
    for im in rec.images.values():
        if im.has_pose:
            m = np.asarray(im.cam_from_world().matrix())  # [3, 4]
            R, t = m[:, :3], m[:, 3]
            out[im.name] = (-R.T @ t, R)
    return out


def compare_cameras(
    estimate: dict[str, tuple[np.ndarray, np.ndarray]], reference: dict[str, tuple[np.ndarray, np.ndarray]]
) -> CameraAgreement:
    """Align ``estimate``'s camera centres to ``reference``'s (shared names) and measure the residual."""
    names = sorted(set(estimate) & set(reference))
    if len(names) < 3:
        raise ValueError(f"only {len(names)} images are posed in both reconstructions; need 3")
    a = np.stack([estimate[n][0] for n in names])  # [N, 3]
    b = np.stack([reference[n][0] for n in names])  # [N, 3]
    s, R, t = umeyama(a, b)
    err = np.linalg.norm(a @ (s * R).T + t - b, axis=1)  # [N]
    extent = float(np.sqrt(((b - b.mean(0)) ** 2).sum(1).mean()))
    angles = []
    for i, ni in enumerate(names):  # relative rotations between cameras: independent of the frames
        for nj in names[i + 1 :]:
            rel_est = estimate[ni][1] @ estimate[nj][1].T
            rel_ref = reference[ni][1] @ reference[nj][1].T
            c = np.clip((np.trace(rel_est @ rel_ref.T) - 1.0) / 2.0, -1.0, 1.0)
            angles.append(float(np.degrees(np.arccos(c))))
    return CameraAgreement(
        common=len(names),
        rms=float(np.sqrt((err**2).mean())),
        max=float(err.max()),
        extent=extent,
        rotation_deg_median=float(np.median(angles)),
    )
