"""``td-synth haze``: add haze to an existing clean dataset (the Mip-NeRF 360 "foggy" protocol).

    I = J * T + A * (1 - T),   T = exp(-beta * tau),   tau = integral of f(x) along the pixel's ray

``f = 1`` gives the protocol's homogeneous fog, ``T = exp(-beta * d)`` with ``d`` the distance
along the ray to the pixel's surface point. The heterogeneous option multiplies beta by a smooth
3D field ``f(x) = 1 + h * mean_i sin(w_i . x + phi_i)`` (three random plane waves, ``0 <= h < 1``),
integrated along the ray from the camera to the surface point in closed form, so T is exact.

Depth ``d`` comes from the dataset's depth maps (camera z-depth in dataset units) or is rendered
from a trained run (``--depth-from-run RUN/config.yml``), converted back to dataset units. Because
T decreases monotonically with tau, a target median transmittance fixes beta in closed form:
``beta = -ln(T_target) / median(tau)`` (no iterative search needed).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from torch import Tensor

from components.data.cameras import Cameras
from components.data.config import DataConfig
from components.data.images import read_depth, read_image
from components.data.loader import check_root, load_scene
from components.data.ply import write_ply_points
from components.data.scene import DataWarning, SceneData
from components.losses.depth_priors import in_image, project_points
from components.synth.generate import torch_threads
from components.synth.haze_ball import HazeBall
from components.synth.writer import (
    check_output_dir,
    frame_entry,
    staged_output,
    write_json,
    write_map,
    write_rgb,
)
from tridehaze_plugin.errors import ConfigError, UserError

DEFAULT_MEDIAN_T = 0.4
"""Target median transmittance when neither --beta nor --median-transmittance is given."""


@dataclass
class HazeConfig:
    """Synthesise haze on a clean dataset, keeping the clean images as paired ground truth."""

    data: Path
    """Clean dataset folder (nerfstudio, Blender or COLMAP; detected like td-train --data)."""
    output_dir: Path
    """Where the hazy nerfstudio dataset is written (must be new or empty unless --overwrite)."""
    beta: float | None = None
    """Extinction coefficient in 1 / dataset unit. Give this or --median-transmittance."""
    median_transmittance: float | None = None
    """Choose beta so the median transmittance over all pixels of all views is this (in (0, 1));
    default 0.4 when --beta is not given."""
    airlight: tuple[float, float, float] = (0.8, 0.8, 0.8)
    """Airlight A (RGB in [0, 1])."""
    heterogeneous: float = 0.0
    """Strength h in [0, 1) of the smooth 3D field multiplying beta (0: homogeneous fog)."""
    feature_size: float = 0.5
    """Wavelength of the heterogeneous field, as a fraction of the median scene depth."""
    depth_from_run: Path | None = None
    """A trained run's config.yml (e.g. vanilla-gs on this dataset) to render depth from; needed when
    the dataset has no depth maps, and preferred over them when given."""
    min_alpha: float = 0.5
    """Rendered depth counts only where the run's accumulated opacity reaches this; elsewhere the view's
    largest valid depth is used (background)."""
    max_depth_factor: float | None = None
    """Clamp each view's depth at this multiple of the farthest seed point it sees (the 98th
    percentile of their camera z; views seeing fewer than 10 points are left as they are). A depth
    run invents the depth of a background it never saw (statue: 5-22 units against SfM points at
    1.2-1.5), and haze made for that depth is out of any method's reach; 1.5 keeps the haze within
    what the geometry supports. None: no clamp (the depth check still reports it)."""
    haze_ball_factor: float | None = None
    """Confine the haze to a ball around the seed points: centred on their median, of radius this
    multiple of their 90th-percentile distance from it. Unlike --max-depth-factor, which shortens
    each view's march to its own clamp, this is one 3D medium every view sees alike, so a 3D method
    can recover it wherever the background lies; rays that miss the ball stay clear. None: haze
    everywhere along every ray."""
    downscale: int = 1
    """Integer image downscale of the source dataset (as td-train --downscale)."""
    parser: str = "auto"
    """Dataset parser (auto, nerfstudio, blender, colmap)."""
    seed: int = 0
    """Seed of the heterogeneous field."""
    overwrite: bool = False
    """Replace an output folder this same tool wrote before (a folder it did not write, or one
    holding files it did not write, is refused); the old one stays until the new is complete."""
    cache_dir: Path | None = None
    """Cache for undistorted / downscaled copies (default: $TRIDEHAZE_CACHE or ~/.cache/tridehaze)."""
    threads: int = 1
    """Torch CPU threads (0: torch default)."""

    def check(self) -> None:
        if self.beta is not None and self.median_transmittance is not None:
            raise ConfigError("give either --beta or --median-transmittance, not both")
        if self.beta is not None and not (math.isfinite(self.beta) and self.beta >= 0):
            raise ConfigError(f"--beta must be a finite number >= 0, got {self.beta}")
        mt = self.median_transmittance
        if mt is not None and not 0.0 < mt < 1.0:
            raise ConfigError(f"--median-transmittance must be in (0, 1), got {mt}")
        if not all(0.0 <= a <= 1.0 for a in self.airlight):
            raise ConfigError(f"--airlight must be three values in [0, 1], got {self.airlight}")
        if not 0.0 <= self.heterogeneous < 1.0:
            raise ConfigError(f"--heterogeneous must be in [0, 1), got {self.heterogeneous}")
        if not (math.isfinite(self.feature_size) and self.feature_size > 0):
            raise ConfigError(f"--feature-size must be a finite number > 0, got {self.feature_size}")
        if not 0.0 <= self.min_alpha <= 1.0:
            raise ConfigError(f"--min-alpha must be in [0, 1], got {self.min_alpha}")
        f = self.max_depth_factor
        if f is not None and not (math.isfinite(f) and f >= 1.0):
            raise ConfigError(f"--max-depth-factor must be a finite number >= 1 (or left out), got {f}")
        b = self.haze_ball_factor
        if b is not None and not (math.isfinite(b) and b > 0):
            raise ConfigError(f"--haze-ball-factor must be a finite number > 0 (or left out), got {b}")
        if b is not None and f is not None:
            raise ConfigError(
                "give --haze-ball-factor or --max-depth-factor, not both: the ball already keeps the "
                "haze off a background the points do not reach"
            )
        if self.threads < 0:
            raise ConfigError(f"--threads must be >= 0, got {self.threads}")


# --------------------------------------------------------------------------------------
# rays and the heterogeneous field


def view_rays(cams: Cameras, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Origin [3], unit world directions [H, W, 3] and distance per unit z-depth [H, W] of view ``i``."""
    W, H = int(cams.width[i]), int(cams.height[i])
    xs, ys = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    cam = np.stack(
        [
            (xs - float(cams.cx[i])) / float(cams.fx[i]),
            (ys - float(cams.cy[i])) / float(cams.fy[i]),
            np.ones_like(xs),
        ],
        -1,
    )  # [H, W, 3]
    norm = np.linalg.norm(cam, axis=-1)
    c2w = cams.camtoworlds[i].double().numpy()
    d = (cam / norm[..., None]) @ c2w[:3, :3].T
    return c2w[:3, 3], d, norm


