"""The haze probe behind ``--pipeline.medium.backend auto``: does this capture need a medium at all,
and if so, is one extinction for the whole scene enough or does the haze vary in space?

It reads only the training views and the seed points, before training. A seed point seen in two
views has, under I = J T + A (1 - T), the same clean colour J in both, so

    ln |I_a - A| - ln |I_b - A| = -(tau_a - tau_b)

where tau is the optical depth from each camera to the point: the surface colour cancels (the
dark-channel prior's albedo bias does not enter). In a homogeneous medium tau = beta * distance,
so one beta fitted over all pairs explains every pair up to pixel noise; where the haze varies,
the two rays of a pair cross different amounts of it and whole pairs of views disagree with that
fit. Per pair of views the probe measures the median residual against its spread
(``effect`` = |median| / MAD, and ``F`` = n * effect^2, which grows with the evidence).

Classification (thresholds calibrated on 49 generated scenes, docs/tradeoff.md):
  * ``none``: optical depth beta * (median point distance) < 0.1 (T > 0.9 at a typical distance),
    or a dark channel that does not thicken with distance (rank correlation of -ln T_dcp with the
    points' distance < 0.5: exposure changes or glossy surfaces, not haze);
  * ``varying``: median F > 15 and median effect > 0.3 (pairs of views cross different haze);
  * ``homogeneous``: otherwise (one extinction explains every pair).
Without seed points (or too few shared between views) nothing can be measured: ``unknown``.

The backend for each class (:data:`BACKEND_FOR`) is the one measured best, not the one that looks
simplest: in this engine the ``constant`` medium loses 5-6 dB of restoration PSNR to the tri-plane
even on a perfectly uniform medium, at no lower cost (docs/tradeoff.md), so homogeneous haze also
gets the tri-plane; a capture without haze gets no medium (the tri-plane there invents haze: 17.3
vs 30.7 dB).
"""

from __future__ import annotations

import itertools
import math
import time
import warnings
from dataclasses import asdict, dataclass

import numpy as np
import torch

from components.losses.dcp import DCPResult, estimate_dcp
from components.losses.depth_priors import in_image, project_points
from pipelines.datamanager import DataManager

NONE_OPTICAL_DEPTH = 0.1
"""Below this optical depth at the median point distance the haze is negligible (T > 0.9)."""
BACKEND_FOR = {"none": "none", "homogeneous": "triplane", "varying": "triplane", "unknown": "triplane"}
"""Medium backend per haze class, from the measured comparison (docs/tradeoff.md)."""
MIN_DEPTH_TREND = 0.5
"""Haze thickens with distance: below this rank correlation of -ln T_dcp with the distance of the
seed points, what the pair fit calls extinction is something else (exposure changes, glossy or
haze-coloured surfaces) and no medium is modelled."""
VARYING_F = 15.0
"""Median per-pair F above which pairs of views disagree with a homogeneous medium..."""
VARYING_EFFECT = 0.3
"""...with a median effect size (|median residual| / MAD) above this."""
MAX_VIEWS = 32
"""Views used (evenly spread over the training views); pairs grow as views^2."""
MAX_POINTS = 20_000
"""Seed points used (a fixed random subset beyond this)."""
MIN_SHARED = 15
"""Points two views must share for the pair to count."""
MIN_SIGNAL = 0.05
"""|I - A| below this (a surface the colour of the haze) carries no transmittance information."""
GRID_CELLS = 16
"""Cells along the longer image side of the point z-buffer that drops occluded seed points."""


