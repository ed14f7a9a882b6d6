"""``td-render``: a trained run's renders, per view of a split or along a camera path.

    td-render --load-config RUN/config.yml --split test --outputs clean,depth --output-dir DIR
    td-render --load-config RUN/config.yml --path orbit --num-frames 120 --fps 30 \
              --outputs clean,side-by-side --output-dir DIR

``--path views`` (default) writes ``DIR/<output>/<image name>.png`` for every view of the split, so
results can be compared with any external tool. ``--path interpolate`` (a smooth path through the
split's cameras) and ``--path orbit`` (a circle around the scene centre) write ``DIR/<output>.mp4``
(OpenCV, mp4v), the frames ``DIR/<output>/frame_NNNNN.png`` and ``DIR/camera_path.json``.

Colour outputs are 8-bit RGB; one-channel outputs are colour-mapped (turbo): transmittance and
alpha always over [0, 1]; others (depth) per view over its 1-99 % range, and along a path over the
first frame's range for the whole video so it does not flicker. ``--raw`` also saves them
as float32 ``.npy`` (views only).
``side-by-side`` is hazy | clean next to each other.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import torch
import tyro
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from components.data.images import write_array_atomic, write_bytes_atomic, write_image_atomic
from pipelines.engine.device import resolve_device
from pipelines.engine.run_loader import load_run
from pipelines.evaluation.camera_paths import make_path
from pipelines.evaluation.visualize import UNIT_RANGE, to_png, value_range
from tridehaze_plugin.cli.common import check_output_folder, run_cli
from tridehaze_plugin.config import check_numbers
from tridehaze_plugin.errors import ConfigError, UserError

SIDE_BY_SIDE = "side-by-side"
"""Extra output: the hazy render and the clean one next to each other (hazy | clean)."""


@dataclass
class RenderArgs:
    """Render a trained run: every view of a split, or a video along a camera path."""

    load_config: Path
    """The run's config.yml (written by td-train)."""
    output_dir: Path = Path("renders")
    """Folder that receives one sub-folder (and, for a path, one .mp4) per output."""
    split: Literal["train", "test", "all"] | None = None
    """Which views to render (``--path views``; default test), or whose cameras a path runs through
    or around (default train)."""
    outputs: str = "clean"
    """Comma-separated outputs, e.g. ``clean,hazy,depth`` (what the method renders; see the error for
    the list), plus ``side-by-side`` (hazy | clean)."""
    path: Literal["views", "interpolate", "orbit"] = "views"
    """``views``: one image per view of the split; ``interpolate``: a smooth path through the split's
    cameras (travel order, Catmull-Rom positions, SLERP rotations); ``orbit``: a circle around the
    scene centre at the cameras' mean distance and height."""
    num_frames: int = 120
    """Frames of an ``interpolate`` or ``orbit`` path."""
    fps: float = 30.0
    """Frame rate of the MP4 of a path."""
    frames: bool = True
    """Also keep a path's frames as PNGs (``--no-frames``: only the MP4)."""
    raw: bool = False
    """Also save one-channel outputs as float32 ``.npy`` for analysis (``--path views``)."""
    device: str = "auto"
    """Torch device: auto, cpu or cuda."""


def _device(name: str) -> str:
    return str(resolve_device(name))


def _check(args: RenderArgs, available: list[str]) -> list[str]:
    wanted = [o.strip() for o in args.outputs.split(",") if o.strip()]
    known = [*available, SIDE_BY_SIDE] if {"hazy", "clean"} <= set(available) else list(available)
    unknown = [o for o in wanted if o not in known]
    if not wanted or unknown:
        extra = f"; also {SIDE_BY_SIDE} (hazy | clean)" if SIDE_BY_SIDE in known else ""
        raise ConfigError(
            f"unknown output(s) {', '.join(unknown) or '(none given)'} for --outputs; "
            f"this method renders: {', '.join(available)}{extra}"
        )
    return list(dict.fromkeys(wanted))


def _progress() -> Progress:
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        disable=not sys.stdout.isatty(),
    )


def _image(
    out: dict[str, torch.Tensor], name: str, ranges: dict[str, tuple[float, float]] | None
) -> np.ndarray:
    """uint8 RGB image of output ``name``; ``ranges`` fixes one-channel colour ranges across frames
    (filled on first use); None maps each depth-like image over its own range."""
    if name == SIDE_BY_SIDE:
        return np.concatenate([to_png(out["hazy"]), to_png(out["clean"])], axis=1)
    value = out[name]
    if ranges is None:
        return to_png(value, (0.0, 1.0) if name in UNIT_RANGE else None)
    if value.shape[-1] == 1 and name not in ranges:
        ranges[name] = (0.0, 1.0) if name in UNIT_RANGE else value_range(value[..., 0].float().cpu().numpy())
    return to_png(value, ranges.get(name))