DEPTH_BEYOND_FACTOR = 2.0
"""A pixel's depth is suspect when it exceeds this multiple of the farthest seed point its view sees."""
DEPTH_BEYOND_WARN = 0.05
"""Share of suspect pixels above which ``td-synth haze`` warns."""


def farthest_seen_points(cams: Cameras, points: Tensor, depths: list[np.ndarray]) -> list[float | None]:
    """Per view, the 98th percentile of the camera z of the seed points ``points`` [M, 3] it sees
    in an image of its depth map's size; None for a view seeing fewer than 10 points."""
    out: list[float | None] = []
    viewmats, Ks = cams.viewmats().to(points), cams.Ks().to(points)  # noqa: N806
    for i, depth in enumerate(depths):
        pc, uv = project_points(points, viewmats[i], Ks[i])  # [M, 3], [M, 2]
        seen = pc[in_image(pc, uv, depth.shape[1], depth.shape[0], near=1e-9), 2].numpy()  # [S]
        out.append(float(np.quantile(seen, 0.98)) if seen.size >= 10 else None)
    return out


def depth_beyond_points(cams: Cameras, points: Tensor, depths: list[np.ndarray]) -> float | None:
    """Share of all pixels whose depth [H, W] (z, dataset units) lies beyond ``DEPTH_BEYOND_FACTOR``
    times the farthest seed point their view sees (:func:`farthest_seen_points`; views seeing too
    few are skipped; None if none is left). A depth run renders a background it never saw at
    whatever depth its Gaussians drifted to; the haze made with that depth is then out of the
    photos' reach (docs/results/medium_recovery.md, session 24)."""
    beyond, total = 0, 0
    for depth, far in zip(depths, farthest_seen_points(cams, points, depths), strict=True):
        if far is None:
            continue
        beyond += int((depth > DEPTH_BEYOND_FACTOR * far).sum())
        total += depth.size
    return beyond / total if total else None


