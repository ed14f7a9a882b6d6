"""``load_scene``: any supported dataset folder -> trainer-ready :class:`SceneData`.

Steps, the same for every format: pick a parser, validate every frame (so problems surface
before training, each as one :class:`DataError` naming the file), undistort + downscale into the
cache, normalise poses, split train/test. See docs/data.md for the conventions.
"""

from __future__ import annotations

import os
import posixpath
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch

import components.data.parsers  # noqa: F401  (registers the built-in parsers)
from components.data.cache import prepare_image, prepare_map, scene_cache_dir
from components.data.cameras import Cameras
from components.data.config import DataConfig
from components.data.geometry import Geometry, frame_geometry
from components.data.images import image_size
from components.data.parsers import AUTO_ORDER
from components.data.sanity import (
    check_camera_spread,
    check_downscaled_size,
    check_principal_points,
    check_seed_visibility,
)
from components.data.scene import DataWarning, Frame, ParsedScene, PointTracks, SceneData, SceneTransform
from tridehaze_plugin.errors import DataError, first_few
from tridehaze_plugin.registry import REGISTRY

ROTATION_TOL = 1e-3
"""Largest accepted deviation of a pose rotation from orthonormal (|R^T R - I|, |det R - 1|)."""


def load_scene(cfg: DataConfig) -> SceneData:
    """Parse, validate, undistort/downscale (cached), normalise and split the dataset ``cfg.data``."""
    root = check_root(cfg.data)
    _check_options(cfg)
    parser_name, parser = pick_parser(root, cfg.parser)
    parsed = parser.parse(root, cfg)
    frames = validate_frames(parsed, root, skip_missing=cfg.skip_missing_images)
    train, test = split_indices(frames, parsed, cfg.test_every, root)
    geoms = [frame_geometry(f, cfg.downscale) for f in frames]
    check_downscaled_size(frames, [g.out_size for g in geoms], cfg.downscale)
    c2w_raw = torch.from_numpy(np.stack([f.c2w for f in frames]))  # [N, 4, 4] float64
    check_camera_spread(frames, c2w_raw[:, :3, 3].numpy())
    check_principal_points(frames, root)
    paths = _prepare_files(frames, geoms, scene_cache_dir(root, cfg.cache_dir))

    transform = normalizing_transform(c2w_raw[:, :3, 3], center=cfg.center_poses, scale=cfg.scale_poses)
    c2w = transform.apply_c2w(c2w_raw)
    cameras = Cameras(
        camtoworlds=c2w.float(),
        fx=torch.tensor([g.out.fx for g in geoms], dtype=torch.float32),
        fy=torch.tensor([g.out.fy for g in geoms], dtype=torch.float32),
        cx=torch.tensor([g.out.cx for g in geoms], dtype=torch.float32),
        cy=torch.tensor([g.out.cy for g in geoms], dtype=torch.float32),
        width=torch.tensor([g.out_size[0] for g in geoms], dtype=torch.int64),
        height=torch.tensor([g.out_size[1] for g in geoms], dtype=torch.int64),
    )
    points, colors, kept = _seed_points(parsed, transform, c2w_raw, frames, geoms, root)
    return SceneData(
        name=root.name,
        root=root,
        parser=parser_name,
        image_paths=[p["image"] for p in paths],
        cameras=cameras,
        train_indices=train,
        test_indices=test,
        clean_paths=[p["clean"] for p in paths],
        depth_paths=[p["depth"] for p in paths],
        extra_paths={
            k: [p["extras"].get(k) for p in paths] for k in sorted({k for f in frames for k in f.extras})
        },
        points=points,
        point_colors=colors,
        point_tracks=loaded_tracks(parsed.point_tracks, kept, [f.name for f in frames]),
        transform=transform,
        downscale=cfg.downscale,
        test_is_clean=parsed.test_is_clean,
        frame_names=[f.name for f in frames],
    )


