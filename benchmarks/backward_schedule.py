"""cpu backend: fixed (round-robin) vs first-come tile schedule of the backward, side by side.

With first-come scheduling each thread's gradient buffer sums whichever tiles it happened to
get, so float rounding, and so training, changes from run to run. The fixed schedule gives
thread t the tiles t, t + T, ... and makes every backward bit-identical for a given thread
count. This measures what that costs: forward+backward medians of interleaved repeats on
the benchmark scenes (``make_scene``), plus a lopsided one where all Gaussians crowd one corner
(the worst case for a fixed split), and checks bit-reproducibility of 3 repeated backwards.

    python benchmarks/backward_schedule.py

Writes ``benchmarks/results/backward_schedule.{json,csv,png}``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import time
from pathlib import Path

import torch

import components.rasterizers.cpu_kernel as cpu_kernel
from components.rasterizers import RasterizerConfig
from components.rasterizers.bench import make_scene

SCHEDULES = {"fixed": True, "first-come": False}


def corner_scene(n: int, width: int, height: int) -> dict:
    """make_scene's Gaussians squeezed into the top-left quarter of the image: a few tiles hold all the work."""
    scene = make_scene(n, width, height)
    means = scene["means"].clone()
    f = scene["Ks"][0, 0, 0]
    u = means[:, 0] * f / means[:, 2] + width / 2  # pixel x, y
    v = means[:, 1] * f / means[:, 2] + height / 2
    u, v = u * 0.25, v * 0.25
    means[:, 0] = (u - width / 2) * means[:, 2] / f
    means[:, 1] = (v - height / 2) * means[:, 2] / f
    scene["means"] = means
    return scene


def grads_of(rast, scene: dict, width: int, height: int) -> tuple[float, torch.Tensor]:
    leaves = {k: v.clone().requires_grad_(k not in ("viewmats", "Ks")) for k, v in scene.items()}
    t0 = time.perf_counter()
    out = rast.rasterize(**leaves, width=width, height=height, sh_degree=3)
    (out.rgb.square().sum() + out.alpha.sum()).backward()
    dt = time.perf_counter() - t0
    flat = torch.cat(
        [leaves[k].grad.reshape(-1) for k in ("means", "quats", "scales", "opacities", "colors")]
    )
    return dt, flat


def bench(name: str, scene: dict, width: int, height: int, repeats: int, rast) -> list[dict]:
    times: dict[str, list[float]] = {s: [] for s in SCHEDULES}
    grads: dict[str, list[torch.Tensor]] = {s: [] for s in SCHEDULES}
    for fixed in SCHEDULES.values():  # warm-up
        cpu_kernel.FIXED_SCHEDULE = fixed
        grads_of(rast, scene, width, height)
    for rep in range(repeats):
        order = list(SCHEDULES) if rep % 2 == 0 else list(reversed(SCHEDULES))
        for s in order:
            cpu_kernel.FIXED_SCHEDULE = SCHEDULES[s]
            dt, g = grads_of(rast, scene, width, height)
            times[s].append(dt)
            if len(grads[s]) < 3:
                grads[s].append(g)
    cpu_kernel.FIXED_SCHEDULE = True
    base = statistics.median(times["first-come"])
    rows = []
    for s in SCHEDULES:
        med = statistics.median(times[s])
        rows.append(
            {
                "scene": name,
                "schedule": s,
                "fwd_bwd_s": med,
                "fwd_bwd_min_s": min(times[s]),
                "ratio_vs_first_come": med / base,
                "bit_identical_repeats": all(torch.equal(grads[s][0], g) for g in grads[s][1:]),
            }
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = ap.parse_args()
    torch.set_num_threads(2)
    rast = RasterizerConfig(backend="cpu").setup()
    cases = [
        ("10k 160x120", make_scene(10_000, 160, 120), 160, 120),
        ("50k 320x240", make_scene(50_000, 320, 240), 320, 240),
        ("10k 320x240 x3 scale", make_scene(10_000, 320, 240, scale_mult=3.0), 320, 240),
        ("50k 320x240 corner", corner_scene(50_000, 320, 240), 320, 240),
    ]
    load0 = os.getloadavg()[0]
    rows = []
    for name, scene, w, h in cases:
        rows += bench(name, scene, w, h, args.repeats, rast)
    load1 = os.getloadavg()[0]

    print(f"{'scene':<24} {'schedule':<11} {'fwd+bwd':>9} {'ratio':>7} {'bit-identical':>14}")
    for r in rows:
        print(
            f"{r['scene']:<24} {r['schedule']:<11} {r['fwd_bwd_s'] * 1e3:7.1f}ms"
            f" {r['ratio_vs_first_come']:7.3f} {str(r['bit_identical_repeats']):>14}"
        )
    print(f"load average {load0:.1f} before, {load1:.1f} after; {args.repeats} interleaved repeats, medians")

    args.out.mkdir(parents=True, exist_ok=True)
    meta = {"threads": 2, "repeats": args.repeats, "load_before": load0, "load_after": load1}
    (args.out / "backward_schedule.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    with open(args.out / "backward_schedule.csv", "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=list(rows[0]))
        wr.writeheader()
        wr.writerows(rows)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["scene"] for r in rows))
    fig, ax = plt.subplots(figsize=(7, 3.2))
    for i, s in enumerate(SCHEDULES):
        vals = [
            next(r["fwd_bwd_s"] for r in rows if r["scene"] == n and r["schedule"] == s) * 1e3 for n in names
        ]
        ax.bar([j + 0.4 * i for j in range(len(names))], vals, width=0.4, label=s)
    ax.set_xticks([j + 0.2 for j in range(len(names))], names, fontsize=8)
    ax.set_ylabel("forward + backward (ms)")
    ax.set_title("cpu backend: backward tile schedule (2 threads)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.out / "backward_schedule.png", dpi=120)
    print(f"wrote {args.out}/backward_schedule.{{json,csv,png}}")


if __name__ == "__main__":
    main()
