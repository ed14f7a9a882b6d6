"""``td-synth scene``: a procedural scene rendered with exact haze into a dataset the trainer reads.

Output (nerfstudio layout, paths relative to the folder)::

    transforms.json            OpenGL c2w, fl_x fl_y cx cy w h, explicit train/test split
    images/NNNN.png            hazy views (what a method trains on)
    clean/NNNN.png             haze-free views (``clean_file_path``, evaluation only)
    gt_depth/NNNN.npy          true camera z-depth in metres (``gt_depth_file_path``; sky: far bound)
    gt_transmittance/NNNN.npy  true T in (0, 1] (``gt_transmittance_file_path``)
    gt_scattering/NNNN.npy     true S [H, W, 3] (``gt_scattering_file_path``); hazy = clean * T + S
    points3d.ply               sparse seed cloud (noisy visible surface points, hazy colours by default)
    points3d_tracks.npy        each seed point's track: (point, frame) pairs of train views that see
                               its true surface point unoccluded (``point_tracks_file_path``): as
                               short as COLMAP's on hazy photos for the sfm cloud, complete for clean
    synth_meta.json            settings, medium parameters, timings, mean transmittance

The ``gt_*`` keys land in ``SceneData.extra_paths``, never in ``depth_paths``: true depth would be
a prior no real capture has.
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from components.data.cameras import ViewIntrinsics
from components.data.ply import write_ply_points
from components.synth.layouts import LAYOUTS, Layout, make_layout
from components.synth.march import DEFAULT_SAMPLES
from components.synth.medium import PRESETS, Medium, make_medium
from components.synth.render import CleanView, apply_medium, render_clean
from components.synth.seed_cloud import default_count, pick_pixels, place_points, seed_tracks
from components.synth.trajectories import orbit_poses, walk_poses
from components.synth.writer import frame_entry, staged_output, write_json, write_map, write_rgb
from tridehaze_plugin.errors import ConfigError

GENERATOR_VERSION = 2
"""Bumped whenever the same settings give different files. 2: `sfm` seed clouds carry tracks as
short as COLMAP's (session 45); 1 (no ``generator_version`` in ``synth_meta.json``): complete
tracks."""

LayoutName = Literal["street", "courtyard", "room", "field"]
HazeName = Literal["none", "homogeneous", "height", "patchy", "dense", "uniform", "sunlit"]


@dataclass
class SceneConfig:
    """A procedural hazy scene with exact ground truth."""

    output_dir: Path
    """Dataset folder to write (must be new or empty unless --overwrite)."""
    layout: LayoutName = "courtyard"
    """Scene layout: a street (forward walk), a courtyard, a room (indoor), an open field."""
    haze: HazeName = "patchy"
    """Medium preset: none, homogeneous (constant extinction, light dimmer near the ground), height
    (ground fog), patchy (heterogeneous blobs), dense, uniform (constant extinction and light),
    sunlit (noise-modulated ground fog lit by a low sun with strong forward scattering)."""
    seed: int = 0
    """Random seed for the layout and the medium (same seed, byte-identical images and maps)."""
    num_views: int = 32
    """Number of views."""
    width: int = 160
    """Image width in pixels."""
    height: int = 120
    """Image height in pixels."""
    fov_deg: float = 60.0
    """Horizontal field of view in degrees."""
    trajectory: Literal["auto", "walk", "orbit"] = "auto"
    """Camera path: the layout's default (auto), a forward-facing walk, or an orbit."""
    samples: int = DEFAULT_SAMPLES
    """Ray-marching samples per pixel between the camera and the surface (or far bound)."""
    supersample: int = 2
    """Sub-pixel rays per axis for the clean colour (anti-aliasing of the fine textures)."""
    beta_scale: float = 1.0
    """Multiplies the preset's extinction (2 = twice as thick)."""
    seed_cloud: Literal["sfm", "clean"] = "sfm"
    """Seed points as SfM on hazy photos gives them (sparse, where the hazy view has contrast, depth
    noise growing with distance, 5 % outliers, tracks of about three views; measured, docs/synth.md),
    or ``clean``: true surface points drawn uniformly with only ``--point-noise`` jitter and complete
    tracks (a flattering prior, for comparison)."""
    num_points: int | None = None
    """Seed points over the train views (None: the cloud's own default, sfm 30 per train view and
    at least 64, clean 4000)."""
    point_noise: float = 0.003
    """Seed point jitter on every axis, as a fraction of the point's distance (both clouds)."""
    point_colors: Literal["clean", "hazy"] = "hazy"
    """Seed point colours: the clean surface colour, or the hazy pixel's (what SfM on hazy photos gives)."""
    test_every: int = 8
    """Views 0, N, 2N, ... form the test split (0: no test views)."""
    overwrite: bool = False
    """Replace an output folder this same tool wrote before (a folder it did not write, or one
    holding files it did not write, is refused); the old one stays until the new is complete."""
    threads: int = 1
    """Torch CPU threads while generating (1 is fastest on small images and shared machines; 0: torch default)."""

    def check(self) -> None:
        if self.layout not in LAYOUTS:
            raise ConfigError(f"--layout must be one of {', '.join(LAYOUTS)}, got {self.layout!r}")
        if self.haze not in PRESETS:
            raise ConfigError(f"--haze must be one of {', '.join(PRESETS)}, got {self.haze!r}")
        for name in ("num_views", "width", "height", "samples", "supersample"):
            if getattr(self, name) < 1:
                raise ConfigError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        if not 1.0 <= self.fov_deg <= 170.0:
            raise ConfigError(f"--fov-deg must be in [1, 170], got {self.fov_deg}")
        if not (math.isfinite(self.beta_scale) and self.beta_scale >= 0):
            raise ConfigError(f"--beta-scale must be a finite number >= 0, got {self.beta_scale}")
        if self.seed_cloud not in ("sfm", "clean"):
            raise ConfigError(f"--seed-cloud must be sfm or clean, got {self.seed_cloud!r}")
        if (self.num_points is not None and self.num_points < 0) or not (
            math.isfinite(self.point_noise) and self.point_noise >= 0
        ):
            raise ConfigError("--num-points and --point-noise must be finite and >= 0")
        if self.point_colors not in ("clean", "hazy"):
            raise ConfigError(f"--point-colors must be clean or hazy, got {self.point_colors!r}")
        if self.test_every < 0 or self.test_every == 1:
            raise ConfigError(f"--test-every must be 0 or >= 2, got {self.test_every}")
        if self.threads < 0:
            raise ConfigError(f"--threads must be >= 0, got {self.threads}")