def _seed_points(
    parsed: ParsedScene,
    transform: SceneTransform,
    c2w_raw: torch.Tensor,
    frames: list[Frame],
    geoms: list[Geometry],
    root: Path,
) -> tuple[torch.Tensor | None, torch.Tensor | None, np.ndarray | None]:
    """The usable seed points [M, 3] in the normalised frame, their colours [M, 3] in [0, 1]
    (None when the dataset has none) and the mask of the parsed points kept, after checking that
    the cameras see them."""
    points = colors = keep = None
    if parsed.points is not None and len(parsed.points):
        raw = np.asarray(parsed.points, np.float64)  # [M, 3] in the dataset's frame
        normalised = transform.apply_points(torch.from_numpy(raw))  # [M, 3] the frame training sees
        keep = usable_points(raw, normalised.numpy(), c2w_raw[:, :3, 3].numpy(), root)
        check_seed_visibility(
            raw[keep],
            c2w_raw.numpy(),
            np.array([[g.pinhole.fx, g.pinhole.fy, g.pinhole.cx, g.pinhole.cy] for g in geoms]),  # [N, 4]
            np.array([g.src_size for g in geoms], dtype=np.float64),  # [N, 2]
            [f.name for f in frames],
            root,
        )
        points = normalised[torch.from_numpy(keep)].float()
        if parsed.point_colors is not None:  # [M, 3] in [0, 1]
            colors = torch.from_numpy(np.asarray(parsed.point_colors, np.uint8)[keep]).float() / 255.0
    return points, colors, keep


def loaded_tracks(
    tracks: PointTracks | None, kept: np.ndarray | None, names: list[str]
) -> PointTracks | None:
    """Parsed tracks re-indexed to the kept seed points (``kept`` [M] bool) and the loaded views
    (``names``, in view order); pairs of a dropped point or view go. None without tracks or points.
    A pair outside the parser's own points or frames is the parser's bug (the built-in ones check
    their files), so it raises instead of vanishing from the prior unseen."""
    if tracks is None or kept is None or tracks.names is None:
        return None
    F = len(tracks.names)
    inside = (tracks.point >= 0) & (tracks.point < len(kept)) & (tracks.view >= 0) & (tracks.view < F)
    if not inside.all():
        bad = np.stack([tracks.point[~inside], tracks.view[~inside]], axis=1)[:3].tolist()
        raise ValueError(
            f"{int((~inside).sum())} parsed track pairs lie outside the parser's {len(kept)} points / "
            f"{F} frames (first (point, frame) pairs: {bad})"
        )
    new_point = np.cumsum(kept) - 1  # [M] parsed index -> kept index (valid where kept)
    view_of = {n: i for i, n in enumerate(names)}
    new_view = np.array([view_of.get(n, -1) for n in tracks.names], np.int64)  # [F]
    p, v = tracks.point, new_view[tracks.view]
    ok = kept[p] & (v >= 0)
    return PointTracks(new_point[p[ok]], v[ok])


FAR_POINT = 1e4
"""A seed point farther from the cameras' centre than this many times the capture's size (the
cameras' spread, or a thousandth of the points' median distance for a capture from one spot) is an
outlier, not scenery."""
MAX_COORD = 1e15
"""Largest coordinate (in the normalised frame training sees) a seed point may have: float32
covariances of Gaussians beyond it overflow."""


def usable_points(points: np.ndarray, normalised: np.ndarray, centres: np.ndarray, root: Path) -> np.ndarray:
    """Mask of seed points to keep: finite and not absurdly far (``points`` [M, 3] and camera
    ``centres`` [N, 3] in the dataset's frame, ``normalised`` [M, 3] the same points as training
    sees them); warns with the counts dropped, DataError when none is left."""
    finite = np.isfinite(points).all(axis=1)
    safe = np.where(finite[:, None], points, 0.0)  # [M, 3]
    centre = centres.mean(axis=0)
    dist = np.linalg.norm(safe - centre, axis=1)  # [M]
    spread = float(np.linalg.norm(centres - centre, axis=1).max())
    median = float(np.median(dist[finite])) if finite.any() else 0.0
    inside = np.abs(normalised).max(axis=1) < MAX_COORD  # [M] (False on NaN rows, already out)
    keep = finite & (dist <= FAR_POINT * max(spread, 1e-3 * median)) & inside
    n_bad, n_far = int((~finite).sum()), int((finite & ~keep).sum())
    if not keep.any():
        raise DataError(
            f"none of the {len(points)} seed points is usable ({n_bad} non-finite, {n_far} absurdly far "
            "from the cameras)",
            where=str(root),
            fix="fix or remove the point cloud",
        )
    if n_bad or n_far:
        warnings.warn(
            f"dropped {n_bad} non-finite and {n_far} absurdly far seed point(s) of {len(points)} ({root})",
            DataWarning,
            stacklevel=2,
        )
    return keep


