"""Per-view priors computed once from the hazy inputs: dark-channel transmittance, pseudo-depth,
and the data-driven start of the medium (airlight, extinction, dehazed seed colours).

No network is involved: the paper's monocular depth model cannot be downloaded here, so the
pseudo-depth comes from files, the dark channel, the SfM points or a short haze-agnostic warm-up
(docs/medium.md compares them on generated scenes).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from components.data.cameras import Cameras
from components.data.scene import PointTracks
from components.losses.dcp import DCPResult, dehaze, estimate_dcp
from components.losses.depth_priors import (
    depth_from_dcp,
    depth_from_file,
    depth_from_sfm,
    in_image,
    project_points,
)
from pipelines.engine.datamanager import DataManager

DEPTH_PRIORS = ("auto", "files", "dcp", "sfm", "warmup", "none")


@dataclass
class ViewPrior:
    """What the losses compare against for one training view (all on the training device)."""

    t_dcp: Tensor | None = None  # [H, W] dark-channel transmittance (None: not computed)
    airlight: Tensor | None = None  # [3] the view's dark-channel airlight (None: not computed)
    depth: Tensor | None = (
        None  # [H, W] pseudo-depth (relative unless depth_metric), None: no depth loss on this view
    )
    depth_valid: Tensor | None = None  # [H, W] bool
    depth_metric: bool = False
    """``depth`` is z in the scene's own frame (projected SfM points), so its scale can be used."""


@dataclass
class MediumEstimate:
    """A global start for the medium from the dark channel and the seed points."""

    airlight: Tensor  # [3]
    beta: float | None  # 1 / scene unit; None when there are no seed points to measure it with


_HandOverKey = tuple[tuple[int, ...], tuple[float, ...] | None]
_HANDED_OVER: weakref.WeakKeyDictionary[DataManager, tuple[_HandOverKey, dict[int, DCPResult]]] = (
    weakref.WeakKeyDictionary()
)
"""Dark channels kept by a ``keep=True`` call for the next call on the same data manager and views."""


def dcp_per_view(
    dm: DataManager,
    indices: list[int],
    keep: bool = False,
    airlight: tuple[float, float, float] | None = None,
) -> dict[int, DCPResult]:
    """The dark-channel estimate of each view. ``keep``: hold the result for the next call on the
    same views, which takes it instead of recomputing (the haze probe in ``resolve()`` hands its
    dark channels to the pipeline's setup; held only until then, they cost no memory in training).
    ``airlight``: a known haze light for every view instead of each view's dark-channel estimate."""
    key = (tuple(indices), None if airlight is None else tuple(float(a) for a in airlight))
    held = _HANDED_OVER.pop(dm, None)
    if held is not None and held[0] == key:
        return held[1]
    given = None if airlight is None else np.asarray(airlight, dtype=np.float32)
    out = {i: estimate_dcp(dm.image(i).cpu().numpy(), airlight=given) for i in indices}
    if keep:
        _HANDED_OVER[dm] = (key, out)
    return out


def dehazed_views(dm: DataManager, dcp: dict[int, DCPResult]) -> dict[int, Tensor]:
    """Each view's single-image DCP restoration as uint8 [H, W, 3] on the device (the dcp-gs inputs)."""
    out = {}
    for i, result in dcp.items():
        clean = dehaze(dm.image(i).cpu().numpy(), result)  # [H, W, 3] float32 in [0, 1]
        out[i] = torch.from_numpy((clean * 255.0 + 0.5).astype(np.uint8)).to(dm.device)
    return out


def estimate_medium(
    dm: DataManager, dcp: dict[int, DCPResult], points: Tensor | None, max_views: int = 16
) -> MediumEstimate:
    """Airlight: median of the per-view dark-channel airlights. Extinction: median over seed points
    seen in training views of -ln(T_dcp) / path length, which ties the medium's scale to the
    scene's units (the dark channel alone knows T, not distance)."""
    airlight = torch.from_numpy(np.median(np.stack([r.airlight for r in dcp.values()]), axis=0)).float()
    if points is None or len(points) == 0:
        return MediumEstimate(airlight, None)
    ratios = []
    for i in list(dcp)[:max_views]:
        cam = dm.camera(i).to("cpu")
        pc, uv = project_points(points.detach().float().cpu(), cam.viewmats()[0], cam.Ks()[0])
        W, H = int(cam.width[0]), int(cam.height[0])
        ok = in_image(pc, uv, W, H, near=1e-3)
        if int(ok.sum()) == 0:
            continue
        t = torch.from_numpy(dcp[i].transmittance)  # [H, W]
        px = uv[ok].long()
        t_at = t[px[:, 1], px[:, 0]].clamp(1e-3, 0.999)
        path = pc[ok].norm(dim=-1)  # [m] distance from the camera along the ray
        ratios.append(-torch.log(t_at) / path.clamp_min(1e-6))
    if not ratios:
        return MediumEstimate(airlight, None)
    return MediumEstimate(airlight, float(torch.cat(ratios).median()))


