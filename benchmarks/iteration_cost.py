"""Cost of a full training iteration: vanilla-gs vs Tri-DehazeGS at the same settings.

Every variant trains on the same generated hazy scene with the same Gaussians (densification off,
so the count stays fixed) and the same rasterizer; an iteration is forward + losses + backward +
optimizer step, i.e. exactly what ``td-train`` runs. Variants are interleaved round by round so
load from other users of a shared machine hits all alike; medians and ratios to vanilla-gs are
reported. The Tri-DehazeGS variants differ in how many rays the medium is marched along
(``--pipeline.composite.ray-stride``; 1 = every pixel, the naive evaluation) and in how each pixel
reads them (the compiled read-out, or the torch ops with ``--pipeline.composite.no-fused-readout``),
and in the medium light (the default's one light with an MLP direction model against the field
light with SH order 1 it replaced in session 23).
The default has the depth holds (``--pipeline.composite.depth-gradient
--pipeline.lambda-depth-metric 0.05``: the gradient into the rendered depth and the metric prior);
"without the depth holds" turns both off (the default before session 19).

    python benchmarks/iteration_cost.py                       # 320x240, ~50k Gaussians
    python benchmarks/iteration_cost.py --width 160 --height 120 --points 10000
    python benchmarks/iteration_cost.py --quality-run RUN/config.yml   # + rendering error per stride

With ``--quality-run`` a trained Tri-DehazeGS run is also re-rendered on its test views with each
ray stride: the transmittance and hazy composite are compared with the every-pixel march (stride 1)
and the composite with the hazy inputs, i.e. what the coarse grid costs in accuracy.

Writes ``benchmarks/results/iteration_cost.{json,csv,png}``.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from components.data.loader import load_scene  # noqa: E402
from components.synth.generate import SceneConfig, generate_scene  # noqa: E402
from pipelines.engine.datamanager import DataManager  # noqa: E402
from pipelines.engine.optimizers import Optimizers  # noqa: E402
from pipelines.engine.trainer import optimization_step  # noqa: E402
from tridehaze_plugin.registry import REGISTRY, load_all  # noqa: E402

RESULTS = REPO / "benchmarks" / "results"


TRIMMED = {"depth_trim": 0.2, "lambda_depth": 0.1, "lambda_smooth": 0.05}
"""Session 63's trimmed depth correlation: a quantile of the residuals per view and step."""


def variants() -> dict[str, tuple[str, dict]]:
    """name -> (method, pipeline overrides)."""
    return {
        "vanilla-gs": ("vanilla-gs", {}),
        "tri-dehaze (default: ~1200 rays)": ("tri-dehaze", {}),
        "tri-dehaze (torch read-out)": ("tri-dehaze", {"fused": False}),
        "tri-dehaze (without the depth holds)": ("tri-dehaze", {"holds": False}),
        "tri-dehaze (stride 4)": ("tri-dehaze", {"stride": 4}),
        "tri-dehaze (stride 2)": ("tri-dehaze", {"stride": 2}),
        "tri-dehaze (stride 1, every pixel)": ("tri-dehaze", {"stride": 1}),
        "tri-dehaze (field light, SH1: before session 23)": ("tri-dehaze", {"light": ("field", "sh")}),
        "tri-dehaze (trimmed depth correlation 0.2, session 63)": ("tri-dehaze", {"pipeline": TRIMMED}),
    }


def build(method: str, over: dict, data: Path, points: int, backend: str, device: torch.device):
    cfg = REGISTRY.get("method", method).make_config()
    p = cfg.pipeline
    p = replace(
        p,
        densify=replace(p.densify, enabled=False),
        rasterizer=replace(p.rasterizer, backend=backend),
        model=replace(p.model, max_init_points=points),
        composite=replace(
            p.composite,
            ray_stride=over.get("stride", p.composite.ray_stride),
            fused_readout=over.get("fused", p.composite.fused_readout),
            depth_gradient=over.get("holds", p.composite.depth_gradient),
        ),
    )
    if over.get("holds") is False:  # the depth holds off: no gradient into depth, no metric prior
        p = replace(p, lambda_depth_metric=0.0)
    if "light" in over:  # where the medium light may vary, and its direction model
        space, light = over["light"]
        p = replace(p, medium=replace(p.medium, light_space=space, light=light))
    p = replace(p, **over.get("pipeline", {}))  # any other pipeline fields under test
    cfg = replace(cfg, pipeline=p, dataset=replace(cfg.dataset, data=data), max_steps=10_000)
    scene = load_scene(cfg.dataset)
    dm = DataManager(scene, device, seed=0)
    pipe = cfg.pipeline.setup(dm, seed=0, max_steps=cfg.max_steps)
    opt = Optimizers(pipe.param_groups(), cfg.optimizer, cfg.max_steps, eps=pipe.adam_eps())
    return pipe, opt


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def iteration(pipe, opt, step: int, device: torch.device) -> float:
    """One training iteration, timed to its last kernel (CUDA runs asynchronously)."""
    sync(device)
    t0 = time.perf_counter()
    optimization_step(pipe, opt, step)
    sync(device)
    return time.perf_counter() - t0


