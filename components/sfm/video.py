"""Sharp, evenly spaced frames from a video (OpenCV), ready for structure-from-motion.

The video is split into ``num_frames`` equal segments of consecutive frames and the sharpest
frame of each segment is kept (sharpness: variance of the Laplacian of the grey frame, shrunk to
at most ``SHARPNESS_SIZE`` pixels, a standard blur measure). Two passes over the file: one scores
every frame, one decodes and writes the chosen ones, so memory stays at one frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from tridehaze_plugin.errors import DataError

SHARPNESS_SIZE = 480
"""Longest side at which sharpness is measured (fast, and insensitive to sensor noise)."""


@dataclass
class VideoFrames:
    paths: list[Path]
    """The written frames, in time order."""
    indices: list[int]
    """Frame numbers in the video (0-based) of each written frame."""
    total_frames: int
    """Frames decoded from the video."""
    fps: float
    sharpness: list[float]
    """Laplacian variance of each written frame."""


def sharpness(bgr: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image (higher = sharper)."""
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY) if bgr.ndim == 3 else bgr
    h, w = grey.shape[:2]
    s = SHARPNESS_SIZE / max(h, w)
    if s < 1.0:
        grey = cv2.resize(grey, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


def choose_frames(scores: np.ndarray, num_frames: int) -> list[int]:
    """Indices of the sharpest frame in each of ``num_frames`` equal segments of ``scores`` [F].

    With fewer frames than requested every frame is returned.
    """
    n = len(scores)
    if num_frames >= n:
        return list(range(n))
    edges = np.linspace(0, n, num_frames + 1)
    out = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        lo, hi = int(round(a)), max(int(round(b)), int(round(a)) + 1)
        out.append(lo + int(np.argmax(scores[lo:hi])))
    return out


def _open(path: Path) -> cv2.VideoCapture:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise DataError(
            "video cannot be opened (corrupt, or a codec OpenCV cannot decode)",
            where=str(path),
            fix="re-encode it, e.g. `ffmpeg -i IN -c:v libx264 OUT.mp4`, or extract frames yourself "
            "and use `td-process-data images`",
        )
    return cap


def extract_frames(
    video: Path,
    out_dir: Path,
    num_frames: int,
    progress: Callable[[int, int], None] | None = None,
    suffix: str = ".jpg",
) -> VideoFrames:
    """Write the sharpest frame of each of ``num_frames`` segments to ``out_dir/frame_NNNNN<suffix>``.

    ``progress(done, total)`` is called while scoring (total is the container's frame count, an
    estimate) and while writing.
    """
    video = Path(video)
    if not video.is_file():
        raise DataError("video file not found", where=str(video), fix="check the --data path")
    fps, scores = _score_frames(video, progress)
    if len(scores) < 2:
        raise DataError(
            f"video has {len(scores)} readable frame(s); at least 2 are needed",
            where=str(video),
            fix="check the file plays, or re-encode it",
        )
    chosen = choose_frames(np.asarray(scores), num_frames)
    paths = _write_frames(video, set(chosen), out_dir, suffix, progress)
    if len(paths) != len(chosen):
        raise DataError(
            f"video ended early on the second read ({len(paths)} of {len(chosen)} frames)",
            where=str(video),
            fix="re-encode the video; its frame index is inconsistent",
        )
    return VideoFrames(paths, chosen, len(scores), fps, [scores[i] for i in chosen])


def _score_frames(video: Path, progress: Callable[[int, int], None] | None) -> tuple[float, list[float]]:
    """First pass: (fps, sharpness of every readable frame)."""
    cap = _open(video)
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    expected = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    scores: list[float] = []
    while True:
        ok, frame = cap.read()
        if not ok or frame is None:
            break
        scores.append(sharpness(frame))
        if progress is not None:
            progress(len(scores), max(expected, len(scores)))
    cap.release()
    return fps, scores


def _write_frames(
    video: Path, want: set[int], out_dir: Path, suffix: str, progress: Callable[[int, int], None] | None
) -> list[Path]:
    """Second pass: encode the frames whose index is in ``want``, in order."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    cap = _open(video)
    idx = 0
    params = [cv2.IMWRITE_JPEG_QUALITY, 95] if suffix.lower() in (".jpg", ".jpeg") else []
    while len(paths) < len(want):
        ok, frame = cap.read()
        if not ok or frame is None:
            break
        if idx in want:
            path = out_dir / f"frame_{len(paths) + 1:05d}{suffix}"
            ok_enc, enc = cv2.imencode(suffix, frame, params)
            if not ok_enc:
                raise OSError(f"could not encode frame {idx} as {suffix}")
            path.write_bytes(enc.tobytes())
            paths.append(path)
            if progress is not None:
                progress(len(paths), len(want))
        idx += 1
    cap.release()
    return paths
