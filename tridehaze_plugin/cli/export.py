"""``td-export``: a trained run's clean Gaussians as a standard 3DGS PLY, and its medium.

    td-export --load-config RUN/config.yml --output-dir DIR [--frame original|normalized]

writes ``DIR/splat.ply`` (the clean scene, readable by Gaussian-splat viewers), and for methods
with a medium ``DIR/medium.npz`` + ``DIR/extinction_{xy,xz,yz}.png``, plus ``DIR/export.json``.
The folder is written to a temporary sibling and renamed at the end. See docs/export.md.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import tyro
from rich.console import Console

from components.export.medium import export_medium
from components.export.splat_ply import SplatData, to_original_frame, write_splat_ply
from components.synth.writer import check_output_dir, staged_output, write_json
from pipelines.engine.device import resolve_device
from pipelines.engine.run_loader import load_run
from tridehaze_plugin.cli.common import run_cli
from tridehaze_plugin.config import check_numbers
from tridehaze_plugin.errors import ConfigError, UserError


@dataclass
class ExportArgs:
    """Export a trained run: clean Gaussians as a 3DGS PLY, the medium as a grid + slices."""

    load_config: Path
    """The run's config.yml (written by td-train)."""
    output_dir: Path = Path("export")
    """New folder for splat.ply (+ medium.npz, extinction_*.png, export.json)."""
    frame: Literal["original", "normalized"] = "original"
    """Coordinates: ``original`` = the dataset's own world (the run's dataparser_transforms.json is
    undone: positions, scales, orientations and view-dependent colour); ``normalized`` = the
    centred, rescaled world the run was trained in."""
    medium_resolution: int = 64
    """Extinction grid samples per axis in medium.npz."""
    light_resolution: int = 16
    """Medium-light grid samples per axis (six view directions) in medium.npz."""
    overwrite: bool = False
    """Replace an output folder this same tool wrote before (a folder it did not write, or one
    holding files it did not write, is refused); the old one stays until the new is complete."""
    device: str = "cpu"
    """Torch device used to reload the run (cpu, cuda or auto)."""


def export(args: ExportArgs, console: Console | None = None) -> dict[str, Any]:
    console = console or Console()
    t0 = time.perf_counter()
    if not 2 <= args.medium_resolution <= 512:
        raise ConfigError(f"--medium-resolution must be in [2, 512], got {args.medium_resolution}")
    if not 2 <= args.light_resolution <= 128:
        raise ConfigError(f"--light-resolution must be in [2, 128], got {args.light_resolution}")
    if not args.load_config.is_file():
        raise UserError(
            "run config not found",
            where=str(args.load_config),
            fix="pass the config.yml of a td-train run folder",
        )
    check_output_dir(args.output_dir, args.overwrite, "td-export")
    run = load_run(args.load_config, device=resolve_device(args.device))
    pipeline = run.pipeline
    model = pipeline.scene_gaussians()
    if model is None:
        raise UserError("this run's pipeline has no Gaussian model to export", where=str(args.load_config))
    transform = run.datamanager.scene.transform if args.frame == "original" else None
    splat = SplatData.from_model(model)
    if transform is not None:
        splat = to_original_frame(splat, transform)
    medium = pipeline.medium_field()
    summary: dict[str, Any] = {
        "run": str(run.run_dir.absolute()),
        "step": run.step,
        "frame": args.frame,
        "gaussians": len(splat),
        "sh_degree": splat.sh_degree,
        "transform": run.datamanager.scene.transform.to_dict(),
    }
    with staged_output(args.output_dir, args.overwrite, "td-export") as tmp:
        summary["ply_bytes"] = write_splat_ply(tmp / "splat.ply", splat)
        summary["medium"] = None
        if medium is not None and medium.has_medium and (medium.is_field or medium.renders_with_gaussians):
            summary["medium"] = export_medium(
                medium, tmp, transform, args.medium_resolution, args.light_resolution, model=model
            )
        summary["seconds"] = round(time.perf_counter() - t0, 3)
        write_json(tmp / "export.json", summary)
    _print_summary(console, args, summary)
    return summary


def _print_summary(console: Console, args: ExportArgs, summary: dict[str, Any]) -> None:
    out = args.output_dir
    mb = summary["ply_bytes"] / 1e6
    console.print(
        f"wrote {out / 'splat.ply'}: {summary['gaussians']} Gaussians, SH degree {summary['sh_degree']}, "
        f"{mb:.2f} MB, {args.frame} frame",
        soft_wrap=True,  # a path wrapped by the console cannot be copied
    )
    med = summary["medium"]
    if med is None:
        console.print("this method has no medium: only the PLY was written")
    elif med["kind"] == "field":
        console.print(
            f"wrote {out / 'medium.npz'} ({med['resolution']}^3 extinction, {med['beta_unit']}: "
            f"median {med['beta_median']:.4g}, max {med['beta_max']:.4g}) and 3 extinction slices",
            soft_wrap=True,
        )
    else:
        console.print(
            f"wrote {out / 'medium.npz'} (per-Gaussian extinction and light of the gaussian-bound medium)",
            soft_wrap=True,
        )


def main(argv: list[str] | None = None) -> None:
    args = tyro.cli(ExportArgs, args=sys.argv[1:] if argv is None else argv, prog="td-export")
    check_numbers(args)
    export(args)


def entrypoint() -> None:
    run_cli(main)


if __name__ == "__main__":
    entrypoint()
