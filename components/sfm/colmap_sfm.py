"""Structure-from-motion with pycolmap on the CPU: photos -> a COLMAP dataset ``td-train`` reads.

Stages (each reported to a :class:`Reporter`, so a command-line tool can draw progress bars):

1. ``prepare``: every photo is decoded once (a corrupt file is a one-line error before any work)
   and, with ``enhance`` other than ``none``, a contrast-enhanced copy of the same size is written
   for matching (``components.sfm.enhance``).
2. ``features``: the photos are imported into a COLMAP database from the *originals* (so the camera
   sizes and any EXIF focal length come from them), then SIFT runs on the matching copies, at most
   ``max_image_size`` pixels on the longest side (keypoints are stored in original pixels).
3. ``matching``: exhaustive (every pair) or sequential (each photo with the next ``overlap`` ones
   and, quadratically, 2^k further) pairs, matched in chunks with geometric verification.
4. ``mapping``: incremental mapping; the model with the most registered images is kept.
5. ``undistort``: the originals are undistorted with the kept model (COLMAP's undistorter);
   the result is ``images/`` + ``sparse/0/`` (PINHOLE cameras), the layout of our COLMAP parser.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from components.data.images import IMAGE_SUFFIXES, encode_image, is_image_file, read_image, write_bytes_atomic
from components.sfm.enhance import ENHANCE_CHOICES, enhance_image
from tridehaze_plugin.errors import DataError, UserError

CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
"""Camera models the mapper may estimate (all understood by the COLMAP parser before undistortion)."""

EXHAUSTIVE_MAX_IMAGES = 200
"""``--matcher auto`` matches every pair up to this many photos, sequentially beyond (and for videos)."""


@dataclass
class SfmOptions:
    """How photos are matched and mapped."""

    matcher: Literal["auto", "exhaustive", "sequential"] = "auto"
    """Pairs to match: every pair, or neighbours in name order (ordered captures, videos).
    ``auto``: exhaustive up to 200 photos, sequential beyond."""
    enhance: Literal["none", "clahe", "dcp"] = "none"
    """Match on contrast-enhanced copies (CLAHE, or dark-channel dehazing); the dataset keeps the
    original photos."""
    max_image_size: int = 1600
    """Longest side (pixels) at which features are extracted; larger photos are shrunk for SIFT
    only (keypoints and the dataset stay at full resolution)."""
    camera_model: Literal["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"] = "SIMPLE_RADIAL"
    """Camera model estimated by the mapper (undistorted to PINHOLE at the end). ``PINHOLE`` (separate
    fx, fy) is poorly constrained with few photos; ``SIMPLE_PINHOLE`` suits already undistorted ones."""
    camera_mode: Literal["auto", "single", "per-image"] = "auto"
    """Shared intrinsics: ``auto`` (one camera per image size and EXIF), ``single`` (one camera for
    all photos, e.g. a video), ``per-image``."""
    focal_factor: float | None = None
    """A known focal length, as a multiple of each photo's longest side (a 35 mm-equivalent focal
    length / 36 mm; a 24 mm drone lens: 0.67). Every camera starts there, overriding EXIF.
    None: EXIF where the photos carry it, else COLMAP's guess of 1.2, which can end far off on
    forward walks (docs/synth.md: 1.6-3.2x)."""
    refine_focal: bool = True
    """Let bundle adjustment refine the focal length; ``--no-refine-focal`` keeps a known
    ``--focal-factor`` fixed."""
    max_num_features: int = 8192
    """SIFT features per photo."""
    sequential_overlap: int = 10
    """Sequential matching: each photo is matched with this many following ones, and with those
    2^k ahead for k below it (loops back to the start of a capture are not searched)."""
    threads: int = 2
    """CPU threads for extraction, matching, mapping and undistortion."""
    seed: int = 0
    """Random seed of RANSAC and the mapper (results can still vary with more than one thread)."""
    verbose: bool = False
    """Show COLMAP's own log lines."""

    def check(self) -> None:
        from tridehaze_plugin.errors import ConfigError

        if self.max_image_size < 64:
            raise ConfigError(
                f"--max-image-size must be at least 64, got {self.max_image_size}",
                fix="pass e.g. --max-image-size 1600",
            )
        if self.max_num_features < 64:
            raise ConfigError(f"--max-num-features must be at least 64, got {self.max_num_features}")
        if self.sequential_overlap < 1:
            raise ConfigError(f"--sequential-overlap must be at least 1, got {self.sequential_overlap}")
        if self.threads < 1:
            raise ConfigError(f"--threads must be at least 1, got {self.threads}")
        if self.focal_factor is not None and not 0.05 <= self.focal_factor <= 50:
            raise ConfigError(
                f"--focal-factor is the focal length over the longest image side, got {self.focal_factor}",
                fix="pass e.g. --focal-factor 0.67 for a 24 mm (35 mm-equivalent) lens: 24 / 36",
            )
        if not self.refine_focal and self.focal_factor is None:
            raise ConfigError(
                "--no-refine-focal keeps a known focal length fixed, but none was given",
                fix="add --focal-factor F (focal length / longest image side), or drop --no-refine-focal",
            )
        if self.enhance not in ENHANCE_CHOICES:
            raise ConfigError(
                f"unknown --enhance {self.enhance!r}", fix=f"use one of {', '.join(ENHANCE_CHOICES)}"
            )


