"""How good is a seed cloud? Real SfM on a generated scene's hazy photos against td-synth's cloud.

For each ``td-synth`` scene (which carries its true cameras, depth and transmittance):

1. ``td-process-data images`` reconstructs the hazy photos from scratch (unknown poses, as a user
   would); its camera centres are aligned to the true ones by a similarity (Umeyama), and every
   observation of every 3D point (point, view, keypoint) is compared with the truth at that
   keypoint: relative depth error (z - z_true) / z_true and the true transmittance there;
2. the scene's own ``points3d.ply`` (``model``: the cloud td-synth wrote) gets the same numbers, each point observed in the train view
   where its depth agrees best with the visible surface.

It prints and writes (JSON + markdown + plot): registered views, points per 1000 pixels, where
the observations fall by true T against where the pixels are (a ratio > 1: over-represented),
the median / 90th-percentile relative depth error by depth tercile, and the outlier share
(|relative error| > 10 %).

    # the eleven scenes of docs/results/seed_cloud.md (the clean clouds from a second, clean run):
    for s in courtyard-patchy courtyard-homogeneous courtyard-dense courtyard-height courtyard-none \
             courtyard-sunlit street-sunlit room-dense room-patchy room-homogeneous field-height; do
      td-synth scene --output-dir scenes/$s --layout ${s%%-*} --haze ${s#*-} --width 320 --height 240 \
               --num-views 32 --seed 3
      td-synth scene --output-dir clean/$s --layout ${s%%-*} --haze ${s#*-} --width 320 --height 240 \
               --num-views 32 --seed 3 --seed-cloud clean
      cp clean/$s/points3d.ply scenes/$s/points3d_clean.ply
    done
    python benchmarks/seed_cloud.py --scenes scenes/* --work sfm --output docs/results/seed_cloud \
        --clouds clean=points3d_clean.ply
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from components.data.ply import read_ply_points  # noqa: E402
from components.sfm.align import umeyama  # noqa: E402

T_BINS = ((0.0, 0.3), (0.3, 0.5), (0.5, 0.7), (0.7, 1.01))
OUTLIER = 0.10
"""A point whose depth is off by more than this fraction counts as an outlier."""
BAD_CAMERAS = 0.05
"""A reconstruction whose aligned camera centres are off by more than this share of the camera
extent (median) is wrong (e.g. a focal length far from the truth): its points are not measured."""
MIN_REGISTERED = 0.25
"""Share of the views a reconstruction must register to be measured (two views say nothing)."""
GL_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def true_views(scene: Path) -> dict[str, dict]:
    """Image name -> true w2c (OpenCV) [4, 4], K [3, 3], depth [H, W], T [H, W], split."""
    tf = json.loads((scene / "transforms.json").read_text())
    train = set(tf.get("train_filenames", []))
    K = np.array([[tf["fl_x"], 0, tf["cx"]], [0, tf["fl_y"], tf["cy"]], [0, 0, 1.0]])
    out = {}
    for fr in tf["frames"]:
        c2w = np.asarray(fr["transform_matrix"], np.float64) @ GL_CV  # [4, 4] OpenCV
        t = np.load(scene / fr["gt_transmittance_file_path"])
        out[Path(fr["file_path"]).name] = {
            "w2c": np.linalg.inv(c2w),
            "K": K,
            "depth": np.load(scene / fr["gt_depth_file_path"]),
            "T": t if t.ndim == 2 else t[..., 0],
            "train": fr["file_path"] in train,
        }
    return out


def observe(view: dict, xyz: np.ndarray, uv: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per point of ``xyz`` [N, 3] (world): camera z, pixel (its keypoint ``uv`` if given, else its
    projection), the true depth and T there, and whether the pixel is inside the image."""
    cam = xyz @ view["w2c"][:3, :3].T + view["w2c"][:3, 3]  # [N, 3]
    z = cam[:, 2]
    if uv is None:
        proj = cam @ view["K"].T
        uv = proj[:, :2] / np.maximum(proj[:, 2:3], 1e-9)
    h, w = view["depth"].shape[:2]
    u, v = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    inside = (z > 1e-6) & (u >= 0) & (v >= 0) & (u < w) & (v < h)
    uc, vc = np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)
    return {"z": z, "z_true": view["depth"][vc, uc], "T": view["T"][vc, uc], "inside": inside}


