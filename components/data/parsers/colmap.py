"""COLMAP sparse models (``sparse/0/`` or ``sparse/``, binary or text) with images in ``images/``.

Optional extras next to them: ``clean/`` (haze-free images named like ``images/``; the extension
may differ), ``depths/`` (``<stem>.npy`` or ``<stem>.png``) and ``train_list.txt`` /
``test_list.txt`` (one image name per line) for an explicit split.

COLMAP poses are world-to-camera in OpenCV axes already; only the inverse is taken.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from components.data.cameras import ViewIntrinsics
from components.data.config import DataConfig
from components.data.images import is_image_file
from components.data.parsers.base import DataParser
from components.data.parsers.colmap_binary import check_binary_model
from components.data.scene import Frame, ParsedScene, PointTracks
from tridehaze_plugin.errors import DataError
from tridehaze_plugin.registry import register

SUPPORTED_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")


def find_sparse_dir(root: Path) -> Path | None:
    """``sparse/0`` if it holds a model, else ``sparse`` if it does, else None."""
    for d in (root / "sparse" / "0", root / "sparse"):
        if any((d / f"cameras.{ext}").is_file() for ext in ("bin", "txt")):
            return d
    return None


class ColmapParser(DataParser):
    """COLMAP sparse model + images/ (+ optional clean/, depths/, train_list.txt/test_list.txt)."""

    name = "colmap"
    looks_for = "sparse/0/cameras.bin|txt (or sparse/cameras.*) with images/"

    @classmethod
    def can_parse(cls, root: Path) -> bool:
        return find_sparse_dir(root) is not None

    @classmethod
    def parse(cls, root: Path, cfg: DataConfig) -> ParsedScene:
        sparse = find_sparse_dir(root)
        if sparse is None:
            raise DataError(
                "no COLMAP model found",
                where=str(root / "sparse"),
                fix="expected sparse/0/cameras.bin (or .txt)",
            )
        images_dir = root / "images"
        if not images_dir.is_dir():
            raise DataError(
                "COLMAP dataset has no images/ folder",
                where=str(images_dir),
                fix="put the input photos in images/",
            )
        rec = _read_model(sparse)

        cams = {cid: _camera(cam, sparse) for cid, cam in rec.cameras.items()}
        frames: list[Frame] = []
        unposed = []
        for im in sorted(rec.images.values(), key=lambda im: im.name):
            if not im.has_pose:
                unposed.append(im.name)
                continue
            w2c = np.eye(4)
            w2c[:3, :] = im.cam_from_world().matrix()  # [3, 4]
            c2w = _invert_rigid(w2c)
            frames.append(
                Frame(
                    name=f"images/{im.name}", image_path=images_dir / im.name, c2w=c2w, **cams[im.camera_id]
                )
            )
        if unposed:
            warnings.warn(
                f"{len(unposed)} image(s) in {sparse} have no pose and are skipped (e.g. {unposed[0]})",
                stacklevel=2,
            )
        _attach_clean(root, frames)
        _attach_depths(root, frames)
        points = colors = tracks = None
        if len(rec.points3D):
            pts = [rec.points3D[k] for k in sorted(rec.points3D)]  # stable order: by point id
            points = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)  # [M, 3]
            colors = np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3)  # [M, 3]
            tracks = _tracks(rec, pts)
        return ParsedScene(
            frames,
            points,
            colors,
            point_tracks=tracks,
            train_names=_read_list(root / "train_list.txt"),
            test_names=_read_list(root / "test_list.txt"),
        )


def _tracks(rec, pts: list) -> PointTracks:  # noqa: ANN001 - pycolmap types (imported lazily)
    """Each point's track as (point, image) pairs; images named as the frames are (``images/<name>``)."""
    ids = sorted(rec.images)
    column = {iid: j for j, iid in enumerate(ids)}
    point, view = [], []
    for k, p in enumerate(pts):
        for el in p.track.elements:
            if el.image_id in column:
                point.append(k)
                view.append(column[el.image_id])
    return PointTracks(
        np.array(point, np.int64), np.array(view, np.int64), [f"images/{rec.images[i].name}" for i in ids]
    )