def dehaze_point_colors(
    points: Tensor, colors: Tensor, centers: Tensor, est: MediumEstimate, t_floor: float = 0.2
) -> Tensor:
    """Seed colours with the estimated haze taken out: J = (c - A (1 - T)) / T, T from the nearest
    camera. SfM colours of hazy photos carry the haze; starting the Gaussians hazy makes the
    medium's job (and the ambiguity) harder."""
    if est.beta is None:
        return colors
    c = colors.float()
    if c.max() > 1.0:
        c = c / 255.0
    dist = torch.cdist(points.float(), centers.float().to(points.device)).min(dim=1).values  # [M]
    T = torch.exp(-est.beta * dist).clamp_min(t_floor)[:, None]
    return _invert_haze(c, est.airlight.to(c), T)


def _invert_haze(colour: Tensor, airlight: Tensor, T: Tensor) -> Tensor:
    """J = (c - A (1 - T)) / T clamped to [0, 1]: colour [M, 3], airlight [3], T [M, 1]."""
    return ((colour - airlight * (1 - T)) / T).clamp(0.0, 1.0)


@dataclass
class VisiblePoints:
    """The seed points one view sees, and where."""

    mask: Tensor  # [M] bool
    u: Tensor  # [m] pixel column of each seen point
    v: Tensor  # [m] pixel row
    distance: Tensor  # [m] distance from the camera


def visible_points(camera: Cameras, points: Tensor) -> VisiblePoints:
    """The points [M, 3] (CPU, float) that ``camera`` sees: inside the image and not behind the
    SfM depth prior's occlusion-filtered point z-buffer (within 2 %)."""
    cam = camera.to("cpu")
    H, W = int(cam.height[0]), int(cam.width[0])
    viewmat, K = cam.viewmats()[0].float(), cam.Ks()[0].float()
    zbuf, valid = depth_from_sfm(points, viewmat, K, H, W)  # [H, W] nearest point depth
    pc, uv = project_points(points, viewmat, K)  # [M, 3], [M, 2]
    ok = in_image(pc, uv, W, H, near=1e-3)
    u, v = uv[:, 0].long().clamp(0, W - 1), uv[:, 1].long().clamp(0, H - 1)
    ok &= valid[v, u] & (pc[:, 2] <= 1.02 * zbuf[v, u])
    return VisiblePoints(ok, u[ok], v[ok], pc[ok].norm(dim=-1))


def observed_point_colors(
    dm: DataManager, indices: list[int], points: Tensor, est: MediumEstimate, t_floor: float = 0.2
) -> tuple[Tensor, Tensor]:
    """Seed colours re-read from the training views that see each point, every observation c_k
    dehazed at its own distance d_k, J_k = (c_k - A (1 - T_k)) / T_k with T_k = exp(-beta d_k),
    and averaged with weight T_k^2 (the inversion multiplies the photo's error by 1 / T_k).
    A dataset's point colour is one hazy value whose viewing distance is unknown: dehazing it at
    the nearest camera's distance, the shortest one, leaves haze in and starts the Gaussians too
    bright. Visibility is the SfM depth prior's occlusion-filtered point z-buffer. Returns the
    colours [M, 3] and which points any view saw [M] (the others keep their dataset colour)."""
    pts = points.detach().float().cpu()
    num, den = torch.zeros(len(pts), 3), torch.zeros(len(pts))
    A = est.airlight.float().cpu()  # [3]
    for i in indices:
        vis = visible_points(dm.camera(i), pts)
        c = dm.image(i).cpu()[vis.v, vis.u].float()  # [m, 3] hazy observations
        T = torch.exp(-est.beta * vis.distance).clamp_min(t_floor)[:, None]  # [m, 1]
        num[vis.mask] += T**2 * _invert_haze(c, A, T)
        den[vis.mask] += T[:, 0] ** 2
    seen = den > 0
    return (num / den.clamp_min(1e-12)[:, None]).to(points.device), seen.to(points.device)