def known_focal_factor(views: dict[str, dict]) -> float:
    """The true focal length over the longest image side, from :func:`true_views` (what a user who
    knows the lens passes as ``--focal-factor``)."""
    view = next(iter(views.values()))
    return float(view["K"][0, 0]) / max(view["depth"].shape)


def run_sfm(scene: Path, work: Path, enhance: str, focal_factor: float | None = None) -> Path:
    out = work / f"{scene.name}-{enhance}{'' if focal_factor is None else '-focal'}"
    if not (out / "sparse" / "0").is_dir():
        cmd = [sys.executable, "-m", "tridehaze_plugin.cli.process_data", "images", "--data", str(scene / "images"),
               "--output-dir", str(out), "--camera-model", "SIMPLE_PINHOLE", "--threads", "1", "--overwrite",
               "--enhance", enhance]  # fmt: skip
        if focal_factor is not None:
            cmd += ["--focal-factor", f"{focal_factor:.6f}", "--no-refine-focal"]
        subprocess.run(cmd, check=True, cwd=Path(__file__).resolve().parents[1])
    return out / "sparse" / "0"


def align(rec, views: dict[str, dict]) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Similarity from the SfM frame to the true one, from camera centres *and* orientations: a
    walk's centres are nearly collinear, which leaves a centres-only fit free to roll about the
    line. Scale first from the centres' spreads, then one Umeyama fit on the centres plus a point
    along each camera axis (at a tenth of the true extent, the same length in both frames).
    Returns (s, R, t) and each registered camera's centre error after the fit [N]."""
    est_c, ref_c, est_r, ref_r = [], [], [], []
    for im in rec.images.values():
        m = np.asarray(im.cam_from_world().matrix())  # [3, 4]
        est_c.append(-m[:, :3].T @ m[:, 3])
        est_r.append(m[:, :3])
        ref_c.append(np.linalg.inv(views[im.name]["w2c"])[:3, 3])
        ref_r.append(views[im.name]["w2c"][:3, :3])
    est_c, ref_c = np.stack(est_c), np.stack(ref_c)  # [N, 3]
    spread = lambda c: float(np.sqrt(((c - c.mean(0)) ** 2).sum(1).mean()))  # noqa: E731
    scale = spread(ref_c) / max(spread(est_c), 1e-12)
    length = 0.1 * spread(ref_c)
    src, dst = [est_c], [ref_c]
    for k in range(3):
        src.append(est_c + np.stack([r[k] for r in est_r]) * length / scale)  # row k of w2c = axis k
        dst.append(ref_c + np.stack([r[k] for r in ref_r]) * length)
    s, R, t = umeyama(np.concatenate(src), np.concatenate(dst))
    return s, R, t, np.linalg.norm(est_c @ (s * R).T + t - ref_c, axis=1)