def _read_model(sparse: Path):  # noqa: ANN202 - pycolmap.Reconstruction (imported lazily)
    import pycolmap  # local: heavy import, only needed for this format

    check_binary_model(sparse)  # pycolmap trusts the counts: a bad one allocates without bound
    try:
        return pycolmap.Reconstruction(str(sparse))
    except Exception as exc:  # noqa: BLE001 - pycolmap raises assorted types for bad files
        raise DataError(
            f"cannot read the COLMAP model ({type(exc).__name__}: {str(exc)[:200]})",
            where=str(sparse),
            fix="re-export the model (colmap model_converter) or check the files are complete",
        ) from None


def _camera(cam, sparse: Path) -> dict:
    """COLMAP camera -> Frame keyword arguments ``intrinsics``, ``camera_model`` and ``distortion``
    (OpenCV order)."""
    model = cam.model.name
    p = [float(v) for v in cam.params]
    if model == "PINHOLE":
        fx, fy, cx, cy = p
        dist: tuple[float, ...] = ()
    elif model == "SIMPLE_PINHOLE":
        (fx, cx, cy), fy, dist = p, p[0], ()
    elif model == "SIMPLE_RADIAL":
        fx, cx, cy, k = p
        fy, dist = fx, (k, 0.0, 0.0, 0.0)
    elif model == "RADIAL":
        fx, cx, cy, k1, k2 = p
        fy, dist = fx, (k1, k2, 0.0, 0.0)
    elif model == "OPENCV":
        fx, fy, cx, cy, k1, k2, p1, p2 = p
        dist = (k1, k2, p1, p2)
    else:
        raise DataError(
            f"COLMAP camera {cam.camera_id} uses model {model}, which is not supported",
            where=str(sparse),
            fix=f"use one of {', '.join(SUPPORTED_MODELS)} (or undistort with `colmap image_undistorter` first)",
        )
    if not any(d != 0.0 for d in dist):
        dist = ()
    return {
        "intrinsics": ViewIntrinsics(
            fx=fx, fy=fy, cx=cx, cy=cy, width=int(cam.width), height=int(cam.height)
        ),
        "camera_model": model if dist else "PINHOLE",
        "distortion": dist,
    }


def _invert_rigid(m: np.ndarray) -> np.ndarray:  # [4, 4] -> [4, 4]
    out = np.eye(4)
    R, t = m[:3, :3], m[:3, 3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def _attach_clean(root: Path, frames: list[Frame]) -> None:
    """Pair ``clean/<name>`` with ``images/<name>`` (same name, or same stem with another extension)."""
    clean_dir = root / "clean"
    if not clean_dir.is_dir():
        return
    clean_files = {p.relative_to(clean_dir).as_posix(): p for p in clean_dir.rglob("*") if is_image_file(p)}
    by_stem: dict[str, list[str]] = {}
    for rel in clean_files:
        by_stem.setdefault(rel.rsplit(".", 1)[0], []).append(rel)
    used: set[str] = set()
    for f in frames:
        rel = f.name.removeprefix("images/")
        match = rel if rel in clean_files else None
        if match is None and len(by_stem.get(rel.rsplit(".", 1)[0], [])) == 1:
            match = by_stem[rel.rsplit(".", 1)[0]][0]
        if match is not None:
            f.clean_path = clean_files[match]
            used.add(match)
    unmatched = sorted(set(clean_files) - used)
    if unmatched or (frames and not used):
        examples = ", ".join(unmatched[:3]) or "none of them match"
        hazy = ", ".join(f.name.removeprefix("images/") for f in frames[:3])
        raise DataError(
            f"clean/ and images/ names do not match ({len(unmatched)} clean image(s) without a hazy one: "
            f"{examples}; hazy names look like: {hazy})",
            where=str(clean_dir),
            fix="name each clean image like its hazy counterpart in images/ (the extension may differ)",
        )


def _attach_depths(root: Path, frames: list[Frame]) -> None:
    depth_dir = root / "depths"
    if not depth_dir.is_dir():
        return
    for f in frames:
        stem = f.name.removeprefix("images/").rsplit(".", 1)[0]
        for ext in (".npy", ".png"):
            if (depth_dir / (stem + ext)).is_file():
                f.depth_path = depth_dir / (stem + ext)
                break


def _read_list(path: Path) -> list[str] | None:
    if not path.is_file():
        return None
    lines = (line.strip() for line in path.read_text(encoding="utf-8").splitlines())
    return [line for line in lines if line and not line.startswith("#")]


register("dataparser", ColmapParser.name, ColmapParser)