def clamp_to_points(
    cams: Cameras, points: Tensor, depths: list[np.ndarray], factor: float
) -> tuple[list[np.ndarray], float]:
    """Each view's depth [H, W] clamped at ``factor`` times the farthest seed point it sees (views
    seeing too few points unchanged), and the share of all pixels the clamp moved."""
    out, moved, total = [], 0, 0
    for depth, far in zip(depths, farthest_seen_points(cams, points, depths), strict=True):
        total += depth.size
        if far is None:
            out.append(depth)
            continue
        moved += int((depth > factor * far).sum())
        out.append(np.minimum(depth, factor * far))
    return out, (moved / total if total else 0.0)


def _check_depth(
    scene: SceneData, depths: list[np.ndarray], source: str, warn: bool = True
) -> dict[str, float] | None:
    """:func:`depth_beyond_points` of the dataset's seed cloud as ``synth_meta.json`` records it
    (None without a judgement), with a warning above ``DEPTH_BEYOND_WARN`` when ``warn`` (not with
    a haze ball, which keeps the haze off such a background)."""
    if scene.points is None or not len(scene.points):
        return None
    beyond = depth_beyond_points(scene.cameras, scene.points.double(), depths)
    if warn and beyond is not None and beyond > DEPTH_BEYOND_WARN:
        warnings.warn(
            f"{beyond:.0%} of the pixels' depth ({source}) lies beyond {DEPTH_BEYOND_FACTOR:g}x the farthest "
            "seed point their view sees: the haze there is made for geometry the photos may not "
            "support (a depth run invents the background it never saw); check the depth maps, "
            "confine the haze with --haze-ball-factor 1.5, clamp the depth with "
            "--max-depth-factor 1.5, or treat that part of the set with care",
            DataWarning,
            stacklevel=3,
        )
    return None if beyond is None else {"factor": DEPTH_BEYOND_FACTOR, "share": beyond}


def _clamp_depth(scene: SceneData, depths: list[np.ndarray], factor: float) -> tuple[list[np.ndarray], float]:
    """``--max-depth-factor``: :func:`clamp_to_points` with the dataset's seed cloud; a dataset
    without seed points cannot be clamped and says so."""
    if scene.points is None or not len(scene.points):
        raise UserError(
            "--max-depth-factor clamps the depth at the seed points the views see, and this dataset has none",
            fix="leave --max-depth-factor out, or use a dataset with a point cloud (COLMAP points3D)",
        )
    return clamp_to_points(scene.cameras, scene.points.double(), depths, factor)


