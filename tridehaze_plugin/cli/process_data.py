"""``td-process-data images|video``: photos or a video -> a posed dataset ``td-train`` reads.

    td-process-data images --data PHOTOS --output-dir OUT [--matcher auto|exhaustive|sequential]
                           [--enhance none|clahe|dcp] [--max-image-size 1600]
    td-process-data video --data FILE.mp4 --num-frames 150 --output-dir OUT

Structure-from-motion with pycolmap on the CPU (``components.sfm``); the output is a COLMAP
dataset: ``images/`` (undistorted), ``sparse/0/`` (PINHOLE cameras, the sparse points) and
``sfm_summary.json``. It is written to a temporary sibling folder and renamed into place at the end,
so a failure or Ctrl-C leaves nothing half-written. See docs/export.md.
"""

from __future__ import annotations

import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import tyro
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    SpinnerColumn,
    TextColumn,
    TimeElapsedColumn,
)

from components.sfm.colmap_sfm import Reporter, SfmOptions, check_sfm_output, list_images, run_sfm
from components.synth.writer import staged_output, write_json
from tridehaze_plugin.cli.common import run_cli
from tridehaze_plugin.config import check_numbers
from tridehaze_plugin.errors import ConfigError

DESCRIPTION = "Structure-from-motion (pycolmap, CPU): photos or a video -> a dataset td-train reads."


@dataclass
class ImagesArgs:
    """Reconstruct a folder of photos: features, matching, incremental mapping, undistortion."""

    data: Path
    """Folder holding the photos (directly, not in sub-folders)."""
    output_dir: Path
    """New dataset folder (images/ + sparse/0/); must be new or empty unless --overwrite."""
    sfm: Annotated[SfmOptions, tyro.conf.OmitArgPrefixes] = field(default_factory=SfmOptions)
    overwrite: bool = False
    """Replace an output folder this same tool wrote before (a folder it did not write, or one
    holding files it did not write, is refused); the old one stays until the new is complete."""


@dataclass
class VideoArgs:
    """Extract sharp, evenly spaced frames from a video, then reconstruct them like photos."""

    data: Path
    """The video file (anything OpenCV decodes: mp4, mov, avi, ...)."""
    output_dir: Path
    """New dataset folder (images/ + sparse/0/); must be new or empty unless --overwrite."""
    num_frames: int = 150
    """Frames to keep: the sharpest one in each of this many equal segments of the video."""
    sfm: Annotated[SfmOptions, tyro.conf.OmitArgPrefixes] = field(
        default_factory=lambda: SfmOptions(camera_mode="single")
    )
    overwrite: bool = False
    """Replace an output folder this same tool wrote before (a folder it did not write, or one
    holding files it did not write, is refused); the old one stays until the new is complete."""


Command = (
    Annotated[ImagesArgs, tyro.conf.subcommand("images", description=ImagesArgs.__doc__)]
    | Annotated[VideoArgs, tyro.conf.subcommand("video", description=VideoArgs.__doc__)]
)


class RichReporter(Reporter):
    """A progress bar per stage in a terminal, and one summary line per finished stage."""

    def __init__(self, console: Console, progress: Progress | None) -> None:
        self.console = console
        self.progress = progress
        self.task = None
        self.count = 0

    def start(self, stage: str, total: int | None) -> None:
        if self.progress is not None:
            self.task = self.progress.add_task(stage, total=total)

    def advance(self, n: int = 1) -> None:
        if self.progress is not None and self.task is not None:
            self.progress.advance(self.task, n)

    def update(self, completed: int, total: int | None = None) -> None:
        if self.progress is not None and self.task is not None:
            self.progress.update(self.task, completed=completed, total=total)

    def finish(self, stage: str, seconds: float, detail: str) -> None:
        if self.progress is not None and self.task is not None:
            task = self.progress.tasks[self.task]
            self.progress.update(
                self.task, total=task.completed or 1, completed=task.completed or 1, visible=False
            )
            self.task = None
        self.count += 1
        self.console.print(f"[{self.count}] {stage:<9} {seconds:6.1f} s  {detail}")