@dataclass
class SfmResult:
    num_images: int
    registered: list[str]
    unregistered: list[str]
    num_points: int
    mean_reprojection_error: float
    mean_track_length: float
    num_models: int
    matcher: str
    num_pairs: int
    num_verified_pairs: int
    mean_keypoints: float
    timings_s: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class Reporter:
    """Progress sink; the default does nothing. ``start`` opens a stage of ``total`` steps (None:
    unknown), ``advance``/``update`` move it, ``finish`` closes it with a one-line summary."""

    def start(self, stage: str, total: int | None) -> None:  # noqa: B027 - optional hook
        pass

    def advance(self, n: int = 1) -> None:  # noqa: B027 - optional hook
        pass

    def update(self, completed: int, total: int | None = None) -> None:  # noqa: B027 - optional hook
        pass

    def finish(self, stage: str, seconds: float, detail: str) -> None:  # noqa: B027 - optional hook
        pass


# ---------------------------------------------------------------------------------- inputs


def list_images(folder: Path) -> list[str]:
    """Names of the image files directly in ``folder``, sorted; DataError when unusable."""
    folder = Path(folder)
    if not folder.exists():
        raise DataError("photo folder not found", where=str(folder), fix="check the --data path")
    if not folder.is_dir():
        raise DataError(
            "--data is a file, not a folder of photos",
            where=str(folder),
            fix="pass the folder that holds the photos (use `td-process-data video` for a video)",
        )
    names = sorted(p.name for p in folder.iterdir() if p.is_file() and is_image_file(p))
    if len(names) < 2:
        raise DataError(
            f"found {len(names)} photo(s); structure-from-motion needs at least 2 (3 or more in practice)",
            where=str(folder),
            fix=f"put the photos directly in this folder (endings: {', '.join(IMAGE_SUFFIXES)})",
        )
    return names


def image_pairs(names: list[str], matcher: str, overlap: int) -> list[tuple[str, str]]:
    """Pairs to match: all of them, or each photo with the next ``overlap`` ones and with those
    2^k ahead for k < overlap (COLMAP's sequential matcher with quadratic overlap)."""
    n = len(names)
    if matcher == "exhaustive":
        return [(names[i], names[j]) for i in range(n) for j in range(i + 1, n)]
    pairs: set[tuple[int, int]] = set()
    for i in range(n):
        for k in range(1, overlap + 1):
            if i + k < n:
                pairs.add((i, i + k))
        for k in range(min(overlap, 31)):  # quadratic overlap, as COLMAP: i + 2^k
            if i + (1 << k) < n:
                pairs.add((i, i + (1 << k)))
    return [(names[i], names[j]) for i, j in sorted(pairs)]


