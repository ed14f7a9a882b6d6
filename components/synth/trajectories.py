"""Camera paths: a forward-facing walk or an orbit, as OpenCV camera-to-world poses (z up world)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from components.data.cameras import ViewIntrinsics


@dataclass(frozen=True)
class WalkPath:
    """Walk along a straight line, looking ahead, with a little sway, bob and yaw like a hand-held capture."""

    start: tuple[float, float, float]
    end: tuple[float, float, float]
    sway: float = 0.4
    """Lateral amplitude (m)."""
    yaw_deg: float = 12.0
    """Amplitude of the heading oscillation."""
    pitch_deg: float = -4.0
    """Constant downward tilt (negative looks down)."""


@dataclass(frozen=True)
class OrbitPath:
    """Circle around a target, always looking at it."""

    target: tuple[float, float, float]
    radius: float
    height: float
    """Camera height (m, world z)."""
    arc_deg: float = 360.0
    height_jitter: float = 0.3
    """Height varies sinusoidally by this much (m), so views are not coplanar."""


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV camera-to-world [4, 4] (x right, y down, z forward) at ``eye`` looking at ``target``."""
    z = np.asarray(target, np.float64) - np.asarray(eye, np.float64)
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, np.float64))
    if np.linalg.norm(x) < 1e-9:  # looking straight up or down
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, eye
    return c2w


def walk_poses(path: WalkPath, n: int) -> list[np.ndarray]:
    start, end = np.asarray(path.start, np.float64), np.asarray(path.end, np.float64)
    fwd = end - start
    fwd /= np.linalg.norm(fwd)
    side = np.cross(fwd, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    poses = []
    for i in range(n):
        s = i / max(n - 1, 1)
        phase = 2 * math.pi * 1.5 * s
        eye = start + s * (end - start) + path.sway * math.sin(phase) * side
        eye[2] += 0.05 * math.sin(4 * phase)  # footsteps
        yaw = math.radians(path.yaw_deg) * math.sin(phase + 0.7)
        pitch = math.radians(path.pitch_deg)
        look = math.cos(yaw) * fwd + math.sin(yaw) * side
        look = math.cos(pitch) * look + math.sin(pitch) * np.array([0.0, 0.0, 1.0])
        poses.append(look_at(eye, eye + look))
    return poses


def orbit_poses(path: OrbitPath, n: int) -> list[np.ndarray]:
    target = np.asarray(path.target, np.float64)
    full = abs(path.arc_deg - 360.0) < 1e-6
    poses = []
    for i in range(n):
        s = i / n if full else i / max(n - 1, 1)
        a = math.radians(path.arc_deg) * s
        eye = np.array(
            [
                target[0] + path.radius * math.cos(a),
                target[1] + path.radius * math.sin(a),
                path.height + path.height_jitter * math.sin(3 * a),
            ]
        )
        poses.append(look_at(eye, target))
    return poses


def camera_rays(c2w: np.ndarray, K: ViewIntrinsics) -> tuple[Tensor, Tensor, Tensor]:
    """Rays through the pixel centres of ``K``: origin [3], unit world directions [H, W, 3] and each
    direction's camera-z component [H, W] (z-depth = distance * dz)."""
    ys = torch.arange(K.height, dtype=torch.float32)[:, None] + 0.5
    xs = torch.arange(K.width, dtype=torch.float32)[None, :] + 0.5
    ys, xs = torch.broadcast_tensors(ys, xs)  # [H, W]
    cam = torch.stack([(xs - K.cx) / K.fx, (ys - K.cy) / K.fy, torch.ones_like(xs)], dim=-1)  # [H, W, 3]
    norm = cam.norm(dim=-1)
    R = torch.from_numpy(c2w[:3, :3]).float()
    d = (cam / norm[..., None]) @ R.T
    d = d / d.norm(dim=-1, keepdim=True)
    return torch.from_numpy(c2w[:3, 3]).float(), d, 1.0 / norm


def supersampled(K: ViewIntrinsics, ss: int) -> ViewIntrinsics:
    """The camera whose pixel grid puts ``ss x ss`` evenly spaced samples inside each pixel of ``K``."""
    return ViewIntrinsics(
        fx=K.fx * ss, fy=K.fy * ss, cx=K.cx * ss, cy=K.cy * ss, width=K.width * ss, height=K.height * ss
    )