def build_view_priors(
    dm: DataManager,
    indices: list[int],
    dcp: dict[int, DCPResult],
    source: str,
    points: Tensor | None,
    warmup_depths: dict[int, Tensor] | None = None,
    tracks: PointTracks | None = None,
    union: bool = False,
) -> dict[int, ViewPrior]:
    """One :class:`ViewPrior` per training view for the chosen pseudo-depth ``source`` (``tracks``:
    the views each of ``points`` was observed in, when the dataset records them; ``union``: see
    :func:`sfm_view_depth`)."""
    out: dict[int, ViewPrior] = {}
    for i in indices:
        prior = ViewPrior()
        if i in dcp:
            prior.t_dcp = torch.from_numpy(dcp[i].transmittance).float().to(dm.device)
            prior.airlight = torch.from_numpy(dcp[i].airlight).float().to(dm.device)
        cam = dm.camera(i)
        H, W = int(cam.height[0]), int(cam.width[0])
        d = valid = None
        if source == "files" and dm.scene.depth_paths[i] is not None:
            d, valid = depth_from_file(dm.scene.depth_paths[i], H, W)
        elif source == "dcp":
            d, valid = depth_from_dcp(dm.image(i).cpu().numpy(), result=dcp.get(i))
        elif source == "sfm" and points is not None and len(points) > 0:
            cpu = cam.to("cpu")
            d, valid = sfm_view_depth(points.float().cpu(), tracks, i, cpu, H, W, union=union)
            prior.depth_metric = True
        elif source == "warmup" and warmup_depths is not None:
            d = warmup_depths[i]
            valid = torch.isfinite(d) & (d > 0)
        if d is not None:
            prior.depth = torch.as_tensor(d).float().to(dm.device)
            prior.depth_valid = torch.as_tensor(valid).bool().to(dm.device)
        out[i] = prior
    return out


def sfm_view_depth(
    points: Tensor,
    tracks: PointTracks | None,
    view: int,
    cam: Cameras,
    height: int,
    width: int,
    union: bool = False,
) -> tuple[Tensor, Tensor]:
    """The sparse SfM depth of one view (``points`` [M, 3] on the CPU, ``cam`` [1]). With tracks,
    only the points observed in this view, and no occlusion guess: every point reprojected into
    every view lets hidden surfaces show through gaps in a sparse foreground (14-17 % of the
    projections on generated courtyards and fields), and the guess that drops them also drops far
    ground just above nearer ground in the image (docs/results/medium_recovery.md, session 43).
    ``union``: those pixels, and where no tracked point lands, the untracked points reprojected
    with the guess; real tracks miss views that do see a point (beer: median 4 of 71), and the
    tracked points alone then cover half the pixels (session 44)."""
    vm, K = cam.viewmats()[0].float(), cam.Ks()[0].float()
    if tracks is None:
        return depth_from_sfm(points, vm, K, height, width)
    seen = torch.zeros(len(points), dtype=torch.bool)
    seen[torch.from_numpy(tracks.points_in(view))] = True  # [M]
    depth, valid = depth_from_sfm(points[seen], vm, K, height, width, occlusion_window=0)  # [H, W]
    if union and not seen.all():
        rest, rest_valid = depth_from_sfm(points[~seen], vm, K, height, width)  # [H, W]
        depth, valid = torch.where(valid, depth, rest), valid | rest_valid
    return depth, valid


def resolve_depth_prior(source: str, dm: DataManager) -> str:
    """``auto``: the dataset's depth files when every training view has one; else the SfM points
    when the scene has any (free, and the most accurate of our priors on generated scenes); else
    a haze-agnostic warm-up (docs/medium.md)."""
    if source != "auto":
        return source
    if all(dm.scene.depth_paths[i] is not None for i in dm.train_indices):
        return "files"
    if dm.scene.points is not None and len(dm.scene.points) > 0:
        return "sfm"
    return "warmup"


def scaled_step(step: int | None, fraction: float, max_steps: int) -> int:
    """An explicit step, or ``fraction`` of the run (the paper's 3000 of 15000 is 0.2)."""
    return int(step) if step is not None else int(math.floor(fraction * max_steps + 0.5))
