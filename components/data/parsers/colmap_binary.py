"""Bounds check of COLMAP's binary model files before pycolmap reads them.

pycolmap trusts the counts in a file: a truncated ``points3D.bin`` or a count field of 2^62 makes it
allocate without limit (memory past 10 GB, no output). Walking the records with their sizes takes
milliseconds and turns such a file into a one-line error. Layouts (COLMAP ``src/colmap/scene/
reconstruction_io.cc``), little-endian:

- ``cameras.bin``: u64 count; per camera u32 id, i32 model, u64 width, u64 height, f64 params[n(model)]
- ``images.bin``: u64 count; per image u32 id, f64 qvec[4], f64 tvec[3], u32 camera, name\\0,
  u64 n2d, n2d x (f64 x, f64 y, i64 point3D id)
- ``points3D.bin``: u64 count; per point u64 id, f64 xyz[3], u8 rgb[3], f64 error, u64 track,
  track x (u32 image, u32 point2D index)
"""

from __future__ import annotations

import struct
from pathlib import Path

from tridehaze_plugin.errors import DataError

PARAMS_PER_MODEL = {0: 3, 1: 4, 2: 4, 3: 5, 4: 8, 5: 8, 6: 12, 7: 5, 8: 4, 9: 5, 10: 12, 11: 16}
"""COLMAP camera model id -> number of intrinsic parameters."""

_U64 = struct.Struct("<Q")
_CAMERA = struct.Struct("<IiQQ")  # id, model, width, height
_IMAGE_HEAD = 4 + 8 * 7 + 4  # id, qvec, tvec, camera id
_POINT2D = 24
_POINT_HEAD = struct.Struct("<Q3d3BdQ")  # id, xyz, rgb, error, track length
_TRACK = 8


class _Truncated(Exception):
    pass


def check_binary_model(sparse: Path) -> None:
    """DataError if a ``*.bin`` file in ``sparse`` does not hold the records its counts announce."""
    for name, walk in (("cameras.bin", _cameras), ("images.bin", _images), ("points3D.bin", _points)):
        path = sparse / name
        if not path.is_file():
            continue
        data = path.read_bytes()
        try:
            end, what = walk(data)
        except (_Truncated, struct.error) as exc:
            why = str(exc) if isinstance(exc, _Truncated) else "it ends inside a record"
            raise DataError(
                f"COLMAP {name} is truncated or corrupt ({why}; the file has {len(data)} bytes)",
                where=str(path),
                fix="re-export the model from COLMAP, or rebuild it with td-process-data",
            ) from None
        if end != len(data):
            raise DataError(
                f"COLMAP {name} has {len(data) - end} bytes after its {what}: not a COLMAP model file",
                where=str(path),
                fix="re-export the model from COLMAP, or rebuild it with td-process-data",
            )


def _count(data: bytes, record_min: int, kind: str) -> int:
    n = _U64.unpack_from(data, 0)[0]
    if n * record_min > len(data) - 8:  # cannot fit even with every record at its smallest
        raise _Truncated(f"it announces {n} {kind}, which cannot fit")
    return n


def _need(data: bytes, pos: int, size: int, i: int, kind: str) -> None:
    if size > len(data) - pos:
        raise _Truncated(f"{kind} {i} runs past the end of the file")


def _cameras(data: bytes) -> tuple[int, str]:
    n = _count(data, _CAMERA.size + 8 * 3, "cameras")
    pos = 8
    for i in range(n):
        _need(data, pos, _CAMERA.size, i, "camera")
        _, model, _, _ = _CAMERA.unpack_from(data, pos)
        if model not in PARAMS_PER_MODEL:
            raise _Truncated(f"camera {i} has the unknown model id {model}")
        size = _CAMERA.size + 8 * PARAMS_PER_MODEL[model]
        _need(data, pos, size, i, "camera")
        pos += size
    return pos, f"{n} camera(s)"


def _images(data: bytes) -> tuple[int, str]:
    n = _count(data, _IMAGE_HEAD + 1 + 8, "images")
    pos = 8
    for i in range(n):
        _need(data, pos, _IMAGE_HEAD + 1, i, "image")
        nul = data.find(b"\0", pos + _IMAGE_HEAD)
        if nul < 0:
            raise _Truncated(f"the name of image {i} is not terminated")
        pos = nul + 1
        _need(data, pos, 8, i, "image")
        n2d = _U64.unpack_from(data, pos)[0]
        pos += 8
        if n2d > (len(data) - pos) // _POINT2D:
            raise _Truncated(f"image {i} announces {n2d} 2D points, more than the file holds")
        pos += n2d * _POINT2D
    return pos, f"{n} image(s)"


def _points(data: bytes) -> tuple[int, str]:
    n = _count(data, _POINT_HEAD.size, "points")
    pos = 8
    for i in range(n):
        _need(data, pos, _POINT_HEAD.size, i, "point")
        track = _POINT_HEAD.unpack_from(data, pos)[-1]
        pos += _POINT_HEAD.size
        if track > (len(data) - pos) // _TRACK:
            raise _Truncated(f"point {i} announces a track of {track}, longer than the file holds")
        pos += track * _TRACK
    return pos, f"{n} point(s)"
