"""``td-synth scene|haze|gallery``: hazy datasets with exact ground truth.

* ``scene``: a procedural scene rendered with a known medium (hazy, clean, depth, T, S).
* ``haze``: haze added to an existing clean dataset from its depth maps or a trained run's depth.
* ``gallery``: one PNG of hazy | clean | transmittance per preset.

See docs/synth.md.
"""

from __future__ import annotations

import sys
from typing import Annotated

import tyro
from rich.console import Console

from components.synth.gallery import GalleryConfig, make_gallery
from components.synth.generate import SceneConfig, generate_scene
from components.synth.haze_existing import HazeConfig, haze_dataset
from pipelines.evaluation.run_depth import run_depths
from tridehaze_plugin.cli.common import run_cli
from tridehaze_plugin.config import check_numbers

DESCRIPTION = "Hazy data with exact ground truth: procedural scenes, haze on existing datasets, a gallery."

Command = (
    Annotated[SceneConfig, tyro.conf.subcommand("scene", description=SceneConfig.__doc__)]
    | Annotated[HazeConfig, tyro.conf.subcommand("haze", description=HazeConfig.__doc__)]
    | Annotated[GalleryConfig, tyro.conf.subcommand("gallery", description=GalleryConfig.__doc__)]
)


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    cmd = tyro.cli(Command, args=args, prog="td-synth", description=DESCRIPTION)  # type: ignore[arg-type]
    check_numbers(cmd)
    console = Console(stderr=False)
    if isinstance(cmd, SceneConfig):
        meta = generate_scene(cmd)
        t = meta["timings_s"]
        console.print(
            f"wrote {cmd.output_dir}: {cmd.num_views} views {cmd.width}x{cmd.height}, layout {meta['layout']}, "
            f"haze {cmd.haze}, mean T {meta['mean_transmittance']:.3f}, "
            f"{t['total']:.1f} s (clean {t['clean_render']:.1f} s, haze {t['haze_march']:.1f} s)"
        )
    elif isinstance(cmd, HazeConfig):
        meta = haze_dataset(cmd, run_depths)
        console.print(
            f"wrote {cmd.output_dir}: {len(meta['per_view_mean_transmittance'])} views, beta {meta['beta']:.4g} "
            f"/unit, median T {meta['median_transmittance']:.3f}, mean T {meta['mean_transmittance']:.3f}, "
            f"depth from {meta['depth_source']}, {meta['timings_s']['total']:.1f} s"
        )
    else:
        res = make_gallery(cmd)
        secs = res.pop("seconds")
        means = ", ".join(f"{k} {v:.2f}" for k, v in res.items())
        console.print(f"wrote {cmd.output}: mean T {means} ({secs:.1f} s)")


def entrypoint() -> None:
    run_cli(main)


if __name__ == "__main__":
    entrypoint()
