"""How far restoration could go on a generated set, and where each run stands (no training here).

Per scene of a ``td-bench restoration`` set, side by side:

* **the photos with the true medium**: each test photo inverted with the generator's true T and S,
  J = (I - S) / max(T, t0) + the true light where T < t0 (the dark channel's clamp), at the t0 of
  ``T0S`` that scores best on the scene: what the test photos themselves carry, with no 3D at all;
* **arms**: finished ``td-bench restoration`` runs, ``NAME=FOLDER:METHOD`` (FOLDER holds
  ``seed<N>/results/<scene>/<METHOD>.json``), mean over their seeds with the spread: e.g. the
  default on the hazy photos, ``vanilla-gs`` on the set's haze-free photos (the novel-view ceiling
  of a scene fitted from clean photos with the same cameras and seed cloud), runs through a held
  scene (``--pipeline.scene-from``).

``--make-clean-set OUT`` writes the haze-free copy of ``--set-dir`` the ceiling runs train on: each
scene's clean photos as its inputs (links), the same cameras, seed cloud and tracks, and no true
medium maps (nothing to recover).

    python benchmarks/restoration_ceilings.py --set-dir SET --make-clean-set CLEAN
    td-bench restoration --set-dir CLEAN --output-dir CEIL --methods vanilla-gs --seeds 42 7
    python benchmarks/restoration_ceilings.py --set-dir SET --arms default=BASE:tri-dehaze \\
        clean-photos=CEIL:vanilla-gs --output docs/results/restoration_ceilings
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_output import fmt, grouped_bars, psnr_of_mse, publish  # noqa: E402
from paired_restoration import load_arm as paired_load_arm  # noqa: E402
from paired_restoration import result_value  # noqa: E402

T0S = (0.0, 0.05, 0.1, 0.15)
"""The clamps tried for the true-medium inversion (0: none)."""
MEDIUM_KEYS = ("gt_transmittance_file_path", "gt_scattering_file_path")
"""The true medium maps a haze-free copy drops."""
LINKED = ("clean", "gt_depth")
"""Folders of a scene the haze-free copy links (its photos come from ``clean``)."""
COPIED = ("points3d.ply", "points3d_tracks.npy", "synth_meta.json")
"""Files of a scene the haze-free copy takes as they are (where the scene has them)."""


def _read_image(path: Path) -> np.ndarray:
    """An 8- or 16-bit PNG as float RGB [H, W, 3] in [0, 1]."""
    im = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if im is None:
        raise SystemExit(f"error: cannot read {path}")
    scale = 65535.0 if im.dtype == np.uint16 else 255.0
    return im[..., ::-1].astype(np.float64) / scale


def _test_frames(scene: Path) -> list[dict]:
    meta = json.loads((scene / "transforms.json").read_text())
    test = set(meta.get("test_filenames", []))
    return [f for f in meta["frames"] if f["file_path"] in test]


def true_inversion(scene: Path) -> dict:
    """Restoration PSNR of the test photos inverted with the true medium, per clamp t0 of ``T0S``."""
    errors: dict[float, list[float]] = {t0: [] for t0 in T0S}
    for f in _test_frames(scene):
        if not all(k in f for k in MEDIUM_KEYS):
            return {}
        hazy, clean = _read_image(scene / f["file_path"]), _read_image(scene / f["clean_file_path"])
        T = np.load(scene / f[MEDIUM_KEYS[0]]).astype(np.float64)  # [H, W] or [H, W, 1]
        T = T.reshape(T.shape[0], T.shape[1], 1)
        S = np.load(scene / f[MEDIUM_KEYS[1]]).astype(np.float64)  # [H, W, 3]
        light = S / np.clip(1.0 - T, 1e-3, None)  # [H, W, 3]
        for t0 in T0S:
            Tc = np.maximum(T, max(t0, 1e-4))
            J = np.clip((hazy - light * (1.0 - Tc)) / Tc, 0.0, 1.0)  # [H, W, 3]
            errors[t0].append(float(np.mean((J - clean) ** 2)))
    return {str(t0): psnr_of_mse(statistics.fmean(e)) for t0, e in errors.items() if e}


def load_arm(folder: Path, method: str) -> dict[str, dict[int, dict]]:
    """scene -> seed -> the run's result, for the finished runs of one arm."""
    out: dict[str, dict[int, dict]] = {}
    for (scene, seed), result in paired_load_arm(folder, method).items():
        out.setdefault(scene, {})[seed] = result
    return out


def arm_cell(runs: dict[int, dict]) -> dict:
    """Mean restoration PSNR over an arm's seeds of one scene, its spread, and T / S MAE."""
    psnrs = [v for v in (result_value(r, ("restoration", "psnr")) for r in runs.values()) if v is not None]
    cell: dict = {
        "seeds": sorted(runs),
        "psnr": statistics.fmean(psnrs) if psnrs else None,
        "spread": max(psnrs) - min(psnrs) if len(psnrs) > 1 else None,
    }
    for key in ("t_mae", "t_mae_true_depth", "s_mae", "s_mae_true_depth"):
        vals = [v for v in (result_value(r, ("medium", key)) for r in runs.values()) if v is not None]
        cell[key] = statistics.fmean(vals) if vals else None
    return cell