@dataclass(frozen=True)
class WaveField:
    """``f(x) = 1 + h * mean_i sin(w_i . x + phi_i)``: smooth, positive, mean 1."""

    h: float
    waves: np.ndarray  # [3, 3] wave vectors (rad / unit)
    phases: np.ndarray  # [3]

    @staticmethod
    def make(h: float, wavelength: float, seed: int) -> WaveField:
        rng = np.random.default_rng([seed, 31337])
        dirs = rng.normal(size=(3, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        return WaveField(h, dirs * (2 * np.pi / wavelength), rng.uniform(0, 2 * np.pi, 3))

    def __call__(self, x: np.ndarray) -> np.ndarray:  # [..., 3] -> [...]
        return 1.0 + self.h * np.mean(np.sin(x @ self.waves.T + self.phases), axis=-1)

    def optical_depth(self, o: np.ndarray, d: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """Exact integral of f from ``o`` along unit ``d`` [..., 3] over ``dist`` [...]:
        ``dist * (1 + h * mean_i sin(a_i + b_i dist / 2) sinc(b_i dist / 2))``."""
        if self.h == 0.0:
            return dist
        a = o @ self.waves.T + self.phases  # [3]
        b = d @ self.waves.T  # [..., 3]
        half = b * dist[..., None] / 2
        mean = np.mean(np.sin(a + half) * np.sinc(half / np.pi), axis=-1)  # np.sinc(x) = sin(pi x) / (pi x)
        return dist * (1.0 + self.h * mean)


# --------------------------------------------------------------------------------------
# depth


def fill_invalid_depth(depth: np.ndarray, valid: np.ndarray, where: str) -> np.ndarray:
    if not valid.any():
        raise UserError(
            "a view has no valid depth at all", where=where, fix="check the depth maps or the run"
        )
    out = depth.copy()
    out[~valid] = depth[valid].max()  # holes are background: push them to the view's far end
    return out


def dataset_depths(scene: SceneData) -> list[np.ndarray]:
    """The dataset's depth maps [H, W] (dataset units, z-depth) at each view's image size."""
    out = []
    for i, p in enumerate(scene.depth_paths):
        assert p is not None
        d = read_depth(p)
        H, W = int(scene.cameras.height[i]), int(scene.cameras.width[i])
        if d.shape != (H, W):
            d = cv2.resize(d, (W, H), interpolation=cv2.INTER_NEAREST)
        out.append(fill_invalid_depth(d, np.isfinite(d) & (d > 0), str(p)))
    return out


# --------------------------------------------------------------------------------------
# main


def _unique_stems(names: list[str]) -> list[str]:
    stems = [Path(n).stem for n in names]
    if len(set(stems)) == len(stems):
        return stems
    return [f"{i:04d}_{s}" for i, s in enumerate(stems)]


RunDepths = Callable[[SceneData, Path, float], list[np.ndarray]]
"""Renders depth [H, W] (dataset units) for every view of a scene from a trained run's config.yml,
keeping depth only where the run's opacity reaches the given minimum (pipelines/evaluation/run_depth.py)."""


def haze_dataset(cfg: HazeConfig, run_depths: RunDepths | None = None) -> dict[str, Any]:
    """Write the hazy copy of ``cfg.data`` into ``cfg.output_dir``; returns the metadata written.

    ``run_depths`` serves ``--depth-from-run``: rendering a run belongs to the pipelines layer,
    which passes it in (this component never imports upward)."""
    cfg.check()
    root = check_root(cfg.data)
    out = check_output_dir(cfg.output_dir, cfg.overwrite, "td-synth")
    if out == root or root in out.parents:
        raise UserError("--output-dir must be outside the dataset folder", where=str(out))
    t0 = time.perf_counter()
    with torch_threads(cfg.threads):
        data_cfg = DataConfig(
            data=root,
            parser=cfg.parser,
            downscale=cfg.downscale,
            center_poses=False,  # keep the dataset's own units: beta is per dataset unit
            scale_poses=False,
            cache_dir=cfg.cache_dir,
        )
        scene = load_scene(data_cfg)
        depths, source = _depths(cfg, scene, root, run_depths)
        t_depth = time.perf_counter() - t0
        clamped = None
        if cfg.max_depth_factor is not None:
            depths, clamped = _clamp_depth(scene, depths, cfg.max_depth_factor)
        ball = _haze_ball(cfg, scene)
        beyond = _check_depth(scene, depths, source, warn=ball is None)
        taus, field, median_depth = _optical_depths(cfg, scene, depths, ball)
        beta = _solve_beta(cfg, taus)
        with staged_output(out, cfg.overwrite, "td-synth") as tmp:
            meta = _write(cfg, scene, tmp, depths, taus, beta)
            meta.update(
                source=str(root),
                depth_source=source,
                depth_beyond_points=beyond,
                depth_clamp=None if clamped is None else {"factor": cfg.max_depth_factor, "share": clamped},
                haze_ball=None if ball is None else _ball_meta(cfg, scene, ball, taus),
                median_distance=median_depth,
                heterogeneous_field={
                    "h": cfg.heterogeneous,
                    "wavelength": cfg.feature_size * median_depth,
                    "waves": field.waves.tolist(),
                    "phases": field.phases.tolist(),
                },
                timings_s={"depth": round(t_depth, 3), "total": round(time.perf_counter() - t0, 3)},
            )
            write_json(tmp / "synth_meta.json", meta)
    return meta


def _depths(
    cfg: HazeConfig, scene: SceneData, root: Path, run_depths: RunDepths | None
) -> tuple[list[np.ndarray], str]:
    """Each view's z-depth [H, W] in dataset units, from the run or the dataset's maps, and which."""
    if cfg.depth_from_run is not None:
        if run_depths is None:
            raise ValueError("haze_dataset: --depth-from-run needs a run_depths renderer")
        return run_depths(scene, cfg.depth_from_run, cfg.min_alpha), f"run {cfg.depth_from_run}"
    if all(p is not None for p in scene.depth_paths):
        return dataset_depths(scene), "dataset depth maps"
    missing = sum(p is None for p in scene.depth_paths)
    raise UserError(
        f"{missing} of {len(scene)} views have no depth map",
        where=str(root),
        fix="pass --depth-from-run RUN/config.yml (e.g. a vanilla-gs run trained on this dataset)",
    )


def _haze_ball(cfg: HazeConfig, scene: SceneData) -> HazeBall | None:
    """``--haze-ball-factor``: the ball around the dataset's seed cloud; a dataset without seed
    points has nothing to centre it on and says so."""
    if cfg.haze_ball_factor is None:
        return None
    if scene.points is None or not len(scene.points):
        raise UserError(
            "--haze-ball-factor centres the haze on the dataset's seed points, and this dataset has none",
            fix="leave --haze-ball-factor out, or use a dataset with a point cloud (COLMAP points3D)",
        )
    return HazeBall.around(scene.points.double().numpy(), cfg.haze_ball_factor)


def _optical_depths(
    cfg: HazeConfig, scene: SceneData, depths: list[np.ndarray], ball: HazeBall | None
) -> tuple[list[np.ndarray], WaveField, float]:
    """Each view's optical depth per unit beta [H, W] (the field integrated along the ray to the
    surface, within the ball where there is one), the field, and the median ray distance."""
    rays = [view_rays(scene.cameras, i) for i in range(len(scene))]
    dists = [z * norm for z, (_, _, norm) in zip(depths, rays, strict=True)]  # z-depth -> ray distance
    median_depth = float(np.median(np.concatenate([d.ravel() for d in dists])))
    field = WaveField.make(cfg.heterogeneous, cfg.feature_size * median_depth, cfg.seed)
    taus = []
    for (o, d, _), dist in zip(rays, dists, strict=True):
        if ball is None:
            taus.append(field.optical_depth(o, d, dist))
            continue
        enter, length = ball.chord(o, d, dist)  # [H, W] each
        taus.append(field.optical_depth(o + enter[..., None] * d, d, length))
    return taus, field, median_depth


def _ball_meta(cfg: HazeConfig, scene: SceneData, ball: HazeBall, taus: list[np.ndarray]) -> dict[str, Any]:
    """What ``synth_meta.json`` records of the ball: its size, the cameras inside it and the share
    of pixels whose ray never meets the haze."""
    centres = scene.cameras.camtoworlds[:, :3, 3].double().numpy()  # [N, 3]
    clear = sum(int((t <= 0.0).sum()) for t in taus) / sum(t.size for t in taus)
    return {
        "factor": cfg.haze_ball_factor,
        "centre": ball.centre.tolist(),
        "radius": ball.radius,
        "cameras_inside": int(ball.contains(centres).sum()),
        "clear_share": clear,
    }


def _target(cfg: HazeConfig) -> float | None:
    """The median transmittance to hit (None when beta is given)."""
    if cfg.beta is not None:
        return None
    return cfg.median_transmittance if cfg.median_transmittance is not None else DEFAULT_MEDIAN_T


def _solve_beta(cfg: HazeConfig, taus: list[np.ndarray]) -> float:
    target = _target(cfg)
    if target is None:
        return float(cfg.beta)  # type: ignore[arg-type]
    med = float(np.median(np.concatenate([t.ravel() for t in taus])))
    if med <= 0:
        raise UserError(
            "at least half of the pixels see no haze (depths of zero, or rays that miss the haze "
            "ball), so no beta gives that median transmittance",
            fix="give --beta instead, or a larger --haze-ball-factor",
        )
    return -math.log(target) / med


def _intrinsics(scene: SceneData, i: int) -> dict[str, float | int]:
    cams = scene.cameras
    return {"fl_x": float(cams.fx[i]), "fl_y": float(cams.fy[i]), "cx": float(cams.cx[i]),
            "cy": float(cams.cy[i]), "w": int(cams.width[i]), "h": int(cams.height[i])}  # fmt: skip


def _write_transforms(scene: SceneData, root: Path, frames: list[dict[str, Any]]) -> None:
    """transforms.json with the source's splits, and its seed points (points3d.ply) and their
    tracks (points3d_tracks.npy; ``frames`` in the scene's view order) when it has any."""
    transforms: dict[str, Any] = {"camera_model": "PINHOLE", "frames": frames}
    if scene.points is not None and len(scene.points):
        rgb = None
        if scene.point_colors is not None:
            rgb = np.clip(scene.point_colors.numpy() * 255.0 + 0.5, 0, 255).astype(np.uint8)
        write_ply_points(root / "points3d.ply", scene.points.double().numpy(), rgb)
        transforms["ply_file_path"] = "points3d.ply"
        if scene.point_tracks is not None:
            pairs = np.stack([scene.point_tracks.point, scene.point_tracks.view], axis=1)  # [K, 2]
            np.save(root / "points3d_tracks.npy", pairs.astype(np.int64))
            transforms["point_tracks_file_path"] = "points3d_tracks.npy"
    transforms["train_filenames"] = [frames[i]["file_path"] for i in scene.train_indices]
    transforms["test_filenames"] = [frames[i]["file_path"] for i in scene.test_indices]
    write_json(root / "transforms.json", transforms)


def _write(
    cfg: HazeConfig,
    scene: SceneData,
    root: Path,
    depths: list[np.ndarray],
    taus: list[np.ndarray],
    beta: float,
) -> dict[str, Any]:
    A = np.asarray(cfg.airlight, np.float64)
    stems = _unique_stems(scene.names())
    frames, all_T, mean_T = [], [], []
    for i, stem in enumerate(stems):
        J = read_image(scene.image_paths[i]).astype(np.float64) / 255.0  # [H, W, 3]
        T = np.exp(-beta * taus[i])  # [H, W]
        hazy = J * T[..., None] + A * (1.0 - T[..., None])
        files = {
            "file_path": f"images/{stem}.png",
            "clean_file_path": f"clean/{stem}.png",
            "gt_depth_file_path": f"gt_depth/{stem}.npy",
            "gt_transmittance_file_path": f"gt_transmittance/{stem}.npy",
        }
        write_rgb(root / files["file_path"], hazy)
        write_rgb(root / files["clean_file_path"], read_image(scene.image_paths[i]))
        write_map(root / files["gt_depth_file_path"], depths[i])
        write_map(root / files["gt_transmittance_file_path"], T)
        frames.append(
            frame_entry(scene.cameras.camtoworlds[i].double().numpy(), files, _intrinsics(scene, i))
        )
        all_T.append(T.astype(np.float32).ravel())
        mean_T.append(float(T.mean()))
    _write_transforms(scene, root, frames)
    T_all = np.concatenate(all_T)
    return {
        "generator": "td-synth haze",
        "model": "I = J * T + A * (1 - T), T = exp(-beta * integral of f along the ray to the surface point)",
        "beta": beta,
        "beta_units": "1 / dataset unit",
        "airlight": list(cfg.airlight),
        "target_median_transmittance": _target(cfg),
        "median_transmittance": float(np.median(T_all)),
        "mean_transmittance": float(T_all.mean()),
        "per_view_mean_transmittance": [round(v, 5) for v in mean_T],
        "gt_depth": "camera z-depth in dataset units (the depth the haze was made with)",
        "downscale": cfg.downscale,
    }
