"""The data-parser interface and helpers shared by the built-in parsers.

A parser turns one on-disk format into a :class:`~components.data.scene.ParsedScene` and does
nothing else: validation, undistortion, downscaling, normalisation and splitting happen once,
for every format, in :mod:`components.data.loader`.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from components.data.cameras import ViewIntrinsics, opengl_to_opencv
from components.data.config import DataConfig
from components.data.images import image_size
from components.data.scene import ParsedScene
from tridehaze_plugin.errors import DataError, shown


class DataParser:
    """Base class: subclasses set ``name`` and implement ``can_parse`` and ``parse``.

    Both are classmethods so the registry can hold the class itself and the loader never has
    to construct one (parsers are stateless).
    """

    name: ClassVar[str] = ""
    looks_for: ClassVar[str] = ""
    """What ``can_parse`` checks, shown when auto-detection finds nothing."""

    @classmethod
    def can_parse(cls, root: Path) -> bool:
        raise NotImplementedError

    @classmethod
    def parse(cls, root: Path, cfg: DataConfig) -> ParsedScene:
        raise NotImplementedError


# --------------------------------------------------------------------------------------
# paths and json


def load_json(path: Path) -> dict[str, Any]:
    """A JSON object from ``path``; DataError (with line/column) when it is not valid JSON."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DataError("file not found", where=str(path)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"cannot read file ({exc})", where=str(path)) from None
    try:
        meta = json.loads(text)
    except RecursionError:
        raise DataError("JSON nested too deeply to be a dataset file", where=str(path)) from None
    except json.JSONDecodeError as exc:
        raise DataError(
            f"invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}",
            where=str(path),
            fix="fix the syntax (a JSON validator shows the exact spot)",
        ) from None
    if not isinstance(meta, dict):
        raise DataError("expected a JSON object at the top level", where=str(path))
    return meta


def resolve(base: Path, p: str) -> Path:
    """``p`` as written in a dataset file (relative to ``base`` unless absolute)."""
    q = Path(os.path.expanduser(str(p)))
    return q if q.is_absolute() else base / q


def rel_name(path: Path, root: Path) -> str:
    """``path`` relative to ``root`` in POSIX form (the frame's name); the file name if outside."""
    try:
        return Path(os.path.normpath(path)).relative_to(os.path.normpath(root)).as_posix()
    except ValueError:
        return path.name


def find_with_suffix(path: Path, suffixes: tuple[str, ...] = (".png", ".jpg", ".jpeg")) -> Path:
    """``path`` itself if it exists or has a suffix, else the first of ``path + suffix`` that exists.

    Blender-style files often omit the extension (``./train/r_0``). When nothing exists the
    first candidate is returned so that the "missing image" error names a plausible file.
    """
    if path.exists():
        return path
    candidates = [path.with_name(path.name + s) for s in suffixes]
    candidates += [path.with_name(path.name + s.upper()) for s in suffixes]
    for c in candidates:
        if c.exists():
            return c
    return (
        path
        if path.suffix.lower() in (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
        else candidates[0]
    )


# --------------------------------------------------------------------------------------
# transforms.json-style cameras (nerfstudio, Blender, RealX3D)


def c2w_from_opengl(matrix: Any, where: str) -> np.ndarray:
    """A ``transform_matrix`` (OpenGL camera-to-world, 3x4 or 4x4) -> OpenCV c2w [4, 4] float64."""
    try:
        m = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        m = np.zeros(0)
    if m.shape not in ((4, 4), (3, 4)):
        raise DataError(
            f"transform_matrix must be a 4x4 (or 3x4) list of numbers, got shape {m.shape}",
            where=where,
            fix="write the camera-to-world matrix as 4 rows of 4 numbers",
        )
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    return opengl_to_opencv(torch.from_numpy(m)).numpy()


SUPPORTED_JSON_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV")


def json_intrinsics(meta: dict[str, Any], image_path: Path, where: str) -> dict[str, Any]:
    """Intrinsics from merged global + per-frame keys (``fl_x fl_y cx cy w h``, ``camera_angle_x``,
    ``k1 k2 k3 k4 p1 p2``, ``camera_model``) as :class:`Frame` keyword arguments: ``intrinsics``
    (a :class:`ViewIntrinsics`), ``camera_model`` and ``distortion``.

    Width and height missing from the file are read from the image header; when the image does not
    exist they are left 0, and the loader reports the missing image (or drops it) before it looks
    at intrinsics.
    """
    model = str(meta.get("camera_model", "OPENCV")).upper()
    if model not in SUPPORTED_JSON_MODELS:
        raise DataError(
            f"camera_model {shown(model)} is not supported",
            where=where,
            fix=f"use one of {', '.join(SUPPORTED_JSON_MODELS)} (undistort fisheye/equirectangular images first)",
        )
    w, h = _num(meta, "w", where), _num(meta, "h", where)
    if (w is None or h is None) and image_path.is_file():
        iw, ih = image_size(image_path)
        w = iw if w is None else w
        h = ih if h is None else h
    w, h = w or 0.0, h or 0.0
    fx, fy = _num(meta, "fl_x", where), _num(meta, "fl_y", where)
    ax, ay = _num(meta, "camera_angle_x", where), _num(meta, "camera_angle_y", where)
    if fx is None and ax is not None:
        fx = 0.5 * w / math.tan(0.5 * ax) if ax else 0.0
    if fy is None and ay is not None:
        fy = 0.5 * h / math.tan(0.5 * ay) if ay else 0.0
    if fx is None and fy is None:
        raise DataError(
            "no focal length: neither fl_x/fl_y nor camera_angle_x is given",
            where=where,
            fix="add fl_x (pixels) or camera_angle_x (radians)",
        )
    fx = fy if fx is None else fx
    fy = fx if fy is None else fy
    cx, cy = _num(meta, "cx", where), _num(meta, "cy", where)
    k = {key: _num(meta, key, where) or 0.0 for key in ("k1", "k2", "k3", "k4", "p1", "p2")}
    if k["k4"] != 0.0:
        raise DataError(
            "k4 (an r^8 radial term) is not supported for perspective cameras",
            where=where,
            fix="undistort the images first or refit with k1, k2, k3, p1, p2",
        )
    dist = (k["k1"], k["k2"], k["p1"], k["p2"], k["k3"])
    has_dist = any(d != 0.0 for d in dist)
    intrinsics = ViewIntrinsics(
        fx=float(fx),
        fy=float(fy),
        cx=float(w / 2.0 if cx is None else cx),
        cy=float(h / 2.0 if cy is None else cy),
        width=int(round(w)),
        height=int(round(h)),
    )
    return {
        "intrinsics": intrinsics,
        "camera_model": "OPENCV" if has_dist else "PINHOLE",
        "distortion": dist if has_dist else (),
    }


def _num(meta: dict[str, Any], key: str, where: str) -> float | None:
    v = meta.get(key)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise DataError(f"{key} must be a number, got {shown(v)}", where=where)
    return float(v)