@dataclass
class HazeProbe:
    """The probe's measurements and verdict (all logged)."""

    haze: str
    """``none``, ``homogeneous``, ``varying`` or ``unknown``."""
    reason: str
    beta: float = math.nan
    """Extinction fitted over all view pairs (1 / scene unit)."""
    median_distance: float = math.nan
    """Median camera-to-point distance over the visible seed points (scene units)."""
    optical_depth: float = math.nan
    """beta * median_distance."""
    variation_f: float = math.nan
    """Median over view pairs of F = n * (median residual / MAD)^2."""
    variation_effect: float = math.nan
    """Median over view pairs of |median residual| / MAD."""
    depth_trend: float = math.nan
    """Rank correlation of the dark channel's optical depth -ln T_dcp with the point distance."""
    pairs: int = 0
    views: int = 0
    seconds: float = 0.0
    """Time the probe took."""

    @property
    def backend(self) -> str:
        """The medium backend ``auto`` resolves to."""
        return BACKEND_FOR[self.haze]

    def message(self) -> str:
        head = f"haze probe ({self.seconds:.2f} s): {self.haze} haze -> medium backend {self.backend}"
        if math.isnan(self.beta):
            return f"{head} ({self.reason})"
        return (
            f"{head} ({self.reason}; beta {self.beta:.4g} per scene unit, "
            f"dark-channel depth trend {self.depth_trend:.2f}, "
            f"optical depth {self.optical_depth:.3f} at the median distance {self.median_distance:.3g}, "
            f"pair variation F {self.variation_f:.1f} / effect {self.variation_effect:.2f}, "
            f"{self.pairs} view pairs)"
        )

    def to_dict(self) -> dict:
        return {**asdict(self), "backend": self.backend}


