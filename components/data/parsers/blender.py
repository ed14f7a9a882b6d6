"""Blender / NeRF-synthetic / RealX3D layout: ``transforms_train.json`` + ``transforms_test.json``.

The split comes from the files. ``transforms_val.json`` is ignored (as in most NeRF code) unless
there is no test file, in which case it is the test split. Test images are the clean references
in this layout (hazy training views, haze-free test views), so each test frame's ``clean_path``
is its own image and the scene is flagged ``test_is_clean``.
"""

from __future__ import annotations

from pathlib import Path

from components.data.config import DataConfig
from components.data.parsers.base import (
    DataParser,
    c2w_from_opengl,
    find_with_suffix,
    json_intrinsics,
    load_json,
    rel_name,
    resolve,
)
from components.data.ply import read_ply_points
from components.data.scene import Frame, ParsedScene
from tridehaze_plugin.errors import DataError
from tridehaze_plugin.registry import register


class BlenderParser(DataParser):
    """Blender/RealX3D transforms_{train,test}.json (split from the files; test views are clean)."""

    name = "blender"
    looks_for = "transforms_train.json"

    @classmethod
    def can_parse(cls, root: Path) -> bool:
        return (root / "transforms_train.json").is_file()

    @classmethod
    def parse(cls, root: Path, cfg: DataConfig) -> ParsedScene:
        test_file = root / "transforms_test.json"
        if not test_file.is_file() and (root / "transforms_val.json").is_file():
            test_file = root / "transforms_val.json"
        train = _read_split(root, root / "transforms_train.json", is_test=False)
        test = _read_split(root, test_file, is_test=True) if test_file.is_file() else []
        meta = load_json(root / "transforms_train.json")
        points = colors = None
        if meta.get("ply_file_path"):
            points, colors = read_ply_points(resolve(root, str(meta["ply_file_path"])))
        return ParsedScene(
            frames=train + test,
            points=points,
            point_colors=colors,
            train_names=[f.name for f in train],
            test_names=[f.name for f in test],
            test_is_clean=True,
        )


def _read_split(root: Path, path: Path, *, is_test: bool) -> list[Frame]:
    meta = load_json(path)
    frames_meta = meta.get("frames")
    if not isinstance(frames_meta, list):
        raise DataError("no 'frames' list", where=str(path), fix="add a frames list (see docs/data.md)")
    shared = {k: v for k, v in meta.items() if k != "frames"}
    frames = []
    for i, fm in enumerate(frames_meta):
        where = f"{path} frames[{i}]"
        if not isinstance(fm, dict) or "file_path" not in fm or "transform_matrix" not in fm:
            raise DataError("frame needs 'file_path' and 'transform_matrix'", where=where)
        image = find_with_suffix(resolve(path.parent, str(fm["file_path"])))
        merged = {**shared, **{k: v for k, v in fm.items() if k not in ("file_path", "transform_matrix")}}
        clean = image if is_test else None
        if fm.get("clean_file_path"):
            clean = find_with_suffix(resolve(path.parent, str(fm["clean_file_path"])))
        frames.append(
            Frame(
                name=rel_name(image, root),
                image_path=image,
                c2w=c2w_from_opengl(fm["transform_matrix"], where),
                clean_path=clean,
                depth_path=resolve(path.parent, str(fm["depth_file_path"]))
                if fm.get("depth_file_path")
                else None,
                extras={
                    k: resolve(path.parent, str(v))
                    for k, v in fm.items()
                    if k.endswith("_file_path") and k not in ("clean_file_path", "depth_file_path") and v
                },
                **json_intrinsics(merged, image, where),
            )
        )
    return frames


register("dataparser", BlenderParser.name, BlenderParser)
