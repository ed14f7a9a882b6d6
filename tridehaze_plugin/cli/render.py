"""``td-render``: write a trained run's renders for every view of a split.

    td-render --load-config RUN/config.yml --split test --outputs clean,depth --output-dir DIR

writes ``DIR/<output>/<image name>.png`` so results can be compared with any external tool.
Colour outputs are written as 8-bit RGB; one-channel outputs (depth, alpha, ...) as a
colour-mapped preview, plus ``.npy`` float32 arrays with ``--raw``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import torch
import tyro
from rich.progress import Progress

from components.data.images import write_array_atomic, write_image_atomic
from pipelines.run_loader import load_run
from tridehaze_plugin.cli.common import run_cli
from tridehaze_plugin.errors import ConfigError


@dataclass
class RenderArgs:
    """Render a trained run."""

    load_config: Path
    """The run's config.yml (written by td-train)."""
    output_dir: Path = Path("renders")
    """Folder that receives one sub-folder per output."""
    split: Literal["train", "test", "all"] = "test"
    """Which views to render."""
    outputs: str = "clean"
    """Comma-separated outputs, e.g. ``clean,hazy,depth`` (what the method renders; see the error for the list)."""
    raw: bool = False
    """Also save one-channel outputs as float32 ``.npy`` for analysis."""
    device: str = "auto"
    """Torch device: auto, cpu or cuda."""


def to_png(value: torch.Tensor) -> np.ndarray:
    """[H, W, 3] in [0, 1] -> uint8 RGB; [H, W, 1] -> turbo colour map over its 1-99 % range."""
    arr = value.detach().float().cpu().numpy()
    if arr.shape[-1] == 3:
        return (arr.clip(0, 1) * 255 + 0.5).astype(np.uint8)
    x = arr[..., 0]
    finite = x[np.isfinite(x) & (x > 0)] if (x > 0).any() else x[np.isfinite(x)]
    lo, hi = np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0)
    norm = ((x - lo) / max(hi - lo, 1e-12)).clip(0, 1)
    bgr = cv2.applyColorMap((norm * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    return bgr[..., ::-1].copy()


def main(argv: list[str] | None = None) -> None:
    args = tyro.cli(RenderArgs, args=sys.argv[1:] if argv is None else argv, prog="td-render")
    device = "cuda" if args.device == "auto" and torch.cuda.is_available() else args.device
    device = "cpu" if device == "auto" else device
    run = load_run(args.load_config, device=device)
    wanted = [o.strip() for o in args.outputs.split(",") if o.strip()]
    available = run.pipeline.output_names()
    unknown = [o for o in wanted if o not in available]
    if not wanted or unknown:
        raise ConfigError(
            f"unknown output(s) {', '.join(unknown) or '(none given)'} for --outputs; "
            f"this method renders: {', '.join(available)}"
        )
    dm = run.datamanager
    indices = dm.scene.indices(args.split)
    if not indices:
        raise ConfigError(f"the {args.split} split of this run's dataset is empty", fix="use --split train")
    names = dm.scene.names()
    with Progress(disable=not sys.stdout.isatty()) as progress:
        task = progress.add_task(f"render {args.split}", total=len(indices))
        for idx in indices:
            out = run.pipeline.render(dm.camera(idx))
            stem = Path(names[idx]).stem
            for name in wanted:
                write_image_atomic(args.output_dir / name / f"{stem}.png", to_png(out[name]))
                if args.raw and out[name].shape[-1] == 1:
                    write_array_atomic(
                        args.output_dir / name / f"{stem}.npy", out[name][..., 0].float().cpu().numpy()
                    )
            progress.advance(task)
    print(f"wrote {len(indices)} view(s) x {len(wanted)} output(s) to {args.output_dir}")


def entrypoint() -> None:
    run_cli(main)


if __name__ == "__main__":
    entrypoint()
