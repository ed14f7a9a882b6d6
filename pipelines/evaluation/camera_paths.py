"""Camera paths for videos of a trained scene: through the training cameras, or an orbit.

Both work on camera-to-world matrices in OpenCV axes (x right, y down, z forward), like
:class:`~components.data.cameras.Cameras`, and return ``[F, 4, 4]`` float64 arrays.

* :func:`interpolate_path`: the cameras are put in travel order (:func:`order_cameras`: a nearest-
  neighbour chain from an end of the capture), then positions follow a Catmull-Rom spline through
  the camera centres and orientations are SLERPed between consecutive cameras; frames are spaced
  evenly along the path (distance plus turning), so the speed does not jump between sparse and
  dense parts of the capture.
* :func:`orbit_path`: a circle around the scene centre (the point closest to all optical axes), at
  the cameras' mean distance and height, in the plane orthogonal to their mean up direction,
  starting at the first camera of the travel order, turning the way the capture goes, and always
  looking at the centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from components.data.cameras import Cameras, ViewIntrinsics, scene_up
from components.export.quaternions import matrix_to_quat, quat_to_matrix, slerp


@dataclass
class CameraPath:
    """F poses sharing one set of intrinsics (a video needs one frame size)."""

    camtoworlds: np.ndarray  # [F, 4, 4]
    intrinsics: ViewIntrinsics

    def __len__(self) -> int:
        return self.camtoworlds.shape[0]

    def camera(self, i: int, device: torch.device | str = "cpu") -> Cameras:  # [1]
        def one(v: float, dtype: torch.dtype = torch.float32) -> torch.Tensor:
            return torch.tensor([v], dtype=dtype, device=device)

        k = self.intrinsics
        return Cameras(
            camtoworlds=torch.from_numpy(self.camtoworlds[i : i + 1]).float().to(device),
            fx=one(k.fx),
            fy=one(k.fy),
            cx=one(k.cx),
            cy=one(k.cy),
            width=one(k.width, torch.int64),
            height=one(k.height, torch.int64),
        )

    def to_dict(self, fps: float) -> dict:
        k = self.intrinsics
        return {
            "convention": "camera-to-world, OpenCV axes (x right, y down, z forward), run's normalised world",
            "fps": fps,
            "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "w": k.width, "h": k.height},
            "camtoworlds": [m.tolist() for m in self.camtoworlds],
        }  # fmt: skip


# ------------------------------------------------------------------------------ rotations


def rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:  # noqa: N803
    """Angle (radians) of the rotation taking Ra to Rb."""
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return math.acos(float(np.clip(c, -1.0, 1.0)))


def look_at(position: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Camera-to-world [4, 4] (OpenCV axes) at ``position`` looking at ``target``, image up ~ ``up``."""
    z = target - position
    z = z / max(np.linalg.norm(z), 1e-12)
    x = np.cross(-up, z)  # y (down) x z (forward) = x (right)
    if np.linalg.norm(x) < 1e-9:  # looking straight along up: any perpendicular will do
        x = np.cross(np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, :3] = np.stack([x, y, z], axis=1)
    m[:3, 3] = position
    return m


# ------------------------------------------------------------------------------ scene geometry


def scene_focus(c2w: np.ndarray) -> np.ndarray:
    """The point closest (least squares) to every camera's optical axis; the centres' mean when
    the axes are (nearly) parallel, e.g. a forward-facing capture."""
    centers = c2w[:, :3, 3]
    dirs = c2w[:, :3, 2]  # [N, 3] forward axes
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c, d in zip(centers, dirs, strict=True):
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c
    if len(c2w) < 2 or np.linalg.cond(A) > 1e6:
        return centers.mean(axis=0)
    focus = np.linalg.solve(A, b)
    # a focus behind most cameras means the axes diverge: fall back to the centres' mean
    in_front = ((focus - centers) * dirs).sum(axis=1) > 0
    return focus if in_front.mean() >= 0.5 else centers.mean(axis=0)


def order_cameras(centers: np.ndarray) -> list[int]:
    """Travel order: a nearest-neighbour chain from one end of the capture, so an arc of photos is
    walked end to end. The ends tried: the camera farthest from the centroid, and the camera
    farthest from that one; the shorter chain wins."""
    n = len(centers)
    if n <= 2:
        return list(range(n))
    far = int(np.argmax(np.linalg.norm(centers - centers.mean(0), axis=1)))
    start = int(np.argmax(np.linalg.norm(centers - centers[far], axis=1)))
    # the two candidate ends: start the chain at the one whose chain is shorter
    best: list[int] = []
    best_len = math.inf
    for s in (start, far):
        order, left = [s], set(range(n)) - {s}
        length = 0.0
        while left:
            last = centers[order[-1]]
            nxt = min(left, key=lambda j: (float(np.linalg.norm(centers[j] - last)), j))
            length += float(np.linalg.norm(centers[nxt] - last))
            order.append(nxt)
            left.remove(nxt)
        if length < best_len - 1e-12:
            best, best_len = order, length
    return best


# ------------------------------------------------------------------------------ paths


