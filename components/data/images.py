"""Reading and writing image and depth files, with user-facing errors.

Everything goes through ``np.fromfile`` + ``cv2.imdecode`` (not ``cv2.imread``) so that paths
with non-ASCII characters work on every platform, and so that a corrupt file is detected
(``imdecode`` returns ``None``) instead of silently yielding an empty array.

Conventions:

* images come back as uint8 RGB ``[H, W, 3]``: grayscale is repeated to three channels,
  16-bit is reduced to 8-bit, and an alpha channel is *composited onto white*, which is
  what Blender / NeRF-synthetic renders (transparent background) are meant to look like;
* EXIF orientation is ignored, as COLMAP and nerfstudio do, so that pixel sizes agree with
  the camera models written by those tools.
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
import tempfile
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from tridehaze_plugin.errors import DataError

IMAGE_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
"""File endings treated as images when a folder is scanned (compared case-insensitively)."""

DEPTH_SUFFIXES: tuple[str, ...] = (".npy", ".png")

PNG_DEPTH_SCALE = 1e-3
"""16-bit PNG depth is read as millimetres (value * 1e-3 -> metres), as nerfstudio does."""


def is_image_file(path: Path) -> bool:
    return path.suffix.lower() in IMAGE_SUFFIXES


def _check_file(path: Path, what: str) -> None:
    """DataError unless ``path`` is an existing, non-empty file."""
    if not path.exists():
        raise DataError(f"{what} not found", where=str(path), fix="check the path or restore the file")
    if not path.is_file():
        raise DataError(f"{what} is not a file", where=str(path), fix="point to a file, not a folder")
    if path.stat().st_size == 0:
        raise DataError(f"{what} is empty (0 bytes)", where=str(path), fix="re-export or remove the file")


def _read_bytes(path: Path, what: str) -> np.ndarray:
    """File contents as a uint8 buffer [B]; DataError when missing, unreadable or empty."""
    path = Path(path)
    _check_file(path, what)
    try:
        buf = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise DataError(
            f"{what} cannot be read ({exc.strerror or exc})", where=str(path), fix="check file permissions"
        ) from None
    if buf.size == 0:
        raise DataError(f"{what} is empty (0 bytes)", where=str(path), fix="re-export or remove the file")
    return buf


@contextlib.contextmanager
def _opencv_silent() -> Iterator[None]:
    """Mute OpenCV's own log lines (``[ERROR:0@...] readHeader ...``) on stderr: a file it cannot
    decode is reported once, as a DataError."""
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    if log is None:
        yield
        return
    before = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        log.setLogLevel(before)


def decode_raw(path: Path, what: str = "image") -> np.ndarray:
    """Decode an image file as stored: [H, W] or [H, W, C] (BGR/BGRA order), any bit depth."""
    buf = _read_bytes(path, what)
    with _opencv_silent():
        arr = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if arr is None or arr.size == 0:
        raise DataError(
            f"{what} is corrupt or not a supported image format",
            where=str(path),
            fix="re-export it as PNG or JPEG, or remove it from the dataset",
        )
    return arr


def to_uint8(arr: np.ndarray) -> np.ndarray:
    """Map any image dtype to uint8 (16-bit divided by 257, floats clipped to [0, 1])."""
    if arr.dtype == np.uint8:
        return arr
    if arr.dtype == np.uint16:
        return ((arr.astype(np.uint32) + 128) // 257).astype(np.uint8)
    if np.issubdtype(arr.dtype, np.floating):
        return (np.clip(np.nan_to_num(arr), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    return np.clip(arr, 0, 255).astype(np.uint8)


def to_rgb(arr: np.ndarray) -> np.ndarray:
    """Decoded BGR(A)/gray uint8 [H, W(, C)] -> RGB [H, W, 3]; alpha composited onto white."""
    if arr.ndim == 2:
        arr = arr[:, :, None]
    c = arr.shape[2]
    if c in (2, 4):  # gray+alpha or BGRA
        alpha = arr[:, :, -1:].astype(np.float32) / 255.0  # [H, W, 1]
        color = arr[:, :, :-1].astype(np.float32)
        arr = (color * alpha + 255.0 * (1.0 - alpha) + 0.5).astype(np.uint8)
        c -= 1
    if c == 1:
        return np.repeat(arr, 3, axis=2)
    return np.ascontiguousarray(arr[:, :, ::-1])  # BGR -> RGB


def read_image(path: Path) -> np.ndarray:
    """Image file -> uint8 RGB [H, W, 3]; DataError for missing, unreadable, empty or corrupt files."""
    return to_rgb(to_uint8(decode_raw(Path(path), "image")))


MAP_ASPECT_TOLERANCE = 0.02
"""A per-pixel map may be stored at another resolution than its image (a half-size depth map is
common) but not with another shape: a relative aspect difference above this is refused."""


def check_map_fits(shape: tuple[int, ...], width: int, height: int, path: Path) -> None:
    """DataError when a map of ``shape`` [h, w, ...] cannot be the map of a ``width`` x ``height``
    image: resizing it anyway would pair pixels with the wrong depths."""
    h, w = int(shape[0]), int(shape[1])
    if h < 1 or w < 1 or abs((w / h) / (width / height) - 1.0) > MAP_ASPECT_TOLERANCE:
        raise DataError(
            f"map is {w}x{h} but its image is {width}x{height} (another aspect ratio)",
            where=str(path),
            fix="write the map at the image's size (or a uniform scale of it)",
        )


def read_map(src: Path) -> np.ndarray:
    """A per-pixel map (``.npy`` [H, W] or [H, W, C], or an image file) as stored; DataError when
    it is not one."""
    src = Path(src)
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


def read_depth(path: Path, png_scale: float = PNG_DEPTH_SCALE) -> np.ndarray:
    """Depth map -> float32 [H, W].

    ``.npy`` values are used as stored; a 16-bit PNG is multiplied by ``png_scale`` (millimetres
    to metres by default); an 8-bit PNG is divided by 255 (a relative depth, e.g. a visualisation
    of a monocular estimate).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        _check_file(path, "depth map")
        try:
            arr = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise DataError(
                f"depth map is not a valid .npy array ({exc})",
                where=str(path),
                fix="re-save it with numpy.save",
            ) from None
        arr = np.squeeze(np.asarray(arr))  # [H, W, 1] / [1, H, W] -> [H, W]
        if arr.ndim != 2 or not np.issubdtype(arr.dtype, np.number):
            raise DataError(
                f"depth map must be a 2-D numeric array, got shape {tuple(arr.shape)} dtype {arr.dtype}",
                where=str(path),
                fix="save an [H, W] float array",
            )
        return arr.astype(np.float32)
    if suffix == ".png":
        arr = decode_raw(path, "depth map")
        if arr.ndim == 3:
            arr = arr[:, :, 0]
        if arr.dtype == np.uint16:
            return arr.astype(np.float32) * np.float32(png_scale)
        if arr.dtype == np.uint8:
            return arr.astype(np.float32) / 255.0
        return arr.astype(np.float32)
    raise DataError(
        f"unsupported depth format {path.suffix!r}",
        where=str(path),
        fix=f"convert it to one of {', '.join(DEPTH_SUFFIXES)}",
    )


