"""Tiny synthetic datasets for the data-layer tests (written into tmp_path)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

GL_CV = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV <-> OpenGL camera axes (self-inverse)


def look_at(eye, target, world_up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV camera-to-world [4, 4] at ``eye`` looking at ``target`` (x right, y down, z forward)."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, world_up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, eye
    return c2w


def ring_poses(n: int, radius: float = 4.0, height: float = 1.0, center=(0.0, 0.0, 0.0)) -> list[np.ndarray]:
    """``n`` OpenCV c2w looking at ``center`` from a circle around it."""
    out = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = np.asarray(center) + [radius * np.cos(a), radius * np.sin(a), height]
        out.append(look_at(eye, center))
    return out


def project(c2w: np.ndarray, fx, fy, cx, cy, X) -> np.ndarray:
    """Pixel (u, v) of world point X [3] seen by an OpenCV camera."""
    R, t = c2w[:3, :3], c2w[:3, 3]
    p = R.T @ (np.asarray(X, dtype=np.float64) - t)
    return np.array([fx * p[0] / p[2] + cx, fy * p[1] / p[2] + cy])


def make_image(w: int, h: int, seed: int = 0) -> np.ndarray:
    """Smooth-ish RGB uint8 [H, W, 3] (gradients + a seed-dependent offset)."""
    yy, xx = np.mgrid[0:h, 0:w]
    img = np.stack(
        [xx * 255 // max(w - 1, 1), yy * 255 // max(h - 1, 1), (xx + yy + seed * 37) % 256], axis=-1
    )
    return img.astype(np.uint8)


def write_rgb(path: Path, img: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), img[:, :, ::-1].copy())
    return path


def write_nerfstudio(
    root: Path,
    n: int = 6,
    w: int = 40,
    h: int = 30,
    f: float = 35.0,
    *,
    clean: bool = False,
    extra_global: dict | None = None,
    frame_extra=None,
) -> list[np.ndarray]:
    """A nerfstudio transforms.json with global intrinsics; returns the OpenCV c2w of each frame."""
    poses = ring_poses(n)
    frames = []
    for i, c2w in enumerate(poses):
        write_rgb(root / "images" / f"frame_{i:03d}.png", make_image(w, h, i))
        fr = {"file_path": f"images/frame_{i:03d}.png", "transform_matrix": (c2w @ GL_CV).tolist()}
        if clean:
            write_rgb(root / "clean" / f"frame_{i:03d}.png", make_image(w, h, i + 100))
            fr["clean_file_path"] = f"clean/frame_{i:03d}.png"
        if frame_extra:
            fr.update(frame_extra(i))
        frames.append(fr)
    meta = {"fl_x": f, "fl_y": f, "cx": w / 2, "cy": h / 2, "w": w, "h": h, "camera_model": "PINHOLE"}
    meta.update(extra_global or {})
    meta["frames"] = frames
    (root / "transforms.json").write_text(json.dumps(meta))
    return poses


def write_blender(root: Path, n_train: int = 4, n_test: int = 2, size: int = 32, angle: float = 0.69) -> None:
    poses = ring_poses(n_train + n_test)
    for split, idx in (("train", range(n_train)), ("test", range(n_train, n_train + n_test))):
        frames = []
        for k, i in enumerate(idx):
            img = np.dstack([make_image(size, size, i), np.full((size, size), 255, np.uint8)])  # RGBA
            cv2.imwrite(str(_mk(root / split / f"r_{k}.png")), img[:, :, [2, 1, 0, 3]].copy())
            frames.append({"file_path": f"./{split}/r_{k}", "transform_matrix": (poses[i] @ GL_CV).tolist()})
        (root / f"transforms_{split}.json").write_text(
            json.dumps({"camera_angle_x": angle, "frames": frames})
        )


def _mk(p: Path) -> Path:
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


def rot_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> unit quaternion (w, x, y, z), as COLMAP writes it."""
    w = np.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = np.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2
    y = np.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2
    z = np.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2
    x = np.copysign(x, R[2, 1] - R[1, 2])
    y = np.copysign(y, R[0, 2] - R[2, 0])
    z = np.copysign(z, R[1, 0] - R[0, 1])
    q = np.array([w, x, y, z])
    return q / np.linalg.norm(q)


def write_colmap(
    root: Path,
    n: int = 5,
    w: int = 40,
    h: int = 30,
    *,
    model: str = "PINHOLE",
    params: list[float] | None = None,
    points: np.ndarray | None = None,
    sparse: str = "sparse/0",
    write_images: bool = True,
) -> list[np.ndarray]:
    """A COLMAP text model (one camera per image, listed in reverse name order); returns OpenCV c2w."""
    params = params or [30.0, 31.0, w / 2, h / 2]
    poses = ring_poses(n)
    d = _mk(root / sparse / "x").parent
    cams, ims = ["# cameras"], ["# images"]
    for i in reversed(range(n)):  # COLMAP does not sort: the parser must
        cams.append(f"{i + 1} {model} {w} {h} " + " ".join(repr(float(p)) for p in params))
        R, t = poses[i][:3, :3].T, -poses[i][:3, :3].T @ poses[i][:3, 3]  # world-to-camera
        q = rot_to_quat(R)
        ims.append(
            f"{i + 1} {' '.join(map(repr, q.tolist()))} {' '.join(map(repr, t.tolist()))} {i + 1} {i:04d}.png"
        )
        ims.append("")
        if write_images:
            write_rgb(root / "images" / f"{i:04d}.png", make_image(w, h, i))
    if points is None:
        points = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1]])
    pts = [f"{k + 1} {x!r} {y!r} {z!r} 200 100 50 0.5" for k, (x, y, z) in enumerate(points.tolist())]
    (d / "cameras.txt").write_text("\n".join(cams) + "\n")
    (d / "images.txt").write_text("\n".join(ims) + "\n")
    (d / "points3D.txt").write_text("\n".join(["# points"] + pts) + "\n")
    return poses