def _catmull_rom(p0, p1, p2, p3, u: float) -> np.ndarray:
    """Uniform Catmull-Rom between p1 (u=0) and p2 (u=1)."""
    u2, u3 = u * u, u * u * u
    return 0.5 * (
        2 * p1 + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u2 + (-p0 + 3 * p1 - 3 * p2 + p3) * u3
    )


def interpolate_path(c2w: np.ndarray, num_frames: int, order: list[int] | None = None) -> np.ndarray:
    """[N, 4, 4] key cameras -> [F, 4, 4] smooth path through all of them (first to last)."""
    c2w = np.asarray(c2w, np.float64)
    if order is None:
        order = order_cameras(c2w[:, :3, 3])
    keys = c2w[order]
    n = len(keys)
    if n == 1 or num_frames == 1:
        return np.repeat(keys[:1], num_frames, axis=0)
    pos = keys[:, :3, 3]
    quats = [matrix_to_quat(k[:3, :3]) for k in keys]
    for i in range(1, n):  # keep consecutive quaternions on one hemisphere
        if np.dot(quats[i - 1], quats[i]) < 0:
            quats[i] = -quats[i]
    extent = max(float(np.linalg.norm(pos - pos.mean(0), axis=1).mean()), 1e-9)
    seg = np.array(
        [
            np.linalg.norm(pos[i + 1] - pos[i]) + 0.5 * extent * rotation_angle(keys[i, :3, :3], keys[i + 1, :3, :3])
            for i in range(n - 1)
        ]
    )  # fmt: skip
    seg = np.maximum(seg, 1e-9)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    out = np.zeros((num_frames, 4, 4))
    for f, s in enumerate(np.linspace(0.0, cum[-1], num_frames)):
        i = min(int(np.searchsorted(cum, s, side="right")) - 1, n - 2)
        u = float(np.clip((s - cum[i]) / seg[i], 0.0, 1.0))
        p = _catmull_rom(pos[max(i - 1, 0)], pos[i], pos[i + 1], pos[min(i + 2, n - 1)], u)
        out[f, :3, :3] = quat_to_matrix(slerp(quats[i], quats[i + 1], u))
        out[f, :3, 3] = p
        out[f, 3, 3] = 1.0
    return out


def orbit_path(c2w: np.ndarray, num_frames: int, center: np.ndarray | None = None) -> np.ndarray:
    """[N, 4, 4] cameras -> [F, 4, 4] one full circle around ``center`` (default: :func:`scene_focus`)."""
    c2w = np.asarray(c2w, np.float64)
    up = scene_up(c2w)
    center = scene_focus(c2w) if center is None else np.asarray(center, np.float64)
    rel = c2w[:, :3, 3] - center  # [N, 3]
    heights = rel @ up  # [N]
    horiz = rel - heights[:, None] * up  # [N, 3]
    radius = float(np.linalg.norm(horiz, axis=1).mean())
    height = float(heights.mean())
    if radius < 1e-9:  # cameras on the axis: orbit at their distance instead
        radius = max(float(np.linalg.norm(rel, axis=1).mean()), 1e-3)
    order = order_cameras(c2w[:, :3, 3])
    first = horiz[order[0]]  # start at the first camera of the travel order
    if np.linalg.norm(first) < 1e-9:
        first = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 = first / np.linalg.norm(first)
    e2 = np.cross(up, e1)
    # turn the way the capture goes (summed angular steps of the cameras, in travel order)
    ang = np.arctan2(horiz @ e2, horiz @ e1)
    steps = np.angle(np.exp(1j * np.diff(ang[order]))) if len(order) > 1 else np.zeros(1)
    sign = -1.0 if steps.sum() < 0 else 1.0
    out = np.zeros((num_frames, 4, 4))
    for f in range(num_frames):
        theta = sign * 2 * math.pi * f / num_frames
        p = center + height * up + radius * (math.cos(theta) * e1 + math.sin(theta) * e2)
        out[f] = look_at(p, center, up)
    return out


def reference_intrinsics(cams: Cameras, indices: list[int]) -> ViewIntrinsics:
    """The intrinsics of the view with the most common size among ``indices``."""
    sizes = [(int(cams.width[i]), int(cams.height[i])) for i in indices]
    common = max(set(sizes), key=lambda s: (sizes.count(s), s))
    i = indices[sizes.index(common)]
    return ViewIntrinsics(
        fx=float(cams.fx[i]),
        fy=float(cams.fy[i]),
        cx=float(cams.cx[i]),
        cy=float(cams.cy[i]),
        width=common[0],
        height=common[1],
    )


def make_path(kind: str, cams: Cameras, indices: list[int], num_frames: int) -> CameraPath:
    """The ``interpolate`` or ``orbit`` path for the views ``indices`` of ``cams``."""
    c2w = cams.camtoworlds[indices].detach().cpu().double().numpy()  # [N, 4, 4]
    if kind == "interpolate":
        poses = interpolate_path(c2w, num_frames)
    elif kind == "orbit":
        poses = orbit_path(c2w, num_frames)
    else:
        raise ValueError(f"unknown camera path {kind!r}; use interpolate or orbit")
    return CameraPath(poses, reference_intrinsics(cams, indices))
