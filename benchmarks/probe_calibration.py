"""Calibration of the haze probe (``--pipeline.medium.backend auto``) on generated scenes.

Generates every layout x haze preset (8 views at 64x48, and 24 views at 128x96 without ``dense``)
with ``td-synth``'s generator, runs :func:`pipelines.haze_probe.probe_haze` on each and prints the
measured statistics per true class with the probe's verdicts, the table of docs/tradeoff.md.

    python benchmarks/probe_calibration.py                       # ~2 min on 2 cores
    python benchmarks/probe_calibration.py --scenes-dir /tmp/probe-scenes   # keep the scenes

Writes ``benchmarks/results/probe_calibration.{json,csv,png}`` (the plot: pair variation F
against effect size, one marker per scene coloured by its true class, decision thresholds drawn).
"""

from __future__ import annotations

import argparse
import csv
import json
import tempfile
import time
from collections import Counter
from pathlib import Path

import torch

from components.data.config import DataConfig
from components.data.loader import load_scene
from components.synth.generate import SceneConfig, generate_scene
from pipelines.datamanager import DataManager
from pipelines.haze_probe import VARYING_EFFECT, VARYING_F, probe_haze

LAYOUTS = ("courtyard", "street", "room", "field")
SIZES = {
    "small": ({"num_views": 8, "width": 64, "height": 48}, ("none", "uniform", "homogeneous", "height", "patchy", "dense")),
    "big": ({"num_views": 24, "width": 128, "height": 96}, ("none", "uniform", "homogeneous", "height", "patchy")),
}  # fmt: skip
TRUTH = {"none": "none", "uniform": "homogeneous", "homogeneous": "homogeneous"}
"""Expected class per preset (every other preset: ``varying``)."""
RESULTS = Path(__file__).resolve().parent / "results"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes-dir", type=Path, default=None, help="where to generate (default: a temp dir)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.scenes_dir or Path(tmp)
        rows = []
        for size, (dims, presets) in SIZES.items():
            for layout in LAYOUTS:
                for haze in presets:
                    path = root / f"{layout}-{haze}-{size}"
                    if not (path / "transforms.json").exists():
                        generate_scene(SceneConfig(output_dir=path, layout=layout, haze=haze, seed=args.seed,
                                                   samples=32, supersample=1, num_points=1500, **dims))  # fmt: skip
                    scene = load_scene(DataConfig(data=path))
                    t0 = time.perf_counter()
                    p = probe_haze(DataManager(scene, torch.device("cpu")), scene.train_indices, scene.points)
                    rows.append({"layout": layout, "size": size, "preset": haze, "expected": TRUTH.get(haze, "varying"),
                                 **p.to_dict(), "seconds": time.perf_counter() - t0})  # fmt: skip
    print("| true class | scenes | optical depth | depth trend | F | effect | probe says |")
    print("|---|---|---|---|---|---|---|")
    for cls in ("none", "homogeneous", "varying"):
        rs = [r for r in rows if r["expected"] == cls]

        def span(key: str, rs=rs) -> str:
            v = [r[key] for r in rs]
            return f"{min(v):.2f} to {max(v):.2f}"

        said = ", ".join(f"{k} {n}" for k, n in Counter(r["haze"] for r in rs).most_common())
        print(f"| {cls} | {len(rs)} | {span('optical_depth')} | {span('depth_trend')} | {span('variation_f')} | "
              f"{span('variation_effect')} | {said} |")  # fmt: skip
    for r in rows:
        if r["haze"] != r["expected"]:
            print(f"miss: {r['layout']} {r['preset']} ({r['size']}): {r['haze']}")
    right = sum(r["haze"] == r["expected"] for r in rows)
    print(f"{right}/{len(rows)} classified as their preset; probe time median "
          f"{sorted(r['seconds'] for r in rows)[len(rows) // 2]:.2f} s")  # fmt: skip
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "probe_calibration.json").write_text(json.dumps(rows, indent=1))
    with (RESULTS / "probe_calibration.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    plot(rows, RESULTS / "probe_calibration.png")


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    colours = {"none": "tab:gray", "homogeneous": "tab:blue", "varying": "tab:red"}
    for cls, c in colours.items():
        rs = [r for r in rows if r["expected"] == cls]
        ax.scatter([max(r["variation_f"], 1e-2) for r in rs], [r["variation_effect"] for r in rs], c=c,
                   label=f"true: {cls}", marker="o", edgecolors=["k" if r["haze"] != cls else c for r in rs])  # fmt: skip
    ax.axvline(VARYING_F, color="k", lw=0.8, ls="--")
    ax.axhline(VARYING_EFFECT, color="k", lw=0.8, ls="--")
    ax.set_xscale("log")
    ax.set_xlabel("median pair F (log)")
    ax.set_ylabel("median pair effect |median| / MAD")
    ax.set_title("haze probe on generated scenes (black edge: misclassified)")
    ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
