"""Haze-lines (Berman et al., CVPR 2016) against the dark channel as a transmittance prior.

The dark channel reads generated haze too dense because the clean patches are not black; the
haze-lines prior errs the other way where a colour cluster has no haze-free member. On scenes that
carry the true T, S and depth (``td-synth scene``), per scene over the training views' surface
pixels (0.05 < T < 0.95, not at the far bound): the median ratio of optical depths, estimate over
truth (with quartiles), and the T MAE, for the dark channel and for haze-lines pooled over all
training views (one radius maximum per line), each with the views' own dark-channel airlight and
with the true mean light S / (1 - T). No training; session 69 of docs/results/medium_recovery.md
reads the table.

    python benchmarks/haze_lines_prior.py --scenes SET/* --output docs/results/haze_lines_prior
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_output import fmt, grouped_bars, publish  # noqa: E402

from components.losses.dcp import (  # noqa: E402
    dark_channel,
    default_patch,
    estimate_airlight,
    estimate_dcp,
    guided_filter,
)

RADIUS_QUANTILE = 0.99
"""A line's haze-free radius: this quantile of its pixels' distances from the airlight (robust max)."""
T_FLOOR = 0.05
ESTIMATORS = ("dcp/own", "haze-lines/own", "dcp/true", "haze-lines/true")


def sphere_points(n: int) -> np.ndarray:
    """[n, 3] near-uniform unit vectors (Fibonacci sphere): the haze-lines' directions."""
    i = np.arange(n) + 0.5
    polar, azimuth = np.arccos(1.0 - 2.0 * i / n), np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)


