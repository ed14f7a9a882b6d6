"""Seed clouds for generated scenes: as good as SfM on hazy photos gives, or clean on request.

The ``clean`` cloud (true surface points, 0.3 % jitter, thousands of them) hands the depth prior
and the medium's initialisation an almost perfect geometry that no capture has. The default
``sfm`` cloud follows what ``td-process-data`` (COLMAP, CLAHE-enhanced matching) actually
reconstructs from generated hazy photos (``benchmarks/seed_cloud.py``, docs/results/seed_cloud.md):

- sparse: 30 points per train view (measured 24-36 per registered view, 0.15-0.49 per 1000
  pixels at 320x240);
- where a matcher finds features: pixels drawn in proportion to the local contrast of the
  CLAHE-enhanced hazy view (a flat or fully veiled surface gets none, sky never);
- depth noise along the ray growing with distance: sigma / z = 0.5 % + 2.5 % * z / z_median of the
  view (measured median errors 0.5-2 % near, 1.5-8 % far);
- 5 % outliers moved along their ray by up to +-50 % (with the depth noise, 4-10 % of the points are
  more than 10 % off; measured 3-11 %).
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from components.data.cameras import ViewIntrinsics
from components.losses.depth_priors import in_image, project_points
from components.sfm.enhance import clahe
from components.synth.geometry import NEAR, SceneGeometry, trace

SFM_POINTS_PER_VIEW = 30
"""Points per train view of the ``sfm`` cloud when the count is not given (measured 24-36 per
registered view at 320x240). Per view, not per pixel: SfM runs on the photos at capture size,
while generated benchmark scenes are rendered small to train fast."""
SFM_MIN_POINTS = 64
"""Floor on the ``sfm`` cloud's default count (a handful of points seeds nothing)."""
SFM_NOISE_FLOOR = 0.005
"""Relative depth noise (sigma / z) of the ``sfm`` cloud at zero depth."""
SFM_NOISE_SLOPE = 0.025
"""Growth of the relative depth noise per view-median depth (sigma / z = floor + slope z / z_med)."""
SFM_OUTLIERS = 0.05
"""Share of ``sfm`` points moved along their ray by a factor in [0.5, 1.5]."""


def default_count(model: str, train_views: int) -> int:
    """The number of seed points of ``model`` for a capture of ``train_views`` training views."""
    if model == "clean":
        return 4000
    return max(SFM_MIN_POINTS, SFM_POINTS_PER_VIEW * train_views)


