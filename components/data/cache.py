"""On-disk cache of undistorted / downscaled copies, so the work is done once per dataset.

Copies live in ``<cache root>/data/<scene>-<hash of its path>/``; each file name carries a hash
of (absolute source path, file size, modification time, camera geometry, downscale, kind), so an
edited source file or a different setting gives a new copy, and an unchanged one is reused as is.
Files are written atomically (temporary file + ``os.replace``), so an interrupted or concurrent
run never leaves a half-written copy behind. The dataset folder itself is never written.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from components.data.geometry import Geometry, apply_geometry
from components.data.images import decode_raw, read_image, write_array_atomic, write_image_atomic
from tridehaze_plugin.errors import DataError

CACHE_ENV_VAR = "TRIDEHAZE_CACHE"
CACHE_VERSION = 1
"""Bump when the processing changes so stale copies are not reused."""


def cache_root(cache_dir: Path | None) -> Path:
    """``cache_dir``, else ``$TRIDEHAZE_CACHE``, else ``~/.cache/tridehaze``."""
    if cache_dir is not None:
        return Path(cache_dir).expanduser()
    env = os.environ.get(CACHE_ENV_VAR)
    return Path(env).expanduser() if env else Path.home() / ".cache" / "tridehaze"


def scene_cache_dir(root: Path, cache_dir: Path | None) -> Path:
    root = Path(root).resolve()
    tag = hashlib.sha1(str(root).encode("utf-8")).hexdigest()[:8]
    return cache_root(cache_dir) / "data" / f"{root.name}-{tag}"


def cached_path(src: Path, geom: Geometry, kind: str, name: str, out_dir: Path, suffix: str) -> Path:
    """Where the processed copy of ``src`` goes (depends on the file's identity and the geometry)."""
    src = Path(src).resolve()
    st = src.stat()
    key = {
        "v": CACHE_VERSION,
        "kind": kind,
        "src": str(src),
        "size": st.st_size,
        "mtime_ns": st.st_mtime_ns,
        "geometry": geom.key(),
    }
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode("utf-8")).hexdigest()[:16]
    stem = name.rsplit(".", 1)[0].replace("/", "__").replace("\\", "__")
    return out_dir / f"{stem}-{digest}{suffix}"


def prepare_image(src: Path, geom: Geometry, name: str, out_dir: Path) -> Path:
    """The path the trainer should read for colour image ``src`` (the original when nothing changes)."""
    if geom.is_identity:
        return Path(src)
    dst = cached_path(src, geom, "image", name, out_dir, ".png")
    if not dst.is_file():
        img = read_image(src)  # [H, W, 3] uint8 RGB (alpha composited onto white)
        _write(dst, lambda: write_image_atomic(dst, apply_geometry(img, geom)))
    return dst


def prepare_map(src: Path, geom: Geometry, name: str, out_dir: Path) -> Path:
    """Like :func:`prepare_image` for depth maps and other per-pixel maps (values kept, nearest resampling).

    ``.npy`` stays ``.npy``; image files keep their bit depth and channels and are written as PNG
    (TIFF stays TIFF), so a 16-bit depth PNG remains a 16-bit depth PNG.
    """
    if geom.is_identity:
        return Path(src)
    src = Path(src)
    suffix = src.suffix.lower()
    out_suffix = suffix if suffix in (".npy", ".png", ".tif", ".tiff") else ".png"
    dst = cached_path(src, geom, "map", name, out_dir, out_suffix)
    if not dst.is_file():
        arr = _read_map(src)
        _write(dst, lambda: write_array_atomic(dst, apply_geometry(arr, geom, nearest=True)))
    return dst


def _read_map(src: Path) -> np.ndarray:
    if src.suffix.lower() == ".npy":
        try:
            arr = np.squeeze(np.load(src, allow_pickle=False))
        except (ValueError, OSError, EOFError) as exc:
            raise DataError(
                f"not a valid .npy array ({exc})", where=str(src), fix="re-save it with numpy.save"
            ) from None
        if arr.ndim not in (2, 3):
            raise DataError(f"per-pixel map must be [H, W] or [H, W, C], got {arr.shape}", where=str(src))
        if arr.dtype == np.bool_:
            return arr.astype(np.uint8)  # masks: 0/1 survive nearest resampling exactly
        if arr.dtype not in (np.uint8, np.uint16, np.int16, np.float32, np.float64):
            return arr.astype(np.float32)  # dtypes OpenCV cannot resample
        return arr
    return decode_raw(src, "per-pixel map")


def _write(dst: Path, write) -> None:
    try:
        write()
    except OSError as exc:
        raise DataError(
            f"cannot write to the cache ({exc.strerror or exc})",
            where=str(dst.parent),
            fix="pass --cache-dir DIR (or set $TRIDEHAZE_CACHE) to a writable folder",
        ) from None