def rows_of(set_dir: Path, arms: list[tuple[str, Path, str]]) -> list[dict]:
    loaded = [(name, load_arm(folder, method)) for name, folder, method in arms]
    scenes = sorted(
        {s for _, runs in loaded for s in runs} or {p.name for p in set_dir.iterdir() if p.is_dir()}
    )
    rows = []
    for scene in scenes:
        inv = true_inversion(set_dir / scene) if (set_dir / scene / "transforms.json").is_file() else {}
        best = max(inv.items(), key=lambda kv: kv[1]) if inv else None
        row = {"scene": scene, "true_inversion": inv, "true_inversion_best": best}
        row["arms"] = {name: arm_cell(runs.get(scene, {})) for name, runs in loaded}
        rows.append(row)
    return rows


def _pair(cell: dict, key: str) -> str:
    """``key`` at the rendered depth with its value at the true depth in brackets."""
    return f"{fmt(cell.get(key))} ({fmt(cell.get(key + '_true_depth'))})"


def table(rows: list[dict], names: list[str]) -> str:
    head = "| scene | the photos with the true medium (best t0) | " + " | ".join(
        f"{n}: PSNR (spread) / T MAE / S MAE (at the true depth)" for n in names
    )
    lines = [head + " |", "|" + "---|" * (len(names) + 2)]
    for r in rows:
        best = r["true_inversion_best"]
        cells = [f"{fmt(best[1], 2)} ({best[0]})" if best else "-"]
        for n in names:
            c = r["arms"][n]
            spread = f" ({fmt(c['spread'], 2)})" if c["spread"] is not None else ""
            medium = f"{_pair(c, 't_mae')} / {_pair(c, 's_mae')}"
            cells.append(f"{fmt(c['psnr'], 2)}{spread} / {medium}")
        lines.append(f"| {r['scene']} | " + " | ".join(cells) + " |")
    bests = [r["true_inversion_best"][1] for r in rows if r["true_inversion_best"]]
    means = [fmt(statistics.fmean(bests), 2) if bests and len(bests) == len(rows) else "-"]
    for n in names:
        cells = [r["arms"][n] for r in rows]
        mean = {k: [c[k] for c in cells] for k in cells[0]} if cells else {}
        mean = {
            k: statistics.fmean(v) if v and None not in v else None for k, v in mean.items() if k != "seeds"
        }
        means.append(f"{fmt(mean.get('psnr'), 2)} / {_pair(mean, 't_mae')} / {_pair(mean, 's_mae')}")
    lines.append("| **mean** | " + " | ".join(means) + " |")
    note = (
        "\nRestoration PSNR in dB over each scene's test views, mean over the arm's seeds (spread: "
        "max - min). T and S MAE with the medium marched to the rendered depth (to the true depth "
        "in brackets). The true-medium inversion uses each test photo alone; t0 is the clamp "
        f"(of {', '.join(str(t) for t in T0S)}) that scores best on the scene.\n"
    )
    return "\n".join(lines) + "\n" + note


def plot(rows: list[dict], path: Path) -> None:
    names = list(rows[0]["arms"]) if rows else []
    series = [("photos, true medium", [(r["true_inversion_best"] or (0, 0.0))[1] for r in rows])]
    series += [(n, [r["arms"][n]["psnr"] or 0.0 for r in rows]) for n in names]
    grouped_bars(path, [r["scene"] for r in rows], series, "restoration PSNR (dB)", legend_above=True)


def make_clean_set(set_dir: Path, out: Path) -> None:
    """The haze-free copy of every scene of ``set_dir`` under ``out`` (see the module's docstring)."""
    scenes = sorted(p for p in set_dir.iterdir() if (p / "transforms.json").is_file())
    if not scenes:
        raise SystemExit(f"error: no scene (a folder with transforms.json) in {set_dir}")
    for scene in scenes:
        dst = out / scene.name
        dst.mkdir(parents=True, exist_ok=True)
        if not (scene / "clean").is_dir():
            raise SystemExit(f"error: {scene} has no clean/ photos to train on")
        for name in LINKED:
            link = dst / name
            if (scene / name).exists() and not link.exists():
                link.symlink_to((scene / name).resolve())
        if not (dst / "images").exists():
            (dst / "images").symlink_to((scene / "clean").resolve())
        for name in COPIED:
            if (scene / name).is_file():
                shutil.copy2(scene / name, dst / name)
        meta = json.loads((scene / "transforms.json").read_text())
        for frame in meta["frames"]:
            for key in MEDIUM_KEYS:
                frame.pop(key, None)
        (dst / "transforms.json").write_text(json.dumps(meta, indent=1))
    print(f"wrote the haze-free copy of {len(scenes)} scenes to {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--set-dir", type=Path, required=True, help="the hazy td-bench restoration set")
    ap.add_argument("--make-clean-set", type=Path, help="write the set's haze-free copy here and stop")
    ap.add_argument("--arms", nargs="*", default=[], metavar="NAME=FOLDER:METHOD")
    ap.add_argument("--output", type=Path, help="output stem: writes .json, .md, .png")
    args = ap.parse_args()
    if args.make_clean_set is not None:
        make_clean_set(args.set_dir, args.make_clean_set)
        return
    if args.output is None:
        ap.error("--output is required (or --make-clean-set)")
    arms = []
    for spec in args.arms:
        name, _, rest = spec.partition("=")
        folder, _, method = rest.rpartition(":")
        if not name or not folder or not method or not Path(folder).is_dir():
            ap.error(f"--arms takes NAME=FOLDER:METHOD with an existing folder, got {spec!r}")
        arms.append((name, Path(folder), method))
    rows = rows_of(args.set_dir, arms)
    how = "`python benchmarks/restoration_ceilings.py " + " ".join(sys.argv[1:]) + "`"
    publish(args.output, rows, "How far restoration could go", how, table(rows, [a[0] for a in arms]), plot)


if __name__ == "__main__":
    main()