def feature_weight(hazy: torch.Tensor) -> np.ndarray:
    """[H, W, 3] hazy view -> [H*W] local contrast where a matcher looks for features: the Sobel
    magnitude of the CLAHE-enhanced grey view (``td-process-data --enhance clahe``, what hazy
    photos need), 3x3 smoothed. CLAHE restores much of the contrast haze took, so features are
    not confined to the clearest pixels (as measured), yet flat or fully veiled surfaces get none."""
    rgb = np.clip(hazy.numpy() * 255.0 + 0.5, 0, 255).astype(np.uint8)  # [H, W, 3]
    grey = cv2.cvtColor(clahe(rgb), cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0  # [H, W]
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.blur(np.sqrt(gx * gx + gy * gy), (3, 3)).reshape(-1)  # [H*W]


def pick_pixels(
    model: str, hit: np.ndarray, hazy: torch.Tensor, k: int, rng: np.random.Generator
) -> np.ndarray:
    """Indices of ``k`` surface pixels (``hit`` [H*W] bool): uniform (clean) or by contrast (sfm)."""
    idx = np.flatnonzero(hit)
    if len(idx) == 0 or k == 0:
        return idx[:0]
    if model == "clean":
        return np.sort(rng.choice(idx, size=min(k, len(idx)), replace=False))
    w = feature_weight(hazy)[idx].astype(np.float64)
    if w.sum() <= 0:
        return idx[:0]
    k = min(k, int((w > 0).sum()))
    return np.sort(rng.choice(idx, size=k, replace=False, p=w / w.sum()))


SFM_TRACK_KEEP = 0.6
"""Chance that an ``sfm`` track keeps a view that sees the point within ``SFM_TRACK_ANGLE`` of the
view it was found in. With the angle below it gives COLMAP's median track of 3 views on generated
hazy views (5 scenes at 320x240, 32 views; docs/results/track_completeness.md); td-synth's
complete tracks had 11-14."""
SFM_TRACK_ANGLE = 30.0
"""Degrees between a view's ray to the point and the finding view's ray beyond which an ``sfm``
track never keeps it (COLMAP: 0.03-0.06 of the seeing views 20-40 degrees from the nearest track
view are in the track, none beyond 40)."""
TRACK_TOLERANCE = 1e-3
"""A track view must see the point's surface within this share of its distance (the hit's own
rounding; anything nearer along the ray is an occluder)."""


def seed_tracks(
    geometry: SceneGeometry,
    surface: np.ndarray,
    poses: list[np.ndarray],
    K: ViewIntrinsics,
    views: list[int],
    model: str = "clean",
    source: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """[P, 2] (point, view) pairs: the ``views`` (indices into ``poses``, OpenCV camera-to-world)
    whose image holds the true ``surface`` point [M, 3] (before the cloud's noise) with nothing in
    front of it. ``clean``: all of them (matching succeeds everywhere). ``sfm``: what COLMAP keeps
    on hazy photos: the point's ``source`` view [M] (where it was found) always, another seeing view
    with chance ``SFM_TRACK_KEEP`` when its ray is within ``SFM_TRACK_ANGLE`` of the source's, else
    never (drawn from ``rng``). One traced ray per point and view."""
    if model == "sfm" and (source is None or rng is None):
        raise ValueError("sfm tracks need each point's source view and a random generator")
    pairs = []
    X = torch.from_numpy(np.asarray(surface, np.float64)).float()  # [M, 3]
    if model == "sfm":
        src_c = torch.stack(
            [torch.from_numpy(np.asarray(poses[int(j)], np.float64)[:3, 3]).float() for j in source]
        )
        src_ray = torch.nn.functional.normalize(X - src_c, dim=-1) if len(X) else X  # [M, 3]
        cos_max = float(np.cos(np.radians(SFM_TRACK_ANGLE)))
    k = torch.tensor([[K.fx, 0.0, K.cx], [0.0, K.fy, K.cy], [0.0, 0.0, 1.0]])
    for j in views:
        c2w = torch.from_numpy(np.asarray(poses[j], np.float64)).float()
        centre = c2w[:3, 3]
        pc, uv = project_points(X, torch.linalg.inv(c2w), k)  # [M, 3], [M, 2] (OpenCV axes)
        idx = torch.nonzero(in_image(pc, uv, K.width, K.height, near=NEAR))[:, 0]
        if len(idx) == 0:
            continue
        offset = X[idx] - centre  # [m, 3]
        dist = offset.norm(dim=-1)
        hit = trace(geometry, centre.expand(len(idx), 3), offset / dist[:, None])
        seen = hit.t >= dist * (1.0 - TRACK_TOLERANCE)  # [m] no surface in front of the point
        if model == "sfm":
            near = (src_ray[idx] * (offset / dist[:, None])).sum(-1) >= cos_max  # [m]
            keep = near & torch.from_numpy(rng.random(len(idx)) < SFM_TRACK_KEEP)
            seen &= keep | torch.from_numpy(source[idx.numpy()] == j)
        pts = idx[seen].numpy()
        pairs.append(np.stack([pts, np.full(len(pts), j)], axis=1))
    return np.concatenate(pairs).astype(np.int64) if pairs else np.zeros((0, 2), np.int64)


def place_points(
    model: str, origins: np.ndarray, dirs: np.ndarray, t: np.ndarray, jitter: float, rng: np.random.Generator
) -> np.ndarray:
    """[k, 3] points along rays (``origins``, unit ``dirs`` [k, 3], true distances ``t`` [k]) with
    the model's errors: ``jitter * distance`` on every axis for both; depth noise and outliers
    along the ray for ``sfm``."""
    t = t.astype(np.float64)
    if model == "sfm" and len(t):
        rel = SFM_NOISE_FLOOR + SFM_NOISE_SLOPE * t / np.median(t)  # [k]
        t = t * (1.0 + rng.normal(size=t.shape) * rel)
        out = rng.random(len(t)) < SFM_OUTLIERS
        t[out] *= rng.uniform(0.5, 1.5, size=int(out.sum()))
        t = np.maximum(t, 1e-3)
    xyz = origins + t[:, None] * dirs  # [k, 3]
    return xyz + rng.normal(size=xyz.shape) * (jitter * t)[:, None]