# --------------------------------------------------------------------------------------
# folder, options and parser


def check_root(data: Path | None) -> Path:
    """The dataset folder as an absolute path; DataError when absent or not a folder."""
    if data is None:
        raise DataError("no dataset given", fix="pass --data DIR (a dataset folder)")
    root = Path(os.path.expanduser(str(data)))
    if not root.exists():
        raise DataError("dataset folder not found", where=str(root), fix="check the --data path")
    if not root.is_dir():
        raise DataError(
            "--data must be a folder, got a file", where=str(root), fix="pass the folder that holds it"
        )
    return root.resolve()


def _check_options(cfg: DataConfig) -> None:
    if isinstance(cfg.downscale, bool) or not isinstance(cfg.downscale, int) or cfg.downscale < 1:
        raise DataError(
            f"downscale must be an integer >= 1, got {cfg.downscale!r}",
            where="--downscale",
            fix="use 1, 2, 4, ...",
        )
    if isinstance(cfg.test_every, bool) or not isinstance(cfg.test_every, int) or cfg.test_every < 0:
        raise DataError(
            f"test_every must be an integer >= 0, got {cfg.test_every!r}",
            where="--test-every",
            fix="use 8 (every 8th view is a test view) or 0 (no test split)",
        )


def pick_parser(root: Path, name: str) -> tuple[str, type]:
    """(name, parser class): ``name`` as given, or for ``auto`` the first that recognises ``root``.

    Built-ins are tried in :data:`AUTO_ORDER` (nerfstudio, blender, colmap), then plugin parsers by name.
    """
    if name != "auto":
        return name, REGISTRY.get("dataparser", name)
    names = REGISTRY.names("dataparser")
    order = [n for n in AUTO_ORDER if n in names] + [n for n in names if n not in AUTO_ORDER]
    for n in order:
        cls = REGISTRY.get("dataparser", n)
        if cls.can_parse(root):
            return n, cls
    looked = "; ".join(f"{n}: {getattr(REGISTRY.get('dataparser', n), 'looks_for', '?')}" for n in order)
    raise DataError(
        f"cannot tell the dataset format (looked for {looked})",
        where=str(root),
        fix="point --data at a folder in one of these formats, or pass --parser NAME",
    )


# --------------------------------------------------------------------------------------
# validation


def validate_frames(parsed: ParsedScene, root: Path, *, skip_missing: bool = False) -> list[Frame]:
    """The usable frames; DataError for anything that would break training or evaluation later."""
    frames = list(parsed.frames)
    if not frames:
        raise DataError(
            "no images found in the dataset", where=str(root), fix="check the dataset lists its images"
        )
    _check_unique_names(frames, root)
    missing = [f for f in frames if not f.image_path.is_file()]
    if missing:
        listed = first_few([f.name for f in missing])
        if not skip_missing:
            raise DataError(
                f"{len(missing)} of {len(frames)} listed image(s) are missing: {listed}",
                where=str(missing[0].image_path),
                fix="restore them, or pass --skip-missing-images to drop those views",
            )
        frames = [f for f in frames if f.image_path.is_file()]
        if not frames:
            raise DataError("all listed images are missing", where=str(missing[0].image_path.parent))
        warnings.warn(
            f"skipping {len(missing)} view(s) whose image is missing: {listed}", DataWarning, stacklevel=3
        )
    for f in frames:
        _check_pose(f)
        _check_intrinsics(f)
        size = _check_image_size(f)
        if f.clean_path is not None:
            _check_clean(f, size)
        if f.depth_path is not None and not f.depth_path.is_file():
            raise DataError(f"depth map of frame {f.name} not found", where=str(f.depth_path))
        for key, p in f.extras.items():
            if not p.is_file():
                raise DataError(f"{key} of frame {f.name} not found", where=str(p))
    return frames