def load_aligned(model: Path, views: dict[str, dict]):
    """An SfM model and its similarity (s, R, t) to the true frame; raises on a failed or wrong
    reconstruction (too few views registered, cameras far from the true ones)."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(model))
    if len(rec.images) < MIN_REGISTERED * len(views):
        raise ValueError(f"only {len(rec.images)} of {len(views)} views registered")
    s, R, t, err = align(rec, views)
    centres = np.stack([np.linalg.inv(v["w2c"])[:3, 3] for v in views.values()])
    extent = float(np.sqrt(((centres - centres.mean(0)) ** 2).sum(1).mean()))
    if np.median(err) > BAD_CAMERAS * extent:
        raise ValueError(
            f"wrong reconstruction: median camera centre error {100 * np.median(err) / extent:.0f} % of the "
            f"camera extent ({len(rec.images)} views registered)"
        )
    return rec, s, R, t


def sfm_observations(model: Path, views: dict[str, dict]) -> tuple[dict, int]:
    """Observations of the SfM points in the true frame, and the number of registered views."""
    rec, s, R, t = load_aligned(model, views)
    rows: dict[str, list] = {"z": [], "z_true": [], "T": [], "inside": [], "point": []}
    for pid, p in rec.points3D.items():
        x = s * R @ np.asarray(p.xyz) + t  # [3] true frame
        for el in p.track.elements:
            im = rec.images[el.image_id]
            uv = np.asarray(im.points2D[el.point2D_idx].xy)[None]  # [1, 2]
            o = observe(views[im.name], x[None], uv)
            for k in ("z", "z_true", "T", "inside"):
                rows[k].append(o[k][0])
            rows["point"].append(pid)
    return {k: np.asarray(v) for k, v in rows.items()}, len(rec.images)


def cloud_observations(ply: Path, views: dict[str, dict]) -> dict[str, np.ndarray]:
    """Observations of a seed cloud in the true frame: each point in the train view where its depth
    agrees best with the visible surface (the view it was most likely drawn from; this flatters a
    cloud slightly, never the other way); a point inside no view is left out."""
    xyz, _ = read_ply_points(ply)
    best_err = np.full(len(xyz), np.inf)
    best: dict[str, np.ndarray] = {k: np.zeros(len(xyz)) for k in ("z", "z_true", "T")}
    for v in views.values():
        if not v["train"]:
            continue
        o = observe(v, xyz)
        err = np.where(o["inside"], np.abs(o["z"] - o["z_true"]) / np.maximum(o["z_true"], 1e-9), np.inf)
        better = err < best_err
        best_err[better] = err[better]
        for k in best:
            best[k][better] = o[k][better]
    keep = np.isfinite(best_err)
    return {**{k: v[keep] for k, v in best.items()}, "inside": np.ones(int(keep.sum()), bool),
            "point": np.flatnonzero(keep)}  # fmt: skip


def summarise(obs: dict[str, np.ndarray], views: dict[str, dict], registered: int, pixels: int) -> dict:
    ins = obs["inside"] & (obs["z_true"] > 0)
    rel = (obs["z"][ins] - obs["z_true"][ins]) / obs["z_true"][ins]
    T, zt = obs["T"][ins], obs["z_true"][ins]
    pix_T = np.concatenate([v["T"].ravel() for v in views.values() if v["train"]])
    coverage = {}
    for lo, hi in T_BINS:
        share_obs = float(((T >= lo) & (T < hi)).mean()) if len(T) else 0.0
        share_pix = float(((pix_T >= lo) & (pix_T < hi)).mean())
        coverage[f"{lo:.1f}-{min(hi, 1.0):.1f}"] = {"obs": share_obs, "pixels": share_pix,
                                                    "ratio": share_obs / share_pix if share_pix else None}  # fmt: skip
    by_depth = {}
    if len(zt):
        edges = np.quantile(zt, [0, 1 / 3, 2 / 3, 1])
        for i, name in enumerate(("near", "mid", "far")):
            m = (zt >= edges[i]) & (zt <= edges[i + 1])
            a = np.abs(rel[m])
            by_depth[name] = {"depth": float(np.median(zt[m])), "median": float(np.median(a)),
                              "p90": float(np.quantile(a, 0.9))}  # fmt: skip
    points = len(np.unique(obs["point"]))
    bad = np.abs(rel) > OUTLIER
    return {
        "registered": registered,
        "views": len(views),
        "points": points,
        "points_per_kpixel": 1000.0 * points / pixels,
        "observations": int(len(obs["z"])),
        "coverage_by_T": coverage,
        "rel_depth_error_by_depth": by_depth,
        "rel_depth_error_median": float(np.median(np.abs(rel))) if len(rel) else None,
        "outlier_share": float(bad.mean()) if len(rel) else None,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="+", type=Path, required=True)
    ap.add_argument("--work", type=Path, required=True, help="folder for the SfM reconstructions (reused)")
    ap.add_argument("--output", type=Path, required=True, help="path stem of the .json / .md / .png written")
    ap.add_argument(
        "--enhance", default="clahe", help="td-process-data --enhance (CLAHE: what hazy photos need)"
    )
    ap.add_argument(
        "--clouds", nargs="*", default=[], help="extra seed clouds per scene: NAME=relative/path.ply"
    )
    ap.add_argument(
        "--known-focal", action="store_true",
        help="give SfM each scene's true focal length, fixed (--focal-factor F --no-refine-focal)",
    )  # fmt: skip
    args = ap.parse_args()
    results = {}
    for scene in args.scenes:
        views = true_views(scene)
        pixels = sum(v["depth"].size for v in views.values() if v["train"])
        entry = {}
        try:
            focal = known_focal_factor(views) if args.known_focal else None
            obs, reg = sfm_observations(run_sfm(scene, args.work, args.enhance, focal), views)
            entry["sfm"] = summarise(obs, views, reg, pixels)
        except (subprocess.CalledProcessError, ValueError) as e:
            entry["sfm"] = {"error": str(e)}
        for name, rel in [("model", "points3d.ply"), *(c.split("=", 1) for c in args.clouds)]:
            if (scene / rel).is_file():
                entry[name] = summarise(cloud_observations(scene / rel, views), views, len(views), pixels)
        results[scene.name] = entry
        print(scene.name, json.dumps({k: _short(v) for k, v in entry.items()}), flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.with_suffix(".json").write_text(json.dumps(results, indent=2) + "\n")
    md = markdown(results)
    args.output.with_suffix(".md").write_text(md)
    plot(results, args.output.with_suffix(".png"))
    print(md)


def _short(s: dict) -> dict:
    if "error" in s:
        return s
    return {"reg": s["registered"], "pts/kpx": round(s["points_per_kpixel"], 2),
            "med": round(s["rel_depth_error_median"] or -1, 4), "out": round(s["outlier_share"] or -1, 3)}  # fmt: skip


def markdown(results: dict) -> str:
    bins = [f"{lo:.1f}-{min(hi, 1.0):.1f}" for lo, hi in T_BINS]
    head = ["scene", "cloud", "views", "pts / kpx", *(f"T {b}" for b in bins), "depth err near / mid / far (median)",
            "far p90", "outliers"]  # fmt: skip
    lines = [
        "# Seed clouds: real SfM on generated hazy views against td-synth's clouds",
        "",
        "Written by `python benchmarks/seed_cloud.py` (command in its docstring). `sfm`: "
        "`td-process-data images --enhance clahe` on the hazy views, aligned to the true cameras; "
        "`model`: the cloud td-synth writes by default (`--seed-cloud sfm`); `clean`: `--seed-cloud clean`. "
        "Discussion: docs/synth.md.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for scene, entry in results.items():
        for cloud, s in entry.items():
            if "error" in s:
                lines.append(f"| {scene} | {cloud} | failed: {s['error']} |")
                continue
            d = s["rel_depth_error_by_depth"]
            cov = [f"{s['coverage_by_T'][b]['ratio']:.2f}" if s["coverage_by_T"][b]["ratio"] is not None else "-"
                   for b in bins]  # fmt: skip
            errs = " / ".join(f"{100 * d[k]['median']:.2f} %" for k in ("near", "mid", "far") if k in d)
            lines.append(
                f"| {scene} | {cloud} | {s['registered']}/{s['views']} | {s['points_per_kpixel']:.2f} | "
                + " | ".join(cov)
                + f" | {errs} | {100 * d.get('far', {}).get('p90', float('nan')):.1f} % | "
                f"{100 * s['outlier_share']:.1f} % |"
            )
    note = ("\nT columns: share of observations in that true-T bin over the share of pixels there "
            "(1 = unbiased, < 1 = under-represented). Depth error: |z - z_true| / z_true per depth tercile.\n")  # fmt: skip
    return "\n".join(lines) + "\n" + note


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bins = [f"{lo:.1f}-{min(hi, 1.0):.1f}" for lo, hi in T_BINS]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    styles = {"sfm": "tab:red", "model": "tab:blue"}
    for entry in results.values():
        for cloud, s in entry.items():
            if "error" in s:
                continue
            c = styles.get(cloud, "tab:green")
            r = [
                np.nan if s["coverage_by_T"][b]["ratio"] is None else s["coverage_by_T"][b]["ratio"]
                for b in bins
            ]
            axes[0].plot(range(len(bins)), r, marker="o", color=c, alpha=0.6, label=cloud)
            d = s["rel_depth_error_by_depth"]
            axes[1].plot([0, 1, 2], [100 * d[k]["median"] for k in ("near", "mid", "far")], marker="o", color=c,
                         alpha=0.6, label=cloud)  # fmt: skip
    axes[0].set_xticks(range(len(bins)), [f"T {b}" for b in bins])
    axes[0].set_ylabel("observations / pixels (share ratio)")
    axes[0].axhline(1.0, color="gray", lw=0.8, ls="--")
    axes[1].set_xticks([0, 1, 2], ["near", "mid", "far"])
    axes[1].set_ylabel("median |depth error| (%)")
    axes[1].set_yscale("log")
    save_figure(fig, axes, path)


def save_figure(fig, axes, path: Path) -> None:
    """One legend entry per label on each axis (lines share labels per cloud), grid, save, close."""
    import matplotlib.pyplot as plt

    for ax in axes:
        h, lab = ax.get_legend_handles_labels()
        ax.legend(
            dict(zip(lab, h, strict=False)).values(), dict(zip(lab, h, strict=False)).keys(), fontsize=8
        )
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