def profile(pipe, opt, step: int, device: torch.device, iterations: int, out: Path) -> list[dict]:
    """torch.profiler over a few iterations: where the time of a Tri-DehazeGS step goes.

    The pipeline labels its stages (``td.rasterize``, ``td.medium``, ``td.composite+loss``) with
    ``record_function``; the table lists those labels and the most expensive operators by device
    time (CUDA) or CPU time.
    """
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    for k in range(2):  # warm-up outside the trace
        iteration(pipe, opt, step + k, device)
    with torch_profile(activities=activities) as prof:
        for k in range(iterations):
            iteration(pipe, opt, step + 2 + k, device)
    key = "device_time_total" if device.type == "cuda" else "cpu_time_total"
    rows = []
    for ev in prof.key_averages():
        total = getattr(ev, key, 0.0) or 0.0
        rows.append(
            {
                "name": ev.key,
                "calls": ev.count // iterations,
                "ms_per_iteration": round(total / 1000 / iterations, 3),
                "cpu_ms_per_iteration": round(ev.cpu_time_total / 1000 / iterations, 3),
            }
        )
    rows.sort(key=lambda r: -r["ms_per_iteration"])
    labels = [r for r in rows if r["name"].startswith("td.")]
    top = [r for r in rows if not r["name"].startswith(("td.", "ProfilerStep"))][:25]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".profile.json").write_text(json.dumps({"stages": labels, "ops": top}, indent=2))
    print(f"\nprofile ({iterations} iterations, {key}):")
    for r in labels + top:
        print(f"  {r['name'][:60]:60s} {r['calls']:5d} {r['ms_per_iteration']:9.3f} ms")
    return labels + top