def render_views(args: RenderArgs, run, wanted: list[str], indices: list[int]) -> None:
    dm = run.datamanager
    names = dm.scene.names()
    with _progress() as progress:
        task = progress.add_task(f"render {args.split}", total=len(indices))
        for idx in indices:
            out = run.pipeline.render(dm.camera(idx))
            stem = Path(names[idx]).stem
            for name in wanted:
                img = _image(out, name, None)  # depth: each view over its own range
                write_image_atomic(args.output_dir / name / f"{stem}.png", img)
                if args.raw and name in out and out[name].shape[-1] == 1:
                    write_array_atomic(
                        args.output_dir / name / f"{stem}.npy", out[name][..., 0].float().cpu().numpy()
                    )
            progress.advance(task)
    print(f"wrote {len(indices)} view(s) x {len(wanted)} output(s) to {args.output_dir}")


def _open_writer(path: Path, fps: float, size: tuple[int, int]) -> cv2.VideoWriter:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), size)
    if not writer.isOpened():
        raise UserError(
            "OpenCV cannot write MP4 (mp4v) video here",
            where=str(path),
            fix="install an OpenCV build with FFmpeg (opencv-python-headless)",
        )
    return writer


def render_path(args: RenderArgs, run, wanted: list[str], indices: list[int]) -> None:
    """Render a camera path into a staging folder; move the videos and frames into place at the end."""
    dm = run.datamanager
    path = make_path(args.path, dm.cameras, indices, args.num_frames)
    out_dir = args.output_dir
    out_dir.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=".render-", dir=out_dir))
    t0 = time.perf_counter()
    writers: dict[str, cv2.VideoWriter] = {}
    try:
        ranges: dict[str, tuple[float, float]] = {}
        with _progress() as progress:
            task = progress.add_task(f"render {args.path}", total=len(path))
            for f in range(len(path)):
                out = run.pipeline.render(path.camera(f, dm.device))
                for name in wanted:
                    img = _image(out, name, ranges)  # [H, W', 3] uint8 RGB
                    if name not in writers:
                        writers[name] = _open_writer(
                            stage / f"{name}.mp4", args.fps, (img.shape[1], img.shape[0])
                        )
                    writers[name].write(np.ascontiguousarray(img[..., ::-1]))
                    if args.frames:
                        write_image_atomic(stage / name / f"frame_{f:05d}.png", img)
                progress.advance(task)
        for w in writers.values():
            w.release()
        writers.clear()
        write_bytes_atomic(stage / "camera_path.json", json.dumps(path.to_dict(args.fps)).encode())
        for name in wanted:  # swap each output in (an old folder of frames is replaced as a whole)
            os.replace(stage / f"{name}.mp4", out_dir / f"{name}.mp4")
            if args.frames:
                target = out_dir / name
                old = out_dir / f".{name}.old-{uuid.uuid4().hex[:8]}" if target.exists() else None
                if old is not None:
                    os.rename(target, old)
                os.rename(stage / name, target)
                if old is not None:
                    shutil.rmtree(old, ignore_errors=True)
        os.replace(stage / "camera_path.json", out_dir / "camera_path.json")
    finally:
        for w in writers.values():
            w.release()
        shutil.rmtree(stage, ignore_errors=True)
    secs = time.perf_counter() - t0
    print(
        f"wrote {len(path)} frames ({path.intrinsics.width}x{path.intrinsics.height}, {args.fps:g} fps, {args.path}) x "
        f"{len(wanted)} output(s) to {out_dir}: {', '.join(f'{n}.mp4' for n in wanted)} ({secs:.1f} s)"
    )


def _check_video_args(args: RenderArgs) -> None:
    """Frame count and rate of a camera-path video (checked before the run is loaded)."""
    if args.path == "views":
        return
    if args.num_frames < 2:
        raise ConfigError(
            f"--num-frames must be at least 2, got {args.num_frames}", fix="pass e.g. --num-frames 120"
        )
    if not 0 < args.fps <= 1000:  # a video writer cannot use more (1e308 left an empty folder)
        raise ConfigError(f"--fps must be in (0, 1000], got {args.fps:g}", fix="pass e.g. --fps 30")


def main(argv: list[str] | None = None) -> None:
    args = tyro.cli(RenderArgs, args=sys.argv[1:] if argv is None else argv, prog="td-render")
    check_numbers(args)
    check_output_folder(args.output_dir)
    device = _device(args.device)
    _check_video_args(args)
    run = load_run(args.load_config, device=device)
    wanted = _check(args, run.pipeline.output_names())
    split = args.split or ("test" if args.path == "views" else "train")
    indices = run.datamanager.scene.indices(split)
    if not indices:
        raise ConfigError(f"the {split} split of this run's dataset is empty", fix="use --split train or all")
    args.split = split
    if args.path == "views":
        render_views(args, run, wanted, indices)
    else:
        render_path(args, run, wanted, indices)


def entrypoint() -> None:
    run_cli(main)


if __name__ == "__main__":
    entrypoint()