def _check_unique_names(frames: list[Frame], root: Path) -> None:
    seen: set[str] = set()
    for f in frames:
        if f.name in seen:
            raise DataError(f"image {f.name} is listed twice", where=str(root), fix="list each image once")
        seen.add(f.name)


def _check_pose(f: Frame) -> None:
    c2w = np.asarray(f.c2w, dtype=np.float64)
    if c2w.shape != (4, 4) or not np.all(np.isfinite(c2w[:3])):
        raise DataError(
            f"pose of frame {f.name} contains NaN or Inf",
            where=str(f.image_path),
            fix="fix or remove this frame's camera-to-world matrix",
        )
    R = c2w[:3, :3]
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if err > ROTATION_TOL or abs(det - 1.0) > ROTATION_TOL:
        raise DataError(
            f"pose of frame {f.name} is not a rigid rotation (max|R^T R - I| = {err:.2g}, det R = {det:.4g})",
            where=str(f.image_path),
            fix="camera-to-world rotations must be orthonormal with det +1 (no scale, shear or mirror)",
        )
    # snap to the nearest rotation so viewmats are exactly rigid
    u, _, vt = np.linalg.svd(R)
    clean = np.eye(4)
    clean[:3, :3] = u @ vt
    clean[:3, 3] = c2w[:3, 3]
    f.c2w = clean


def _check_intrinsics(f: Frame) -> None:
    intr = f.intrinsics
    vals = {"fx": intr.fx, "fy": intr.fy, "width": intr.width, "height": intr.height}
    for k, v in vals.items():
        if not np.isfinite(v) or v <= 0:
            raise DataError(
                f"frame {f.name} has non-positive or invalid {k} = {v}",
                where=str(f.image_path),
                fix="focal lengths and image sizes must be positive",
            )
    if not (np.isfinite(intr.cx) and np.isfinite(intr.cy)):
        raise DataError(f"frame {f.name} has an invalid principal point", where=str(f.image_path))


def _check_image_size(f: Frame) -> tuple[int, int]:
    size = image_size(f.image_path)  # DataError for unreadable / corrupt files
    k = f.intrinsics
    if size != (k.width, k.height):
        raise DataError(
            f"image is {size[0]}x{size[1]} but its camera says {k.width}x{k.height}",
            where=str(f.image_path),
            fix="use the images the camera model was made for (not a resized copy), or fix w/h",
        )
    return size


def _check_clean(f: Frame, size: tuple[int, int]) -> None:
    assert f.clean_path is not None
    if f.clean_path == f.image_path:
        return
    if not f.clean_path.is_file():
        raise DataError(
            f"clean (haze-free) image of frame {f.name} not found",
            where=str(f.clean_path),
            fix="restore it or remove clean_file_path for this frame",
        )
    csize = image_size(f.clean_path)
    if csize != size:
        raise DataError(
            f"clean image is {csize[0]}x{csize[1]} but hazy image {f.name} is {size[0]}x{size[1]}",
            where=str(f.clean_path),
            fix="clean and hazy images must be pixel-aligned at the same size",
        )


# --------------------------------------------------------------------------------------
# split


