"""Seed Gaussians on the ground beyond the seed cloud, for the far terrain of open scenes.

Structure from motion finds few points on ground too far for parallax or too deep in the haze, so
no Gaussian starts there, and the optimiser covers those pixels with what is nearest: on the
generated fields the terrain seen at true T 0.05-0.4 (true depth 7-22 scene units) is rendered at
0.3-0.5 of its depth. Where a training ray below the horizon sees no seed point, it is followed to
the ground plane (a low quantile of the seed points' height along the cameras' up) and a seed is
put where it meets it, beyond the view's farthest seed points. Only for open ground: behind a
wall the plane runs on, and a seed cast through the wall's pixels starts the wall at a second
depth (docs/results/medium_recovery.md, session 42).
"""

from __future__ import annotations

import torch
from torch import Tensor

from components.data.cameras import Cameras
from components.losses.depth_priors import in_image, project_points
from components.medium.compositing import pixel_rays
from pipelines.engine.datamanager import DataManager
from pipelines.tridehaze.priors import visible_points

GROUND_QUANTILE = 0.02
"""The ground's height: this quantile of the seed points' heights along the up direction."""
FAR_QUANTILE = 0.98
"""A ground seed must lie beyond this quantile of the distances of the seed points inside its
view's image (occluded or not)."""
MAX_REACH = 8.0
"""... and within this many times that distance (rays grazing the horizon meet the plane far away)."""
LOCATED_RADIUS = 4
"""Pixels within this many pixels of a seen seed point are left to the seed cloud."""


def ground_seeds(
    dm: DataManager, points: Tensor, up: Tensor, count: int, seed: int = 0
) -> tuple[Tensor, Tensor]:
    """Points [M, 3] on the ground plane along the training rays no seed point ``points`` [N, 3]
    vouches for, at most ``count`` over all views, and their colours [M, 3] in [0, 1] (the hazy
    pixel they were cast from). M = 0 where no view sees unlocated ground."""
    pts = points.detach().float().cpu()
    up = up.detach().float().cpu()
    up = up / up.norm().clamp_min(1e-12)
    ground = float(torch.quantile(pts @ up, GROUND_QUANTILE))
    views = list(dm.train_indices)
    per_view = max(1, count // max(len(views), 1))
    gen = torch.Generator().manual_seed(seed)
    out_pts, out_cols = [], []
    for i in views:
        cam = dm.camera(i).to("cpu")
        p, rows, cols = _view_ground(cam, pts, up, ground)
        if len(p) == 0:
            continue
        pick = torch.randperm(len(p), generator=gen)[:per_view]
        out_pts.append(p[pick])
        out_cols.append(dm.image(i).detach().float().cpu()[rows[pick], cols[pick], :3])
    if not out_pts:
        return torch.zeros(0, 3), torch.zeros(0, 3)
    return torch.cat(out_pts)[:count], torch.cat(out_cols)[:count]  # fewer than one per view


def _view_ground(cam: Cameras, pts: Tensor, up: Tensor, ground: float) -> tuple[Tensor, Tensor, Tensor]:
    """One view's candidate ground points [K, 3] and the pixel rows and columns [K] they come from."""
    H, W = int(cam.height[0]), int(cam.width[0])
    pc, uv = project_points(pts, cam.viewmats()[0].float(), cam.Ks()[0].float())  # [N, 3], [N, 2]
    inside = in_image(pc, uv, W, H, near=1e-3)
    if int(inside.sum()) < 10:
        return torch.zeros(0, 3), torch.zeros(0, dtype=torch.long), torch.zeros(0, dtype=torch.long)
    # the cloud's reach in this view: every point in the image, occluded or not (on ground seen
    # at a grazing angle the occlusion filter keeps only the nearest few)
    far = float(torch.quantile(pc[inside].norm(dim=-1), FAR_QUANTILE))
    vis = visible_points(cam, pts)
    located = torch.zeros(1, 1, H, W)
    located[0, 0, vis.v, vis.u] = 1.0
    k = 2 * LOCATED_RADIUS + 1
    located = torch.nn.functional.max_pool2d(located, k, stride=1, padding=LOCATED_RADIUS)[0, 0] > 0  # [H, W]
    dirs, origin = pixel_rays(cam, H, W, torch.device("cpu"), torch.float32)  # [H, W, 3], [3]
    dirs = dirs / dirs.norm(dim=-1, keepdim=True)
    down = dirs @ up  # [H, W] < 0 below the horizon
    t = (ground - float(origin @ up)) / down.clamp(max=-1e-6)  # [H, W] distance to the plane
    keep = (down < -1e-3) & (t > far) & (t < MAX_REACH * far) & ~located
    rows, cols = keep.nonzero(as_tuple=True)
    return origin + t[keep, None] * dirs[keep], rows, cols