@contextlib.contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run with ``n`` torch threads (0: leave as is), restoring the previous setting afterwards."""
    before = torch.get_num_threads()
    if n > 0:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def camera_poses(layout: Layout, trajectory: str, n: int) -> tuple[str, list[np.ndarray]]:
    kind = layout.default_trajectory if trajectory == "auto" else trajectory
    return kind, (walk_poses(layout.walk, n) if kind == "walk" else orbit_poses(layout.orbit, n))


def split(n: int, test_every: int) -> tuple[list[int], list[int]]:
    test = [i for i in range(n) if test_every and i % test_every == 0 and n > 1]
    return [i for i in range(n) if i not in test], test


def sample_points(
    view: CleanView,
    hazy: torch.Tensor,
    colors: torch.Tensor,
    k: int,
    cfg: SceneConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``k`` seed points of one view (``hazy`` [H, W, 3] decides where the sfm cloud finds
    features) with their pixel's ``colors`` [H, W, 3]; errors as ``cfg.seed_cloud`` models them.
    Also returns the true surface points they were drawn from (for their tracks)."""
    pick = pick_pixels(cfg.seed_cloud, view.hit.numpy(), hazy, k, rng)
    if len(pick) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros((0, 3))
    o, d = view.origins.numpy()[pick].astype(np.float64), view.dirs.numpy()[pick].astype(np.float64)
    t = view.t_end.numpy()[pick]
    xyz = place_points(cfg.seed_cloud, o, d, t, cfg.point_noise, rng)  # [k, 3]
    rgb = colors.reshape(-1, 3).numpy()[pick]
    return xyz, np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8), o + t.astype(np.float64)[:, None] * d