def resolve_matcher(matcher: str, num_images: int, ordered: bool = False) -> str:
    if matcher != "auto":
        return matcher
    return "sequential" if ordered or num_images > EXHAUSTIVE_MAX_IMAGES else "exhaustive"


# ---------------------------------------------------------------------------------- the run


@contextmanager
def _colmap_log(verbose: bool) -> Iterator[None]:
    import pycolmap

    old = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 0 if verbose else 3  # 3: fatal only; failures are raised as our errors
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


class _Stages:
    """Times each stage of the reconstruction and reports its start, progress and one-line result."""

    def __init__(self, reporter: Reporter) -> None:
        self.rep = reporter
        self.timings: dict[str, float] = {}

    @contextmanager
    def stage(self, name: str, total: int | None) -> Iterator[list[str]]:
        """``with stages.stage(name, n) as detail: ...; detail.append("what it found")``."""
        t0 = time.perf_counter()
        self.rep.start(name, total)
        detail: list[str] = []
        yield detail
        self.timings[name] = time.perf_counter() - t0
        self.rep.finish(name, self.timings[name], "".join(detail))


def run_sfm(
    image_dir: Path,
    names: list[str],
    out_dir: Path,
    work_dir: Path,
    opts: SfmOptions,
    reporter: Reporter | None = None,
    ordered: bool = False,
) -> SfmResult:
    """Reconstruct ``names`` in ``image_dir``; write ``out_dir/images`` and ``out_dir/sparse/0``.

    ``work_dir`` receives the database and matching copies (the caller deletes it). ``ordered``
    marks the names as a capture sequence (video frames): ``--matcher auto`` is then sequential.
    """
    import pycolmap

    opts.check()
    stages = _Stages(reporter or Reporter())
    work_dir.mkdir(parents=True, exist_ok=True)
    pycolmap.set_random_seed(opts.seed)
    db_path = work_dir / "database.db"
    with _colmap_log(opts.verbose):
        match_dir = _prepare(image_dir, names, work_dir, opts, stages)
        mean_kp = _extract_features(db_path, image_dir, match_dir, names, opts, stages)
        matcher, pairs, verified = _match(db_path, names, work_dir, opts, ordered, stages)
        found = f"{verified} of {len(pairs)} photo pairs matched ({mean_kp:.0f} keypoints per photo)"
        hint = ("" if matcher == "exhaustive" else ", try --matcher exhaustive") + (
            "" if opts.enhance != "none" else ", or --enhance clahe for hazy photos"
        )
        rec, num_models, model_dir = _map(db_path, image_dir, work_dir, names, opts, stages, found, hint)
        registered = sorted(im.name for im in rec.images.values() if im.has_pose)
        _undistort(work_dir, model_dir, image_dir, out_dir, opts, stages, len(registered))
    return SfmResult(
        num_images=len(names),
        registered=registered,
        unregistered=sorted(set(names) - set(registered)),
        num_points=int(rec.num_points3D()),
        mean_reprojection_error=float(rec.compute_mean_reprojection_error()),
        mean_track_length=float(rec.compute_mean_track_length()),
        num_models=num_models,
        matcher=matcher,
        num_pairs=len(pairs),
        num_verified_pairs=verified,
        mean_keypoints=mean_kp,
        timings_s={k: round(v, 3) for k, v in stages.timings.items()},
    )


