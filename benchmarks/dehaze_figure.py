"""Side-by-side figure of finished runs on generated scenes: hazy input | each run's clean render |
haze-free reference | the last run's transmittance, one row per scene (first test view).

    python benchmarks/dehaze_figure.py --runs RUN_A/config.yml RUN_B/config.yml ... --output docs/images/x.png

Runs are grouped by scene (their dataset folder) and labelled by method; the restoration PSNR
of the shown view is printed on each clean render. ``--clean-fill haze-light farthest-seen``
renders each run once per ``--pipeline.composite.clean-fill`` (rendering only), labelled by it.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from pipelines.engine.metrics import psnr  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402

LABEL_BAR = 18
"""Height (px) of the white strip above each tile that carries its label."""


def _u8(x: torch.Tensor) -> np.ndarray:
    x = x.detach().cpu().float()
    if x.shape[-1] == 1:
        import cv2

        g = (x[..., 0].clamp(0, 1).numpy() * 255).astype(np.uint8)
        return cv2.applyColorMap(g, cv2.COLORMAP_VIRIDIS)[..., ::-1]
    return (x.clamp(0, 1).numpy() * 255).round().astype(np.uint8)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=Path, nargs="+", required=True)
    ap.add_argument("--output", type=Path, required=True)
    ap.add_argument(
        "--clean-fill", nargs="+", default=[], choices=["haze-light", "farthest-seen", "farthest-ground", "auto"],
        help="render each run with each of these fills of the clean render's fade (default: the run's own)",
    )  # fmt: skip
    args = ap.parse_args()
    import cv2

    torch.set_grad_enabled(False)
    by_scene: dict[str, list] = defaultdict(list)
    for cfg in args.runs:
        run = load_run(cfg)
        by_scene[str(run.config.dataset.data)].append(run)
    rows, header = [], None
    for scene, runs in by_scene.items():
        dm = runs[0].datamanager
        idx = dm.test_indices[0]
        clean_ref = dm.clean_image(idx)
        tiles = [("hazy input", _u8(dm.image(idx)), float(psnr(dm.image(idx), clean_ref)))]
        T = None
        for run in runs:
            for fill in args.clean_fill or [None]:
                label = run.config.method_name
                if fill is not None:
                    run.pipeline.compositor.config.clean_fill = fill
                    label = f"{label} ({fill})"
                out = run.pipeline.render(run.datamanager.camera(idx))
                tiles.append((label, _u8(out["clean"]), float(psnr(out["clean"], clean_ref))))
            if run.pipeline.medium.has_medium:
                T = out["transmittance"]
        tiles.append((f"clean: {Path(scene).name}", _u8(clean_ref), None))
        if T is not None:
            tiles.append(("transmittance", _u8(T), None))
        imgs = []
        for label, img, p in tiles:
            img = cv2.resize(np.ascontiguousarray(img), None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
            # the label on a strip above the tile, so it never hides (or is hidden by) the picture
            bar = np.full((LABEL_BAR, img.shape[1], 3), 255, np.uint8)
            text = f"{label}" + (f" {p:.1f} dB" if p is not None else "")
            cv2.putText(
                bar, text, (4, LABEL_BAR - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA
            )
            imgs.append(np.concatenate([bar, img], axis=0))
        rows.append(np.concatenate(imgs, axis=1))
        header = Path(scene).name
        print(header, " | ".join(f"{lab}: {p:.2f}" for lab, _, p in tiles if p is not None))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    args.output.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.output), np.concatenate(rows, axis=0)[..., ::-1])
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