def split_indices(
    frames: list[Frame], parsed: ParsedScene, test_every: int, root: Path
) -> tuple[list[int], list[int]]:
    """(train, test) indices into ``frames``.

    An explicit split from the dataset wins (names must exist; views dropped as missing are simply
    left out; a list given alone makes the other split its complement). Otherwise every
    ``test_every``-th view (0, N, 2N, ...) is a test view; ``test_every = 0`` or fewer than two views
    means no test split.
    """
    n = len(frames)
    if parsed.train_names is None and parsed.test_names is None:
        if test_every == 0 or n < 2:
            return list(range(n)), []
        test = [i for i in range(n) if i % test_every == 0]
        train = [i for i in range(n) if i % test_every != 0]
        if not train:
            raise DataError(
                f"test_every={test_every} leaves no training views", where="--test-every", fix="use 0 or >= 2"
            )
        return train, test
    all_names = [f.name for f in parsed.frames]
    index = {f.name: i for i, f in enumerate(frames)}
    chosen: dict[str, set[str] | None] = {}
    for which, names in (("train", parsed.train_names), ("test", parsed.test_names)):
        chosen[which] = None if names is None else {_match_name(nm, all_names, which, root) for nm in names}
    train_set, test_set = chosen["train"], chosen["test"]
    if train_set is None:
        train_set = set(index) - (test_set or set())
    if test_set is None:
        test_set = set(index) - train_set
    both = sorted(train_set & test_set)
    if both:
        raise DataError(
            f"{len(both)} view(s) are in both the train and the test split, e.g. {both[0]}",
            where=str(root),
            fix="list each view in one split only",
        )
    train = sorted(index[nm] for nm in train_set if nm in index)
    test = sorted(index[nm] for nm in test_set if nm in index)
    if not train:
        raise DataError(
            "the explicit split has no training views", where=str(root), fix="list some train images"
        )
    return train, test


def _match_name(name: str, all_names: list[str], which: str, root: Path) -> str:
    """The frame name that split entry ``name`` refers to: exact, or a unique path suffix."""
    norm = posixpath.normpath(name.replace("\\", "/"))
    if norm in all_names:
        return norm
    hits = [n for n in all_names if n.endswith("/" + norm)]
    if len(hits) == 1:
        return hits[0]
    stem_hits = [
        n for n in all_names if n.rsplit(".", 1)[0] == norm or n.rsplit(".", 1)[0].endswith("/" + norm)
    ]
    if len(stem_hits) == 1:
        return stem_hits[0]
    raise DataError(
        f"{which} split names {name!r}, which matches {'several' if hits else 'no'} image(s) of the dataset",
        where=str(root),
        fix=f"use names like {all_names[0]!r}",
    )


# --------------------------------------------------------------------------------------
# normalisation


def normalizing_transform(centers: torch.Tensor, *, center: bool, scale: bool) -> SceneTransform:
    """Similarity (no rotation) putting the mean camera centre at 0 and the farthest camera at distance 1.

    ``centers`` is [N, 3]. A single camera, or cameras all at one spot, leave the scale at 1.
    """
    centers = centers.to(torch.float64)
    t = -centers.mean(dim=0) if center else torch.zeros(3, dtype=torch.float64)  # [3]
    s = 1.0
    if scale and len(centers) > 1:
        far = float((centers + t).norm(dim=-1).max())
        if far > 1e-9:
            s = 1.0 / far
    return SceneTransform(torch.eye(3, dtype=torch.float64), t, s)


# --------------------------------------------------------------------------------------
# files


def _prepare_files(frames: list[Frame], geoms: list[Geometry], out_dir: Path) -> list[dict]:
    """Per frame: the paths the trainer reads (cached undistorted / downscaled copies where needed)."""

    def one(i: int) -> dict:
        f, g = frames[i], geoms[i]
        image = prepare_image(f.image_path, g, f.name, out_dir)
        if f.clean_path is None:
            clean = None
        elif f.clean_path == f.image_path:
            clean = image
        else:
            clean = prepare_image(f.clean_path, g, "clean/" + f.name, out_dir)
        depth = prepare_map(f.depth_path, g, "depth/" + f.name, out_dir) if f.depth_path else None
        extras = {k: prepare_map(p, g, f"{k}/{f.name}", out_dir) for k, p in f.extras.items()}
        return {"image": image, "clean": clean, "depth": depth, "extras": extras}

    if all(g.is_identity for g in geoms):
        return [one(i) for i in range(len(frames))]
    workers = max(1, min(8, os.cpu_count() or 1))
    with ThreadPoolExecutor(max_workers=workers) as pool:  # OpenCV releases the GIL while it works
        return list(pool.map(one, range(len(frames))))