def _prepare(image_dir: Path, names: list[str], work_dir: Path, opts: SfmOptions, stages: _Stages) -> Path:
    """Check every photo reads (and sizes agree for one camera); write enhanced copies for matching."""
    with stages.stage("prepare", len(names)) as detail:
        match_dir = image_dir if opts.enhance == "none" else work_dir / "match"
        sizes: dict[tuple[int, int], str] = {}
        for name in names:
            rgb = read_image(image_dir / name)  # DataError for corrupt / unreadable photos
            sizes.setdefault((rgb.shape[1], rgb.shape[0]), name)
            if opts.camera_mode == "single" and len(sizes) > 1:
                (w0, h0), first = next(iter(sizes.items()))
                raise DataError(
                    f"--camera-mode single needs photos of one size, but {first} is {w0}x{h0} and "
                    f"{name} is {rgb.shape[1]}x{rgb.shape[0]}",
                    where=str(image_dir),
                    fix="use --camera-mode auto (one camera per size) or resize the photos",
                )
            if opts.enhance != "none":
                out = enhance_image(rgb, opts.enhance)
                write_bytes_atomic(match_dir / name, encode_image(match_dir / name, out))
            stages.rep.advance()
        detail.append(f"{len(names)} photos, enhance {opts.enhance}")
    return match_dir


def _extract_features(
    db_path: Path, image_dir: Path, match_dir: Path, names: list[str], opts: SfmOptions, stages: _Stages
) -> float:
    """SIFT features of every photo into the database; returns the mean keypoint count."""
    import pycolmap

    with stages.stage("features", len(names)) as detail:
        pycolmap.Database.open(db_path).close()
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = opts.camera_model
        mode = {
            "auto": pycolmap.CameraMode.AUTO,
            "single": pycolmap.CameraMode.SINGLE,
            "per-image": pycolmap.CameraMode.PER_IMAGE,
        }[opts.camera_mode]
        pycolmap.import_images(db_path, image_dir, camera_mode=mode, image_names=names, options=reader)
        if opts.focal_factor is not None:
            _set_known_focal(db_path, opts.focal_factor)
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = opts.threads
        extraction.max_image_size = opts.max_image_size
        extraction.use_gpu = False
        extraction.sift.max_num_features = opts.max_num_features
        chunk = max(opts.threads, 4)
        for i in range(0, len(names), chunk):
            part = names[i : i + chunk]
            pycolmap.extract_features(
                db_path, match_dir, image_names=part, camera_mode=mode, reader_options=reader,
                extraction_options=extraction, device=pycolmap.Device.cpu,
            )  # fmt: skip
            stages.rep.advance(len(part))
        with pycolmap.Database.open(db_path) as db:
            kp = {im.name: db.num_keypoints_for_image(im.image_id) for im in db.read_all_images()}
        mean_kp = float(np.mean([kp.get(n, 0) for n in names]))
        detail.append(f"{mean_kp:.0f} keypoints per photo")
    return mean_kp


def _set_known_focal(db_path: Path, factor: float) -> None:
    """Every camera in the database starts at focal = factor x its longest side, as a prior."""
    import pycolmap

    with pycolmap.Database.open(db_path) as db:
        for cam in db.read_all_cameras():
            params = np.array(cam.params, dtype=np.float64)
            params[list(cam.focal_length_idxs())] = factor * max(cam.width, cam.height)
            cam.params = params
            cam.has_prior_focal_length = True
            db.update_camera(cam)


