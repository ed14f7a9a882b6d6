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

from components.data.geometry import Geometry, apply_geometry
from components.data.images import (
    check_map_fits,
    read_image,
    read_map,
    write_array_atomic,
    write_image_atomic,
)
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
        arr = read_map(src)
        check_map_fits(arr.shape, *geom.src_size, src)
        _write(dst, lambda: write_array_atomic(dst, apply_geometry(arr, geom, nearest=True)))
    return dst


def _write(dst: Path, write) -> None:
    try:
        write()
    except OSError as exc:
        raise DataError(
            f"cannot write to the cache ({exc.strerror or exc})",
            where=str(dst.parent),
            fix="pass --cache-dir DIR (or set $TRIDEHAZE_CACHE) to a writable folder",
        ) from None
