"""Analytic primitives and a vectorised nearest-hit ray tracer with per-primitive culling.

World convention: metres, z up. Primitives are few and simple (infinite planes, axis-aligned
boxes, spheres, vertical capped cylinders), so every intersection is closed-form. Each primitive
is intersected only with the rays that can reach it: for camera rays the pixels inside its
projected bounding box (a rectangle of the image), for shadow rays (all parallel to the sun) the
rays inside its bounding box seen along the sun. That keeps the cost near "each pixel meets a few
primitives" instead of "each pixel meets every primitive", without an acceleration structure.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

EPS = 1e-4
"""Smallest accepted hit distance (m): avoids self-hits of rays leaving a surface."""
NEAR = 1e-3
"""Near plane (m) used when clipping bounding boxes against a camera."""


@dataclass(frozen=True)
class Material:
    """Procedural surface appearance (see :mod:`components.synth.textures`)."""

    texture: str
    """checker | bricks | tiles | noise | stripes | plain."""
    color_a: tuple[float, float, float]
    color_b: tuple[float, float, float]
    scale: float = 1.0
    """Pattern period in metres (bricks: brick length)."""
    seed: int = 0


def _inf(like: Tensor) -> Tensor:
    return torch.full_like(like, torch.inf)


def _safe(d: Tensor) -> Tensor:
    """Values away from zero (keeps divisions finite, sign preserved)."""
    return torch.where(d.abs() < 1e-12, torch.full_like(d, 1e-12), d)


def _first_ahead(t_near: Tensor, t_far: Tensor, ok: Tensor) -> Tensor:
    """Entry distance, or the exit distance when the origin is inside; inf when neither is ahead."""
    t = torch.where(t_near > EPS, t_near, t_far)
    return torch.where(ok & (t > EPS), t, _inf(t))


@dataclass(frozen=True)
class Plane:
    """Infinite plane ``normal . x = offset``."""

    normal: tuple[float, float, float]
    offset: float
    material: int

    def bounds(self) -> None:
        return None  # unbounded: tested against every ray

    def intersect(self, o: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:  # -> t [M], normal [M, 3]
        n = torch.tensor(self.normal, dtype=o.dtype)
        denom = d @ n
        t = (self.offset - o @ n) / _safe(denom)
        t = torch.where((t > EPS) & (denom.abs() > 1e-9), t, _inf(t))
        return t, n.expand_as(o)


@dataclass(frozen=True)
class Box:
    """Axis-aligned box."""

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    material: int

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.lo), np.asarray(self.hi)

    def intersect(self, o: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:
        inv = 1.0 / _safe(d)  # [M, 3]
        t1 = (torch.tensor(self.lo, dtype=o.dtype) - o) * inv
        t2 = (torch.tensor(self.hi, dtype=o.dtype) - o) * inv
        t_near, ax_near = torch.minimum(t1, t2).max(dim=-1)  # [M]
        t_far, ax_far = torch.maximum(t1, t2).min(dim=-1)
        t = _first_ahead(t_near, t_far, t_far >= t_near)
        axis = torch.where(t_near > EPS, ax_near, ax_far)
        return t, torch.nn.functional.one_hot(axis, 3).to(o.dtype)


@dataclass(frozen=True)
class Sphere:
    center: tuple[float, float, float]
    radius: float
    material: int

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        c = np.asarray(self.center)
        return c - self.radius, c + self.radius

    def intersect(self, o: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:
        oc = o - torch.tensor(self.center, dtype=o.dtype)  # [M, 3]
        b = (oc * d).sum(-1)
        disc = b * b - ((oc * oc).sum(-1) - self.radius**2)
        root = disc.clamp_min(0).sqrt()
        t = _first_ahead(-b - root, -b + root, disc >= 0)
        p = oc + t.clamp_max(1e9)[:, None] * d
        return t, p / self.radius


@dataclass(frozen=True)
class Cylinder:
    """Vertical cylinder with flat caps from ``z0`` to ``z1``."""

    center: tuple[float, float]
    radius: float
    z0: float
    z1: float
    material: int

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        cx, cy = self.center
        r = self.radius
        return np.array([cx - r, cy - r, self.z0]), np.array([cx + r, cy + r, self.z1])

    def intersect(self, o: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:
        ox, oy, oz = o[:, 0] - self.center[0], o[:, 1] - self.center[1], o[:, 2]
        dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
        r2 = self.radius**2
        a = (dx * dx + dy * dy).clamp_min(1e-12)
        b = ox * dx + oy * dy
        disc = b * b - a * (ox * ox + oy * oy - r2)
        root = disc.clamp_min(0).sqrt()
        side = _inf(ox)
        for t_s in ((-b - root) / a, (-b + root) / a):
            z = oz + t_s * dz
            ok = (disc >= 0) & (t_s > EPS) & (z >= self.z0) & (z <= self.z1)
            side = torch.minimum(side, torch.where(ok, t_s, _inf(t_s)))
        cap = _inf(ox)
        for zc in (self.z0, self.z1):
            t_c = (zc - oz) / _safe(dz)
            px, py = ox + t_c * dx, oy + t_c * dy
            ok = (t_c > EPS) & (px * px + py * py <= r2)
            cap = torch.minimum(cap, torch.where(ok, t_c, _inf(t_c)))
        on_cap = cap < side
        t = torch.minimum(side, cap)
        tc = t.clamp_max(1e9)
        n_side = torch.stack(
            [(ox + tc * dx) / self.radius, (oy + tc * dy) / self.radius, torch.zeros_like(ox)], -1
        )
        n_cap = torch.tensor([0.0, 0.0, 1.0], dtype=o.dtype).expand_as(n_side)
        return t, torch.where(on_cap[:, None], n_cap, n_side)


Primitive = Plane | Box | Sphere | Cylinder


@dataclass
class SceneGeometry:
    """Everything a ray can hit, plus the materials the primitives index into."""

    materials: list[Material]
    planes: list[Plane] = field(default_factory=list)
    boxes: list[Box] = field(default_factory=list)
    spheres: list[Sphere] = field(default_factory=list)
    cylinders: list[Cylinder] = field(default_factory=list)

    def primitives(self) -> list[Primitive]:
        return [*self.planes, *self.boxes, *self.spheres, *self.cylinders]


@dataclass
class Hit:
    """Nearest intersection per ray; ``t = inf`` and ``material = -1`` where nothing was hit."""

    t: Tensor  # [...] distance along the (unit) ray
    normal: Tensor  # [..., 3] unit, facing the ray origin
    material: Tensor  # [...] int64

    @property
    def mask(self) -> Tensor:  # [...] bool
        return torch.isfinite(self.t)

    @staticmethod
    def empty(shape: tuple[int, ...]) -> Hit:
        return Hit(
            torch.full(shape, torch.inf), torch.zeros(*shape, 3), torch.full(shape, -1, dtype=torch.int64)
        )

    def flatten(self) -> Hit:
        return Hit(self.t.reshape(-1), self.normal.reshape(-1, 3), self.material.reshape(-1))


def _keep_closer(hit: Hit, sel, t: Tensor, n: Tensor, material: int) -> None:
    """Where ``t`` beats the current hit at index ``sel`` (a slice tuple or index tensor), take it."""
    closer = t < hit.t[sel]
    if not bool(closer.any()):
        return
    hit.t[sel] = torch.where(closer, t, hit.t[sel])
    hit.normal[sel] = torch.where(closer[..., None], n, hit.normal[sel])
    hit.material[sel] = torch.where(closer, torch.full_like(hit.material[sel], material), hit.material[sel])


def _face_viewer(hit: Hit, d: Tensor) -> Hit:
    """Flip normals seen from behind (planes from below, boxes from inside) towards the ray origin."""
    back = (hit.normal * d).sum(-1) > 0
    hit.normal = torch.where(back[..., None], -hit.normal, hit.normal)
    return hit


def trace(geo: SceneGeometry, o: Tensor, d: Tensor) -> Hit:
    """Nearest hit of arbitrary rays ``o + t d`` (``d`` unit) [R, 3], testing every primitive."""
    hit = Hit.empty((o.shape[0],))
    every = slice(None)
    for prim in geo.primitives():
        t, n = prim.intersect(o, d)
        _keep_closer(hit, every, t, n, prim.material)
    return _face_viewer(hit, d)


# --------------------------------------------------------------------------------------
# camera rays: each primitive only meets the pixels of its projected bounding box

_CORNERS = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)], dtype=np.float64)  # [8, 3]
_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]  # 12


def box_to_rect(
    lo: np.ndarray,
    hi: np.ndarray,
    w2c: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    W: int,
    H: int,
) -> tuple[int, int, int, int] | None:
    """Pixel rectangle (x0, y0, x1, y1), end-exclusive, that contains the box's projection; None if unseen.

    The box is clipped against the near plane (corners in front plus edge crossings), so boxes that
    reach behind the camera still get a tight, conservative rectangle.
    """
    pts = (lo + _CORNERS * (hi - lo)) @ w2c[:3, :3].T + w2c[:3, 3]  # [8, 3] camera space
    z = pts[:, 2]
    keep = [pts[z >= NEAR]]
    for a, b in _EDGES:
        if (z[a] - NEAR) * (z[b] - NEAR) < 0:
            s = (NEAR - z[a]) / (z[b] - z[a])
            keep.append((pts[a] + s * (pts[b] - pts[a]))[None])
    vis = np.concatenate(keep)
    if len(vis) == 0:
        return None
    u = fx * vis[:, 0] / vis[:, 2] + cx
    v = fy * vis[:, 1] / vis[:, 2] + cy
    x0, x1 = max(int(np.floor(u.min())) - 1, 0), min(int(np.ceil(u.max())) + 1, W)
    y0, y1 = max(int(np.floor(v.min())) - 1, 0), min(int(np.ceil(v.max())) + 1, H)
    if x0 >= x1 or y0 >= y1:
        return None
    return x0, y0, x1, y1


def trace_grid(
    geo: SceneGeometry, o: Tensor, d: Tensor, c2w: np.ndarray, fx: float, fy: float, cx: float, cy: float
) -> Hit:
    """Nearest hit of a pinhole camera's ray grid ``d`` [H, W, 3] from the single origin ``o`` [3].

    ``fx, fy, cx, cy`` describe the grid itself (for a super-sampled grid, the scaled intrinsics).
    """
    H, W = d.shape[:2]
    hit = Hit.empty((H, W))
    w2c = np.linalg.inv(c2w)
    for prim in geo.primitives():
        b = prim.bounds()
        rect = (0, 0, W, H) if b is None else box_to_rect(b[0], b[1], w2c, fx, fy, cx, cy, W, H)
        if rect is None:
            continue
        x0, y0, x1, y1 = rect
        dd = d[y0:y1, x0:x1].reshape(-1, 3)
        t, n = prim.intersect(o.expand_as(dd), dd)
        sel = (slice(y0, y1), slice(x0, x1))
        _keep_closer(hit, sel, t.reshape(y1 - y0, x1 - x0), n.reshape(y1 - y0, x1 - x0, 3), prim.material)
    return _face_viewer(hit, d)


# --------------------------------------------------------------------------------------
# shadow rays: all parallel, so cull in the plane across the light direction


def occluded(geo: SceneGeometry, o: Tensor, light: tuple[float, float, float]) -> Tensor:
    """[R] bool: whether anything lies along ``o + t * light`` for t > EPS (hard shadows)."""
    L = np.asarray(light, np.float64)
    a = np.cross(L, [0.0, 0.0, 1.0] if abs(L[2]) < 0.9 else [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(L, a)
    basis = torch.tensor(np.stack([a, b, L], 1), dtype=o.dtype)  # [3, 3] columns: across, across, along
    q = o @ basis  # [R, 3] ray origins in the light frame
    d = torch.tensor(L, dtype=o.dtype).expand_as(o)
    blocked = torch.zeros(o.shape[0], dtype=torch.bool)
    for prim in geo.primitives():
        bnd = prim.bounds()
        if bnd is None:
            cand = torch.arange(o.shape[0])
        else:
            pb = (bnd[0] + _CORNERS * (bnd[1] - bnd[0])) @ basis.double().numpy()  # [8, 3]
            lo, hi = pb.min(0).tolist(), pb.max(0).tolist()
            inside = (
                (q[:, 0] >= lo[0])
                & (q[:, 0] <= hi[0])
                & (q[:, 1] >= lo[1])
                & (q[:, 1] <= hi[1])
                & (q[:, 2] <= hi[2])
            )
            inside &= ~blocked
            cand = inside.nonzero().squeeze(1)
        if len(cand) == 0:
            continue
        t, _ = prim.intersect(o[cand], d[cand])
        blocked[cand] |= torch.isfinite(t)
    return blocked