def _match(
    db_path: Path, names: list[str], work_dir: Path, opts: SfmOptions, ordered: bool, stages: _Stages
) -> tuple[str, list[tuple[str, str]], int]:
    """Match the chosen photo pairs and verify them geometrically: (matcher, pairs, verified count)."""
    import pycolmap

    matcher = resolve_matcher(opts.matcher, len(names), ordered)
    pairs = image_pairs(names, matcher, opts.sequential_overlap)
    with stages.stage("matching", len(pairs)) as detail:
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = opts.threads
        matching.use_gpu = False
        verification = pycolmap.TwoViewGeometryOptions()
        if hasattr(verification, "ransac"):
            verification.ransac.random_seed = opts.seed
        step = max(50, len(pairs) // 20)
        for i in range(0, len(pairs), step):
            part = pairs[i : i + step]
            pair_file = work_dir / "pairs.txt"
            pair_file.write_text("".join(f"{a} {b}\n" for a, b in part), encoding="utf-8")
            pairing = pycolmap.ImportedPairingOptions()
            pairing.match_list_path = pair_file
            pycolmap.match_image_pairs(
                db_path, matching_options=matching, pairing_options=pairing,
                verification_options=verification, device=pycolmap.Device.cpu,
            )  # fmt: skip
            stages.rep.advance(len(part))
        with pycolmap.Database.open(db_path) as db:
            _, geoms = db.read_two_view_geometries()
        bad = {
            pycolmap.TwoViewGeometryConfiguration.UNDEFINED,
            pycolmap.TwoViewGeometryConfiguration.DEGENERATE,
        }
        verified = sum(1 for g in geoms if g.config not in bad and len(g.inlier_matches) > 0)
        detail.append(f"{matcher}: {verified} of {len(pairs)} pairs verified")
    return matcher, pairs, verified


def _map(
    db_path: Path, image_dir: Path, work_dir: Path, names: list[str], opts: SfmOptions, stages: _Stages,
    found: str, hint: str,
) -> tuple[Any, int, Path]:  # fmt: skip
    """Incremental mapping; the model with the most registered photos is written to work_dir/sparse/best.
    Returns (reconstruction, number of models, its folder); ``found``/``hint`` word the no-model error."""
    import pycolmap

    with stages.stage("mapping", len(names)) as detail:
        mapping = pycolmap.IncrementalPipelineOptions()
        mapping.num_threads = opts.threads
        mapping.random_seed = opts.seed
        mapping.mapper.num_threads = opts.threads
        mapping.mapper.random_seed = opts.seed
        mapping.triangulation.random_seed = opts.seed
        mapping.ba_refine_focal_length = opts.refine_focal
        mapping.min_model_size = min(mapping.min_model_size, max(2, len(names) // 2))
        sparse_dir = work_dir / "sparse"
        sparse_dir.mkdir(exist_ok=True)
        models = pycolmap.incremental_mapping(
            db_path, image_dir, sparse_dir, options=mapping,
            initial_image_pair_callback=lambda: stages.rep.advance(2),
            next_image_callback=lambda: stages.rep.advance(1),
        )  # fmt: skip
        if not models:
            raise DataError(
                f"structure-from-motion found no model: {found}",
                where=str(image_dir),
                fix="use photos with more overlap and texture" + hint,
            )
        rec = models[max(models, key=lambda k: (models[k].num_reg_images(), models[k].num_points3D()))]
        registered = sum(1 for im in rec.images.values() if im.has_pose)
        detail.append(
            f"{registered}/{len(names)} registered, {rec.num_points3D()} points, {len(models)} model(s)"
        )
    model_dir = sparse_dir / "best"
    model_dir.mkdir()
    rec.write(model_dir)
    return rec, len(models), model_dir


def _undistort(
    work_dir: Path, model_dir: Path, image_dir: Path, out_dir: Path, opts: SfmOptions, stages: _Stages,
    registered: int,
) -> None:  # fmt: skip
    """Undistorted images and the PINHOLE model into out_dir/images and out_dir/sparse/0."""
    import pycolmap

    with stages.stage("undistort", None) as detail:
        undist = work_dir / "undistorted"
        pycolmap.undistort_images(
            undist, model_dir, image_dir, output_type="COLMAP", num_threads=opts.threads
        )
        out_dir.mkdir(parents=True, exist_ok=True)
        shutil.move(str(undist / "images"), str(out_dir / "images"))
        (out_dir / "sparse").mkdir(exist_ok=True)
        shutil.move(str(undist / "sparse"), str(out_dir / "sparse" / "0"))
        detail.append(f"{registered} images")


def check_sfm_output(out: Path, data: Path) -> None:
    """UserError when the output folder would be inside (or be) the photo folder's images."""
    out, data = Path(out).absolute(), Path(data).absolute()
    if out == data:
        raise UserError(
            "--output-dir is the photo folder itself",
            where=str(out),
            fix="write the dataset to a new folder, e.g. --output-dir data/scene",
        )