def _visible(points: torch.Tensor, cam, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices of the seed points in view and in front (a coarse z-buffer of the points themselves),
    their pixel coordinates [M, 2] and distances [M]."""
    pc, uv = project_points(points, cam.viewmats()[0].float(), cam.Ks()[0].float())
    ok = in_image(pc, uv, width, height, near=1e-6)  # [M]
    pc, uv = pc.numpy(), uv.numpy()
    idx = np.nonzero(ok.numpy())[0]
    px = uv[idx].astype(np.int64)  # [M, 2]
    z = pc[idx, 2]
    cell = max(max(width, height) // GRID_CELLS, 1)
    key = (px[:, 1] // cell) * (width // cell + 1) + px[:, 0] // cell
    front = np.full(int(key.max()) + 1 if len(key) else 1, np.inf)
    np.minimum.at(front, key, z)
    keep = z <= 1.1 * front[key]
    idx, px = idx[keep], px[keep]
    return idx, px, np.linalg.norm(pc[idx], axis=-1)


def _rank_correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation (ties broken by order; enough for thousands of samples)."""
    if len(a) < 3:
        return math.nan
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def probe_haze(
    dm: DataManager,
    views: list[int],
    points: torch.Tensor | None,
    seed: int = 0,
    dcp: dict[int, DCPResult] | None = None,
) -> HazeProbe:
    """Measure the training views (see the module docstring) and choose a medium backend.
    ``dcp``: dark-channel results already computed per view (estimated here where missing)."""
    start = time.perf_counter()
    probe = _probe(dm, views, points, seed, dcp or {})
    probe.seconds = time.perf_counter() - start
    return probe


def _probe(
    dm: DataManager, views: list[int], points: torch.Tensor | None, seed: int, dcps: dict[int, DCPResult]
) -> HazeProbe:
    if points is None or len(points) < MIN_SHARED:
        return HazeProbe("unknown", "no seed points to measure the haze with")
    pts = points.detach().float().cpu()
    if len(pts) > MAX_POINTS:
        gen = torch.Generator().manual_seed(seed)
        pts = pts[torch.randperm(len(pts), generator=gen)[:MAX_POINTS]]
    if len(views) > MAX_VIEWS:
        views = [views[round(k * (len(views) - 1) / (MAX_VIEWS - 1))] for k in range(MAX_VIEWS)]
    n, v = len(pts), len(views)
    colour = np.full((v, n, 3), np.nan, np.float32)  # [V, N, 3] pixel colour of each visible point
    dist = np.full((v, n), np.nan, np.float32)  # [V, N]
    airlights, dcp_tau = [], np.full((v, n), np.nan, np.float32)
    for a, i in enumerate(views):
        img = dm.image(i).cpu().numpy()  # [H, W, 3]
        dcp = dcps[i] if i in dcps else estimate_dcp(img)
        airlights.append(dcp.airlight)
        cam = dm.camera(i).to("cpu")
        idx, px, d = _visible(pts, cam, int(cam.width[0]), int(cam.height[0]))
        colour[a, idx] = img[px[:, 1], px[:, 0]]
        dist[a, idx] = d
        dcp_tau[a, idx] = -np.log(np.clip(dcp.transmittance[px[:, 1], px[:, 0]], 1e-3, 1.0))
    airlight = np.median(np.stack(airlights), axis=0)  # [3]
    diff = colour - airlight  # [V, N, 3]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # points no view sees: all-NaN rows
        strength = np.nan_to_num(np.nanmean(np.abs(diff), axis=0))  # [N, 3]
    channel = strength.argmax(-1)  # [N] the channel farthest from the airlight, per point
    signed = np.take_along_axis(diff, np.broadcast_to(channel[None, :, None], (v, n, 1)), 2)[..., 0]  # [V, N]
    log_mag = np.log(np.maximum(np.abs(signed), 1e-6))

    ys, xs = [], []
    for a, b in itertools.combinations(range(v), 2):
        m = np.isfinite(dist[a]) & np.isfinite(dist[b])
        m &= (np.abs(signed[a]) > MIN_SIGNAL) & (np.abs(signed[b]) > MIN_SIGNAL)
        m &= np.sign(signed[a]) == np.sign(signed[b])
        if int(m.sum()) >= MIN_SHARED:
            ys.append(log_mag[a, m] - log_mag[b, m])  # = tau_b - tau_a
            xs.append(dist[b, m] - dist[a, m])
    if len(ys) < 3:
        return HazeProbe(
            "unknown", f"only {len(ys)} view pairs share enough seed points", pairs=len(ys), views=v
        )
    x, y = np.concatenate(xs), np.concatenate(ys)
    beta = float((x * y).sum() / max(float((x * x).sum()), 1e-12))
    f_stats, effects = [], []
    for xp, yp in zip(xs, ys, strict=True):
        r = yp - beta * xp
        med = float(np.median(r))
        mad = 1.4826 * float(np.median(np.abs(r - med))) + 1e-6
        effects.append(abs(med) / mad)
        f_stats.append(len(r) * (med / mad) ** 2)
    median_distance = float(np.nanmedian(dist))
    seen = np.isfinite(dist)
    depth_trend = _rank_correlation(dist[seen], dcp_tau[seen])
    out = HazeProbe(
        "homogeneous", "", beta=beta, median_distance=median_distance, optical_depth=beta * median_distance,
        variation_f=float(np.median(f_stats)), variation_effect=float(np.median(effects)), depth_trend=depth_trend, pairs=len(ys), views=v,
    )  # fmt: skip
    if out.optical_depth < NONE_OPTICAL_DEPTH:
        out.haze = "none"
        out.reason = (
            f"no haze to model: optical depth {out.optical_depth:.3f} < {NONE_OPTICAL_DEPTH} "
            f"(T {math.exp(-out.optical_depth):.2f}) at a typical distance"
        )
    elif depth_trend < MIN_DEPTH_TREND:
        out.haze = "none"
        out.reason = (
            f"no haze to model: the dark channel does not thicken with distance (rank correlation "
            f"{depth_trend:.2f} < {MIN_DEPTH_TREND:g})"
        )
    elif out.variation_f > VARYING_F and out.variation_effect > VARYING_EFFECT:
        out.haze = "varying"
        out.reason = (
            f"view pairs disagree with one extinction "
            f"(F {out.variation_f:.1f} > {VARYING_F:g}, effect {out.variation_effect:.2f} > {VARYING_EFFECT:g})"
        )
    else:
        out.reason = (
            f"one extinction explains every view pair (F {out.variation_f:.1f} <= {VARYING_F:g} or "
            f"effect {out.variation_effect:.2f} <= {VARYING_EFFECT:g})"
        )
    return out