def stride_quality(config_path: Path, strides: list[int | None]) -> list[dict]:
    """Render a trained run's test views with each stride; errors against stride 1 and the inputs."""
    from pipelines.engine.metrics import psnr
    from pipelines.engine.run_loader import load_run

    run = load_run(config_path)
    comp = run.pipeline.compositor
    dm = run.datamanager
    views = dm.test_indices or dm.train_indices[:3]
    renders: dict[int | None, list[dict]] = {}
    with torch.no_grad():
        for stride in [1, *strides]:
            comp.config.ray_stride = stride
            renders[stride] = [run.pipeline.render(dm.camera(i)) for i in views]
    rows = []
    H, W = int(dm.camera(views[0]).height[0]), int(dm.camera(views[0]).width[0])
    for stride in strides:
        comp.config.ray_stride = stride
        effective = comp.stride_for(H, W)
        t_mean = sum(
            float((a["transmittance"] - b["transmittance"]).abs().mean())
            for a, b in zip(renders[stride], renders[1], strict=True)
        ) / len(views)
        t_err = max(
            float((a["transmittance"] - b["transmittance"]).abs().max())
            for a, b in zip(renders[stride], renders[1], strict=True)
        )
        rows.append(
            {
                "ray_stride": "auto" if stride is None else stride,
                "effective_stride": effective,
                "mean_abs_T_vs_stride1": round(t_mean, 5),
                "max_abs_T_vs_stride1": round(t_err, 5),
                "hazy_psnr_vs_stride1": round(
                    sum(
                        float(psnr(a["hazy"], b["hazy"]))
                        for a, b in zip(renders[stride], renders[1], strict=True)
                    )
                    / len(views),
                    2,
                ),
                "reconstruction_psnr": round(
                    sum(
                        float(psnr(a["hazy"], dm.image(i)))
                        for a, i in zip(renders[stride], views, strict=True)
                    )
                    / len(views),
                    3,
                ),
            }
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--points", type=int, default=50_000, help="Gaussians (seed points sampled)")
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--steps", type=int, default=6, help="timed iterations per variant per round")
    ap.add_argument(
        "--step-offset",
        type=int,
        default=1000,
        help="steps are timed from here (Stage I of a 10000-step run: the medium is trained; SH degree 1)",
    )
    ap.add_argument("--backend", default="auto")
    ap.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    ap.add_argument("--variants", nargs="+", default=None, help="subset of the variant names (default: all)")
    ap.add_argument(
        "--profile", type=int, default=0, metavar="N", help="also profile N tri-dehaze iterations"
    )
    ap.add_argument("--out", type=Path, default=RESULTS / "iteration_cost")
    ap.add_argument("--quality-run", type=Path, default=None, help="trained tri-dehaze RUN/config.yml")
    args = ap.parse_args()
    load_all()
    device = torch.device(args.device)
    chosen = {k: v for k, v in variants().items() if args.variants is None or k in args.variants}
    if "vanilla-gs" not in chosen:
        ap.error(f"--variants must include vanilla-gs (the baseline); known: {list(variants())}")
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "scene"
        generate_scene(
            SceneConfig(
                output_dir=data, layout="courtyard", haze="patchy", num_views=args.views,
                width=args.width, height=args.height, num_points=args.points, samples=32,
            )
        )  # fmt: skip
        built = {
            name: build(m, o, data, args.points, args.backend, device) for name, (m, o) in chosen.items()
        }
        times: dict[str, list[float]] = {name: [] for name in built}
        names = list(built)
        for name in names:  # warm-up: compile kernels, fill caches
            iteration(*built[name], args.step_offset, device)
        for r in range(args.rounds):
            for name in names[r % len(names) :] + names[: r % len(names)]:
                for k in range(args.steps):
                    step = args.step_offset + 1 + r * args.steps + k
                    times[name].append(iteration(*built[name], step, device))
        n_gauss = {name: built[name][0].model.num_gaussians for name in names}
        backends = {name: built[name][0].rasterizer.name for name in names}
        peak_gib = None
        if device.type == "cuda":
            peak_gib = round(torch.cuda.max_memory_allocated(device) / 2**30, 2)
        profiled = []
        if args.profile:
            name = next(n for n in names if n.startswith("tri-dehaze"))
            step = args.step_offset + 1 + args.rounds * args.steps
            profiled = profile(*built[name], step, device, args.profile, args.out)
    base = statistics.median(times["vanilla-gs"])
    rows = []
    for name in names:
        med = statistics.median(times[name])
        rows.append(
            {
                "variant": name,
                "median_s": round(med, 4),
                "min_s": round(min(times[name]), 4),
                "ratio_to_vanilla": round(med / base, 3),
                "gaussians": n_gauss[name],
                "rasterizer": backends[name],
                "samples": len(times[name]),
            }
        )
    meta = {
        "width": args.width,
        "height": args.height,
        "views": args.views,
        "threads": torch.get_num_threads(),
        "backend": args.backend,
        "device": torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu",
        "peak_gpu_memory_gib_all_variants": peak_gib,
        "timed_from_step": args.step_offset,
    }
    print(
        f"{args.width}x{args.height}, {rows[0]['gaussians']} Gaussians, {meta['device']}, "
        f"rasterizer {rows[0]['rasterizer']}, {torch.get_num_threads()} threads"
    )
    print(f"{'variant':38s} {'median s':>9s} {'min s':>8s} {'x vanilla':>10s}")
    for row in rows:
        print(
            f"{row['variant']:38s} {row['median_s']:9.4f} {row['min_s']:8.4f} {row['ratio_to_vanilla']:10.2f}"
        )
    quality = []
    if args.quality_run is not None:
        quality = stride_quality(args.quality_run, [None, 2, 4, 8])
        print(f"\nrendering error of the coarse grid on {args.quality_run.parent.name} (test views):")
        print(
            f"{'ray stride':>12s} {'mean|T - T_1|':>14s} {'max|T - T_1|':>13s} {'PSNR vs stride 1':>17s} "
            f"{'recon PSNR':>11s}"
        )
        for q in quality:
            label = f"{q['ray_stride']} ({q['effective_stride']})"
            print(
                f"{label:>12s} {q['mean_abs_T_vs_stride1']:14.5f} {q['max_abs_T_vs_stride1']:13.5f} {q['hazy_psnr_vs_stride1']:17.2f} "
                f"{q['reconstruction_psnr']:11.3f}"
            )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(
        json.dumps({"meta": meta, "rows": rows, "quality": quality, "profile": profiled}, indent=2)
    )
    with args.out.with_suffix(".csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 3.2))
        ax.barh([r["variant"] for r in rows][::-1], [r["median_s"] for r in rows][::-1], color="#4a7ab8")
        for i, r in enumerate(rows[::-1]):
            ax.text(r["median_s"], i, f"  {r['ratio_to_vanilla']:.2f}x", va="center", fontsize=8)
        ax.set_xlabel("median seconds per iteration")
        ax.set_title(f"iteration cost, {args.width}x{args.height}, {rows[0]['gaussians']} Gaussians")
        fig.tight_layout()
        fig.savefig(args.out.with_suffix(".png"), dpi=120)
    except ImportError:
        print("matplotlib missing: no plot (pip install -e '.[bench]')")


if __name__ == "__main__":
    main()
