"""nerfstudio ``transforms.json`` (OpenGL camera-to-world poses, global or per-frame intrinsics).

Keys beyond nerfstudio's: ``clean_file_path`` (a paired haze-free image, used for evaluation) and
any other ``*_file_path`` key per frame (e.g. ``gt_depth_file_path``), kept in ``Frame.extras``
for evaluation only: only ``depth_file_path`` is ever a depth prior. At the top level,
``point_tracks_file_path`` (with ``ply_file_path``) names an ``.npy`` of int pairs [K, 2]: a seed
point's index in the PLY and the index in ``frames`` of a view that observed it (SfM tracks).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from components.data.config import DataConfig
from components.data.parsers.base import (
    DataParser,
    c2w_from_opengl,
    json_intrinsics,
    load_json,
    rel_name,
    resolve,
)
from components.data.ply import read_ply_points
from components.data.scene import Frame, ParsedScene, PointTracks
from tridehaze_plugin.errors import DataError
from tridehaze_plugin.registry import register

TRANSFORMS = "transforms.json"
_OWN_PATHS = ("file_path", "depth_file_path", "clean_file_path")
"""Per-frame path keys with a fixed role; every other ``*_file_path`` (and ``mask_path``) is an extra."""


class NerfstudioParser(DataParser):
    """nerfstudio transforms.json (+ optional clean_file_path / depth_file_path / ply_file_path)."""

    name = "nerfstudio"
    looks_for = TRANSFORMS

    @classmethod
    def can_parse(cls, root: Path) -> bool:
        return (root / TRANSFORMS).is_file()

    @classmethod
    def parse(cls, root: Path, cfg: DataConfig) -> ParsedScene:
        path = root / TRANSFORMS
        meta = load_json(path)
        frames_meta = meta.get("frames")
        if not isinstance(frames_meta, list):
            raise DataError("no 'frames' list", where=str(path), fix="add a frames list (see docs/data.md)")
        base = path.parent
        shared = {k: v for k, v in meta.items() if k != "frames"}
        frames = [_frame(base, root, shared, fm, f"{path} frames[{i}]") for i, fm in enumerate(frames_meta)]
        names = [f.name for f in frames]  # in the file's order, which the tracks index
        frames.sort(key=lambda f: f.name)  # file order is arbitrary; the every-Nth split needs a stable one
        points = colors = tracks = None
        if meta.get("ply_file_path"):
            points, colors = read_ply_points(resolve(base, str(meta["ply_file_path"])))
            if meta.get("point_tracks_file_path"):
                tracks = _tracks(resolve(base, str(meta["point_tracks_file_path"])), len(points), names)
        train = _names(meta.get("train_filenames"), base, root, path)
        test = _names(meta.get("test_filenames", meta.get("val_filenames")), base, root, path)
        return ParsedScene(frames, points, colors, point_tracks=tracks, train_names=train, test_names=test)


def _frame(base: Path, root: Path, shared: dict[str, Any], fm: Any, where: str) -> Frame:
    if not isinstance(fm, dict) or "file_path" not in fm or "transform_matrix" not in fm:
        raise DataError("frame needs 'file_path' and 'transform_matrix'", where=where)
    image = resolve(base, str(fm["file_path"]))
    merged = {**shared, **fm}  # per-frame intrinsics override the global ones
    extras = {
        k: resolve(base, str(v))
        for k, v in fm.items()
        if (k.endswith("_file_path") or k == "mask_path") and k not in _OWN_PATHS and v
    }
    return Frame(
        name=rel_name(image, root),
        image_path=image,
        c2w=c2w_from_opengl(fm["transform_matrix"], where),
        clean_path=resolve(base, str(fm["clean_file_path"])) if fm.get("clean_file_path") else None,
        depth_path=resolve(base, str(fm["depth_file_path"])) if fm.get("depth_file_path") else None,
        extras=extras,
        **json_intrinsics(merged, image, where),
    )


def _tracks(path: Path, num_points: int, names: list[str]) -> PointTracks:
    """The (point, frame) pairs of ``point_tracks_file_path``, checked against the PLY and the frames."""
    fix = "write an .npy of int pairs [K, 2]: (index in the PLY, index in frames), or drop the key"
    if not path.is_file():
        raise DataError("point tracks file not found", where=str(path), fix=fix)
    try:
        pairs = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise DataError(f"cannot read the point tracks ({exc})", where=str(path), fix=fix) from None
    if pairs.ndim != 2 or pairs.shape[1] != 2 or not np.issubdtype(pairs.dtype, np.integer):
        raise DataError(
            f"point tracks must be int pairs [K, 2], got {pairs.dtype} {pairs.shape}",
            where=str(path),
            fix=fix,
        )
    bad = (pairs[:, 0] < 0) | (pairs[:, 0] >= num_points) | (pairs[:, 1] < 0) | (pairs[:, 1] >= len(names))
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise DataError(
            f"{int(bad.sum())} point track pair(s) out of range (row {row}: {pairs[row].tolist()}; "
            f"{num_points} points, {len(names)} frames)",
            where=str(path),
            fix=fix,
        )
    return PointTracks(pairs[:, 0], pairs[:, 1], names)


def _names(value: Any, base: Path, root: Path, where: Path) -> list[str] | None:
    if value is None:
        return None
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise DataError("split lists must be lists of file names", where=str(where))
    return [rel_name(resolve(base, v), root) for v in value]


register("dataparser", NerfstudioParser.name, NerfstudioParser)