def line_of(img: np.ndarray, airlight: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's distance from the airlight [N] and the index of its haze-line [N]."""
    offset = img.reshape(-1, 3) - airlight  # [N, 3]
    radius = np.linalg.norm(offset, axis=1) + 1e-6  # [N]
    return radius, np.argmax((offset / radius[:, None]) @ dirs.T, axis=1)


def haze_lines_t(img: np.ndarray, airlight: np.ndarray, radius, label, r_max) -> np.ndarray:
    """T [H, W] = r / r_max of the pixel's line, at least 1 - min(I / A), guided-filtered as the
    dark channel's estimate is."""
    h, w = img.shape[:2]
    t = radius / np.maximum(r_max[label], 1e-6)  # [N]
    lower = 1.0 - np.min(img.reshape(-1, 3) / np.maximum(airlight, 1e-3), axis=1)  # [N]
    t = np.clip(np.maximum(t, lower), T_FLOOR, 1.0).reshape(h, w).astype(np.float32)
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return np.clip(guided_filter(grey, t, 4 * default_patch(h, w), 1e-3), T_FLOOR, 1.0)


def load_views(scene: Path) -> list[dict]:
    """The training views with their true T [H, W], depth [H, W], dark-channel airlight and true mean light."""
    tf = json.loads((scene / "transforms.json").read_text())
    frames = {f["file_path"]: f for f in tf["frames"]}
    views = []
    for name in tf.get("train_filenames") or list(frames):
        fr = frames[name]
        if "gt_transmittance_file_path" not in fr:
            raise SystemExit(
                f"{scene}: {name} has no gt_transmittance_file_path (make it with td-synth scene)"
            )
        img = cv2.cvtColor(cv2.imread(str(scene / name)), cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
        t_true = np.load(scene / fr["gt_transmittance_file_path"])  # [H, W]
        s_true = np.load(scene / fr["gt_scattering_file_path"])  # [H, W, 3]
        hazy = t_true < 0.9
        light = (s_true[hazy] / (1.0 - t_true[hazy])[:, None]).mean(0) if hazy.any() else np.ones(3)
        dark = dark_channel(img, default_patch(*img.shape[:2]))
        views.append(
            {"img": img, "t": t_true, "depth": np.load(scene / fr["gt_depth_file_path"]),
             "own": estimate_airlight(img, dark), "true": light}
        )  # fmt: skip
    return views


def estimates(views: list[dict], light: str, lines: int) -> dict[str, list[np.ndarray]]:
    """Per view, T from the dark channel and from haze-lines pooled over the views, with the
    airlight ``light`` (``own`` or ``true``)."""
    dirs = sphere_points(lines)
    scene_light = np.median([v[light] for v in views], axis=0)  # [3] one airlight for the pool
    pooled = [line_of(v["img"], scene_light, dirs) for v in views]
    radius = np.concatenate([p[0] for p in pooled])
    label = np.concatenate([p[1] for p in pooled])
    r_max = np.zeros(lines)
    for k in np.unique(label):
        r_max[k] = np.quantile(radius[label == k], RADIUS_QUANTILE)
    return {
        f"dcp/{light}": [estimate_dcp(v["img"], airlight=v[light]).transmittance for v in views],
        f"haze-lines/{light}": [
            haze_lines_t(v["img"], scene_light, r, lab, r_max)
            for v, (r, lab) in zip(views, pooled, strict=True)
        ],
    }


def scene_row(scene: Path, lines: int) -> dict:
    views = load_views(scene)
    far = json.loads((scene / "synth_meta.json").read_text()).get("far_bound_m", float("inf"))
    row = {"scene": scene.name}
    for light in ("own", "true"):
        for name, ts in estimates(views, light, lines).items():
            ratios, errors = [], []
            for v, t in zip(views, ts, strict=True):
                m = (v["t"] > 0.05) & (v["t"] < 0.95) & (v["depth"] < 0.95 * far)  # surfaces seen
                ratios.append(np.log(t[m]) / np.log(v["t"][m]))
                errors.append(np.abs(t[m] - v["t"][m]))
            r, e = np.concatenate(ratios), np.concatenate(errors)
            q25, med, q75 = (float(x) for x in np.quantile(r, [0.25, 0.5, 0.75]))
            row[name] = {"ratio": med, "ratio_q25": q25, "ratio_q75": q75, "t_mae": float(e.mean())}
    return row


def table(rows: list[dict]) -> str:
    head = "| scene | " + " | ".join(ESTIMATORS) + " |\n|---|" + "---|" * len(ESTIMATORS) + "\n"
    cells = lambda r: [  # noqa: E731
        f"{fmt(r[k]['ratio'], 2)} ({fmt(r[k]['ratio_q25'], 2)}-{fmt(r[k]['ratio_q75'], 2)}), "
        f"{fmt(r[k]['t_mae'])}" for k in ESTIMATORS
    ]  # fmt: skip
    body = "".join(f"| {r['scene']} | " + " | ".join(cells(r)) + " |\n" for r in rows)
    return (
        head
        + body
        + (
            "\nEach cell: median ratio of optical depths, estimate / truth (quartiles), then T MAE; "
            "`own`: each view's dark-channel airlight, `true`: the true mean light.\n"
        )
    )


def plot(rows: list[dict], path: Path) -> None:
    series = [(k, [r[k]["t_mae"] for r in rows]) for k in ESTIMATORS]
    grouped_bars(path, [r["scene"] for r in rows], series, "T MAE on seen surfaces", legend_above=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=Path, nargs="+", required=True, help="generated scene folders")
    ap.add_argument("--output", type=Path, required=True, help="output stem: writes .json, .md, .png")
    ap.add_argument("--lines", type=int, default=100, help="haze-lines (directions on the sphere)")
    args = ap.parse_args()
    rows = [scene_row(s, args.lines) for s in sorted(args.scenes)]
    names = ", ".join(s.name for s in sorted(args.scenes))
    how = f"`python benchmarks/haze_lines_prior.py --scenes SET/* --lines {args.lines}` (scenes: {names})"
    publish(
        args.output,
        rows,
        "Haze-lines against the dark channel",
        how,
        table(rows),
        plot,
    )


if __name__ == "__main__":
    main()