# --------------------------------------------------------------------------------------
# sizes without decoding


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) of an image, from the PNG/JPEG header when possible (no full decode).

    Falls back to a full decode for other formats or unusual headers, so every failure is a
    DataError naming the file.
    """
    path = Path(path)
    buf = _read_bytes(path, "image")
    data = buf.tobytes()
    size = _png_size(data) or _jpeg_size(data)
    if size is not None and size[0] > 0 and size[1] > 0:
        return size
    arr = decode_raw(path, "image")
    return int(arr.shape[1]), int(arr.shape[0])


def _png_size(head: bytes) -> tuple[int, int] | None:
    if len(head) >= 24 and head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        w, h = struct.unpack(">II", head[16:24])
        return int(w), int(h)
    return None


_SOF_MARKERS = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    if data[:2] != b"\xff\xd8":
        return None
    i = 2
    n = len(data)
    while i + 4 <= n:
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01, 0xD8) or 0xD0 <= marker <= 0xD7:  # stand-alone markers
            i += 2
            continue
        (length,) = struct.unpack(">H", data[i + 2 : i + 4])
        if marker in _SOF_MARKERS:
            if i + 9 > n:
                return None
            h, w = struct.unpack(">HH", data[i + 5 : i + 9])
            return int(w), int(h)
        if marker == 0xDA:  # start of scan before any frame header: give up
            return None
        i += 2 + length
    return None


# --------------------------------------------------------------------------------------
# writing


def current_umask() -> int:
    """The process umask (reading it means setting it, so it is restored at once)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def default_file_mode() -> int:
    """Permissions an ordinary ``open(path, "w")`` would give (0666 minus the umask)."""
    return 0o666 & ~current_umask()


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write via a temporary file in the same folder + ``os.replace``: readers never see half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, default_file_mode())  # mkstemp makes 0600 files; others expect the umask's
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def encode_image(path: Path, arr: np.ndarray, *, rgb: bool = True) -> bytes:
    """Encode ``arr`` in the format implied by ``path``'s suffix (RGB input is swapped to BGR)."""
    if rgb and arr.ndim == 3 and arr.shape[2] == 3:
        arr = arr[:, :, ::-1]  # RGB -> BGR for OpenCV
    ok, enc = cv2.imencode(Path(path).suffix or ".png", np.ascontiguousarray(arr))
    if not ok:
        raise OSError(f"could not encode image for {path}")
    return enc.tobytes()


def write_image_atomic(path: Path, arr: np.ndarray) -> None:
    """Write a uint8 RGB [H, W, 3] (or gray [H, W]) image atomically; format from the suffix."""
    write_bytes_atomic(Path(path), encode_image(Path(path), arr))


def write_array_atomic(path: Path, arr: np.ndarray) -> None:
    """Write an array atomically: ``.npy`` via numpy, anything else as an image stored as given."""
    path = Path(path)
    if path.suffix.lower() == ".npy":
        bio = io.BytesIO()
        np.save(bio, arr, allow_pickle=False)
        write_bytes_atomic(path, bio.getvalue())
    else:
        write_bytes_atomic(path, encode_image(path, arr, rgb=False))