def generate_scene(cfg: SceneConfig) -> dict[str, Any]:
    """Render the scene of ``cfg`` into ``cfg.output_dir`` (staged, then renamed); returns the metadata."""
    cfg.check()
    with torch_threads(cfg.threads), staged_output(cfg.output_dir, cfg.overwrite, "td-synth") as tmp:
        meta = _render_all(cfg, tmp)
    return meta


OUTPUT_NEUTRAL = ("output_dir", "overwrite", "threads")
"""Settings that do not change the files written."""


def recorded_settings(cfg: SceneConfig) -> dict[str, Any]:
    """``cfg`` as ``synth_meta.json`` records it (paths as text; where it went and whether it
    overwrote left out)."""
    settings = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()}
    settings.pop("output_dir")
    settings.pop("overwrite")
    return settings


def mismatch(path: Path, cfg: SceneConfig) -> str | None:
    """Why the dataset at ``path`` is not what ``generate_scene(cfg)`` writes now (None: it is);
    a set reused across generator changes would silently mix old and new scenes."""
    try:
        meta = json.loads((path / "synth_meta.json").read_text(encoding="utf-8"))
        version, settings = meta.get("generator_version", 1), meta["settings"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return "it holds no readable synth_meta.json (not written by td-synth scene)"
    if version != GENERATOR_VERSION:
        return f"td-synth wrote it at generator version {version}, today's is {GENERATOR_VERSION}"
    want = {k: v for k, v in recorded_settings(cfg).items() if k not in OUTPUT_NEUTRAL}
    diff = [k for k, v in want.items() if settings.get(k) != v]
    return f"its settings differ ({', '.join(diff)})" if diff else None


def write_view(root: Path, stem: str, view, hz) -> dict[str, str]:
    """Write one view's hazy image, clean reference and true depth / T / S maps; returns the
    frame's ``*_file_path`` entries (relative to ``root``)."""
    files = {
        "file_path": f"images/{stem}.png",
        "clean_file_path": f"clean/{stem}.png",
        "gt_depth_file_path": f"gt_depth/{stem}.npy",
        "gt_transmittance_file_path": f"gt_transmittance/{stem}.npy",
        "gt_scattering_file_path": f"gt_scattering/{stem}.npy",
    }
    write_rgb(root / files["file_path"], hz.hazy.numpy())
    write_rgb(root / files["clean_file_path"], view.clean.numpy())
    write_map(root / files["gt_depth_file_path"], view.depth_z.numpy())
    write_map(root / files["gt_transmittance_file_path"], hz.transmittance.numpy())
    write_map(root / files["gt_scattering_file_path"], hz.scattering.numpy())
    return files


def write_tracks(path: Path, cfg: SceneConfig, layout: Layout, poses, K, train, surface, source, n) -> None:
    """The first ``n`` seed points' tracks from their true ``surface`` points and ``source`` views
    (per-view lists), drawn from a random stream of their own so the cloud stays as it was."""
    true_xyz = np.concatenate(surface)[:n] if surface else np.zeros((0, 3))
    src = np.concatenate(source)[:n] if source else np.zeros(0, np.int64)
    rng = np.random.default_rng([cfg.seed, 4343])
    np.save(path, seed_tracks(layout.geometry, true_xyz, poses, K, train, cfg.seed_cloud, src, rng))


def _render_all(cfg: SceneConfig, root: Path) -> dict[str, Any]:
    t_start = time.perf_counter()
    layout = make_layout(cfg.layout, cfg.seed)
    medium = make_medium(cfg.haze, layout.medium_context(), cfg.seed, cfg.beta_scale)
    kind, poses = camera_poses(layout, cfg.trajectory, cfg.num_views)
    K = ViewIntrinsics.from_fov(cfg.width, cfg.height, cfg.fov_deg)
    train, test = split(len(poses), cfg.test_every)
    rng = np.random.default_rng([cfg.seed, 4242])
    num_points = cfg.num_points
    if num_points is None:
        num_points = default_count(cfg.seed_cloud, len(train))
    per_view_points = -(-num_points // max(len(train), 1))
    t_clean = t_haze = t_write = 0.0
    frames, pts, cols, surface, source, mean_T = [], [], [], [], [], []
    T_hist = np.zeros(1001, dtype=np.int64)  # histogram of T for the median without keeping all maps
    for i, c2w in enumerate(poses):
        t0 = time.perf_counter()
        view = render_clean(layout, c2w, K, cfg.supersample)
        t1 = time.perf_counter()
        hz = apply_medium(view, medium, cfg.samples)
        t2 = time.perf_counter()
        frames.append(frame_entry(c2w, write_view(root, f"{i:04d}", view, hz)))
        T = hz.transmittance.numpy()
        mean_T.append(float(T.mean()))
        T_hist += np.bincount(np.clip(np.rint(T.ravel() * 1000), 0, 1000).astype(np.int64), minlength=1001)
        if i in train and num_points:
            colors = view.clean if cfg.point_colors == "clean" else hz.hazy
            p, c, x = sample_points(view, hz.hazy, colors, per_view_points, cfg, rng)
            pts.append(p)
            cols.append(c)
            surface.append(x)
            source.append(np.full(len(x), i))
        t_clean += t1 - t0
        t_haze += t2 - t1
        t_write += time.perf_counter() - t2
    xyz = np.concatenate(pts)[:num_points] if pts else np.zeros((0, 3))
    rgb = np.concatenate(cols)[:num_points] if cols else np.zeros((0, 3), np.uint8)
    write_ply_points(root / "points3d.ply", xyz, rgb)
    write_tracks(root / "points3d_tracks.npy", cfg, layout, poses, K, train, surface, source, num_points)
    transforms = {
        "camera_model": "PINHOLE",
        **{"fl_x": K.fx, "fl_y": K.fy, "cx": K.cx, "cy": K.cy, "w": K.width, "h": K.height},
        "ply_file_path": "points3d.ply",
        "point_tracks_file_path": "points3d_tracks.npy",
        "train_filenames": [frames[i]["file_path"] for i in train],
        "test_filenames": [frames[i]["file_path"] for i in test],
        "frames": frames,
    }
    write_json(root / "transforms.json", transforms)
    meta = _meta(cfg, layout, medium, kind, mean_T, T_hist, len(xyz))
    meta["timings_s"] = {
        "total": round(time.perf_counter() - t_start, 3),
        "clean_render": round(t_clean, 3),
        "haze_march": round(t_haze, 3),
        "write": round(t_write, 3),
        "per_view": round((t_clean + t_haze + t_write) / len(poses), 4),
    }
    write_json(root / "synth_meta.json", meta)
    return meta


def _meta(
    cfg: SceneConfig,
    layout: Layout,
    medium: Medium,
    kind: str,
    mean_T: list[float],
    T_hist: np.ndarray,
    n_pts: int,
) -> dict[str, Any]:
    settings = recorded_settings(cfg)
    median = float(np.searchsorted(np.cumsum(T_hist), T_hist.sum() / 2.0) / 1000.0)
    return {
        "generator": "td-synth scene",
        "generator_version": GENERATOR_VERSION,
        "settings": settings,
        "layout": layout.name,
        "trajectory": kind,
        "world": "metres, z up; poses in transforms.json are OpenGL camera-to-world (nerfstudio)",
        "far_bound_m": layout.far,
        "sun_direction": layout.sun,
        "medium": medium.describe(),
        "image_formation": "hazy = clean * T + S per pixel (8-bit PNG rounding aside); "
        "T = exp(-sum beta_k Delta), S = sum T_k (1 - exp(-beta_k Delta)) L_k, midpoint samples",
        "gt_depth": "camera z-depth in metres along the pixel-centre ray; sky pixels hold the far bound's z",
        "mean_transmittance": float(np.mean(mean_T)),
        "median_transmittance": median,
        "per_view_mean_transmittance": [round(v, 5) for v in mean_T],
        "num_seed_points": n_pts,
    }