def _progress(console: Console) -> Progress:
    return Progress(
        SpinnerColumn(),
        TextColumn("{task.description:<9}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=True,
        disable=not console.is_terminal,
    )


def _check_common(args: ImagesArgs | VideoArgs) -> None:
    args.sfm.check()
    check_sfm_output(args.output_dir, args.data)


def _check_video(args: VideoArgs) -> None:
    if args.num_frames < 2:
        raise ConfigError(
            f"--num-frames must be at least 2, got {args.num_frames}", fix="pass e.g. --num-frames 150"
        )
    if not args.data.is_file():
        raise ConfigError(
            "video file not found" if not args.data.exists() else "--data is a folder, not a video file",
            where=str(args.data),
            fix="pass a video file (use `td-process-data images` for a folder of photos)",
        )


def _frames(args: VideoArgs, frame_dir: Path, reporter: RichReporter) -> tuple[list[str], dict[str, Any]]:
    """The sharpest frame per segment of the video into ``frame_dir``: (names, summary fields)."""
    from components.sfm.video import extract_frames

    t0 = time.perf_counter()
    reporter.start("frames", None)
    frames = extract_frames(args.data, frame_dir, args.num_frames, progress=reporter.update)
    names = [p.name for p in frames.paths]
    reporter.finish(
        "frames",
        time.perf_counter() - t0,
        f"{len(names)} of {frames.total_frames} frames (sharpest per segment)",
    )
    return names, {
        "video": str(args.data.absolute()),
        "video_frames": frames.total_frames,
        "fps": frames.fps,
        "frame_indices": frames.indices,
        "frame_sharpness": [round(s, 2) for s in frames.sharpness],
    }


def process(args: ImagesArgs | VideoArgs, console: Console | None = None) -> dict[str, Any]:
    """Run the command; returns the summary written to ``sfm_summary.json``."""
    console = console or Console()
    _check_common(args)
    is_video = isinstance(args, VideoArgs)
    if is_video:
        _check_video(args)
    else:
        names = list_images(args.data)
    t_start = time.perf_counter()
    extra: dict[str, Any] = {}
    with (
        staged_output(args.output_dir, args.overwrite, "td-process-data") as tmp,
        _progress(console) as progress,
    ):
        reporter = RichReporter(console, progress if console.is_terminal else None)
        work = tmp / ".work"
        if is_video:
            image_dir = work / "frames"
            names, extra = _frames(args, image_dir, reporter)
        else:
            image_dir = args.data
        result = run_sfm(image_dir, names, tmp, work / "sfm", args.sfm, reporter, ordered=is_video)
        shutil.rmtree(work, ignore_errors=True)
        summary = {
            "source": str(args.data.absolute()),
            **result.to_dict(),
            "options": {k: v for k, v in vars(args.sfm).items()},
            **extra,
            "total_s": round(time.perf_counter() - t_start, 3),
        }
        write_json(tmp / "sfm_summary.json", summary)
    out = args.output_dir
    n_reg, n = len(result.registered), result.num_images
    console.print(
        f"registered {n_reg}/{n} images, {result.num_points} points, mean reprojection error "
        f"{result.mean_reprojection_error:.3f} px, mean track length {result.mean_track_length:.2f} "
        f"({summary['total_s']:.1f} s)"
    )
    if result.unregistered:
        shown = ", ".join(result.unregistered[:5]) + (" ..." if len(result.unregistered) > 5 else "")
        console.print(f"not registered (left out of the dataset): {shown}")
    console.print(f"wrote {out}  (train: td-train tri-dehaze --data {out})")
    return summary


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    cmd = tyro.cli(Command, args=args, prog="td-process-data", description=DESCRIPTION)  # type: ignore[arg-type]
    check_numbers(cmd)
    process(cmd)


def entrypoint() -> None:
    run_cli(main)


if __name__ == "__main__":
    entrypoint()
