"""viser's browser camera <-> the framework's :class:`~components.data.cameras.Cameras`.

viser reports a client's camera as ``wxyz`` (the rotation R_world_camera as a unit quaternion),
``position`` (the camera centre in world coordinates) and a vertical field of view, all in OpenCV
camera axes (x right, y down, z forward), which is also this framework's convention: the pose
converts directly into ``camtoworlds`` without any axis flip. Intrinsics follow from the field of
view and the size we choose to render at (square pixels, principal point at the image centre).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from viser import transforms as vtf

from components.data.cameras import Cameras


def image_size(aspect: float, long_side: int) -> tuple[int, int]:
    """(width, height) with the given width/height ratio and longest side ``long_side`` (>= 1 each)."""
    aspect = aspect if math.isfinite(aspect) and aspect > 0 else 1.0
    if aspect >= 1:
        return long_side, max(1, round(long_side / aspect))
    return max(1, round(long_side * aspect)), long_side


def viser_to_camera(wxyz: np.ndarray, position: np.ndarray, fov_y: float, width: int, height: int) -> Cameras:
    """One camera ([1]) looking from a viser pose with vertical field of view ``fov_y`` (radians)."""
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:3, :3] = torch.from_numpy(vtf.SO3(np.asarray(wxyz, dtype=np.float64)).as_matrix())
    c2w[:3, 3] = torch.as_tensor(np.asarray(position, dtype=np.float64))
    f = height / 2.0 / math.tan(fov_y / 2.0)
    return Cameras(
        camtoworlds=c2w[None].float(),  # [1, 4, 4]
        fx=torch.tensor([f]),
        fy=torch.tensor([f]),
        cx=torch.tensor([width / 2.0]),
        cy=torch.tensor([height / 2.0]),
        width=torch.tensor([width]),
        height=torch.tensor([height]),
    )


def camera_to_viser(cameras: Cameras, idx: int) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(wxyz [4], position [3], vertical fov in radians, aspect width/height) of camera ``idx``."""
    c2w = cameras.camtoworlds[idx].detach().double().cpu().numpy()  # [4, 4]
    # project onto SO(3) first: float32 poses are only orthonormal to ~1e-7
    u, _, vt = np.linalg.svd(c2w[:3, :3])
    rot = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    wxyz = vtf.SO3.from_matrix(rot).wxyz
    height, width = float(cameras.height[idx]), float(cameras.width[idx])
    fov_y = 2.0 * math.atan(height / 2.0 / float(cameras.fy[idx]))
    return wxyz, c2w[:3, 3].copy(), fov_y, width / height


def up_direction(cameras: Cameras) -> np.ndarray:
    """World up [3] as the cameras see it: the mean of their -y axes (image up), normalised."""
    up = -cameras.camtoworlds[:, :3, 1].double().mean(0).cpu().numpy()
    norm = np.linalg.norm(up)
    return up / norm if norm > 1e-9 else np.array([0.0, 0.0, 1.0])
