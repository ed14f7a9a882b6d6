"""Rasterizer backends side by side: forward and forward+backward seconds on the same scenes.

Every available backend renders the same frustum-filling random scenes (``make_scene`` of
``components/rasterizers/bench.py``: SH degree 3, ~12 blended Gaussians per pixel). Repeats are
interleaved (backend order rotates each round) so that load from other users of a shared machine
hits all backends alike; medians are reported, with speed-ups against ``torch`` and composited
Gaussian-pixel pairs per second (pairs after the skip / stop rules, counted by the cpu kernel).
Where CUDA and gsplat exist, ``gsplat`` is timed on CUDA tensors (synchronised); its speed-up is
against ``torch`` on CPU, the alternative a user without the GPU would have.

    python benchmarks/rasterizers.py                   # 10k / 50k Gaussians at 160x120 / 320x240
    python benchmarks/rasterizers.py --thread-sweep    # thread settings of the cpu backend

Writes ``benchmarks/results/rasterizers.{json,csv,png}``; the sweep writes
``benchmarks/results/rasterizers.threads.{json,csv}``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from components.native import build as native_build  # noqa: E402
from components.rasterizers import CpuRasterizer, RasterizerConfig, cpu_build  # noqa: E402
from components.rasterizers.bench import make_scene  # noqa: E402
from tridehaze_plugin.registry import REGISTRY  # noqa: E402

RESULTS = REPO / "benchmarks" / "results"


def available_backends() -> list[str]:
    names = []
    for name in ("torch", "cpu", "gsplat"):
        if ("rasterizer", name) not in REGISTRY:
            continue
        if name == "gsplat" and not torch.cuda.is_available():
            continue
        if REGISTRY.get("rasterizer", name).available():
            names.append(name)
    return names


def machine() -> dict:
    cpu = platform.processor()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    return {
        "cpu": cpu,
        "cores": len(os.sched_getaffinity(0)),
        "torch": torch.__version__,
        "gpu": torch.cuda.get_device_name() if torch.cuda.is_available() else None,
        "python": platform.python_version(),
    }


def load() -> float:
    return os.getloadavg()[0]


def device_of(backend: str) -> torch.device:
    """gsplat renders CUDA tensors; torch and cpu are timed on CPU ones (the CPU user's case)."""
    return torch.device("cuda" if backend == "gsplat" else "cpu")


def timer(rast, leaves: dict, width: int, height: int, backward: bool):
    cuda = leaves["means"].device.type == "cuda"

    def sync() -> None:
        if cuda:  # CUDA launches are asynchronous: time the finished work
            torch.cuda.synchronize()

    def run() -> float:
        sync()
        t0 = time.perf_counter()
        with torch.set_grad_enabled(backward):
            out = rast.rasterize(**leaves, width=width, height=height, sh_degree=3)
            if backward:
                (out.rgb.sum() + out.alpha.sum()).backward()
        sync()
        return time.perf_counter() - t0

    return run


def bench_case(
    backends: list[str], n: int, width: int, height: int, repeats: int, scale_mult: float
) -> list[dict]:
    scene = make_scene(n, width, height, scale_mult=scale_mult)

    def leaves(backend: str) -> dict:
        dev = device_of(backend)
        return {k: v.to(dev).clone().requires_grad_(k not in ("viewmats", "Ks")) for k, v in scene.items()}

    pairs = None
    if CpuRasterizer.available():
        pairs = int(CpuRasterizer().blended_per_pixel(**scene, width=width, height=height, sh_degree=3).sum())
    rasts = {b: RasterizerConfig(backend=b).setup(device=device_of(b)) for b in backends}
    inputs = {b: leaves(b) for b in backends}
    runs = {(b, bw): timer(rasts[b], inputs[b], width, height, bw) for b in backends for bw in (False, True)}
    for b in backends:
        runs[(b, True)]()  # warm-up (first-call allocations, kernel load)
    times: dict[tuple[str, bool], list[float]] = {k: [] for k in runs}
    for rep in range(repeats):
        order = backends[rep % len(backends) :] + backends[: rep % len(backends)]
        for b in order:
            for bw in (False, True):
                times[(b, bw)].append(runs[(b, bw)]())
    rows = []
    for b in backends:
        fwd, both = statistics.median(times[(b, False)]), statistics.median(times[(b, True)])
        rows.append(
            {
                "backend": b,
                "n": n,
                "width": width,
                "height": height,
                "forward_s": fwd,
                "fwd_bwd_s": both,
                "forward_min_s": min(times[(b, False)]),
                "fwd_bwd_min_s": min(times[(b, True)]),
                "blended_pairs": pairs,
                "pairs_per_s_fwd": pairs / fwd if pairs else None,
                "pairs_per_s_fwd_bwd": pairs / both if pairs else None,
            }
        )
    ref = next((r for r in rows if r["backend"] == "torch"), None)
    for r in rows:
        r["speedup_fwd"] = ref["forward_s"] / r["forward_s"] if ref else None
        r["speedup_fwd_bwd"] = ref["fwd_bwd_s"] / r["fwd_bwd_s"] if ref else None
    return rows


def print_table(rows: list[dict]) -> None:
    head = (
        f"{'N':>6} {'image':>8} {'backend':>7} {'forward':>9} {'fwd+bwd':>9} {'x torch':>13} {'Mpairs/s':>14}"
    )
    print(head + "\n" + "-" * len(head))
    for r in rows:
        sp = f"{r['speedup_fwd']:5.1f} /{r['speedup_fwd_bwd']:5.1f}" if r["speedup_fwd"] else "-"
        pp = (
            f"{r['pairs_per_s_fwd'] / 1e6:6.1f} /{r['pairs_per_s_fwd_bwd'] / 1e6:6.1f}"
            if r["pairs_per_s_fwd"]
            else "-"
        )
        size = f"{r['width']}x{r['height']}"
        print(
            f"{r['n']:>6} {size:>8} {r['backend']:>7} {r['forward_s']:8.3f}s {r['fwd_bwd_s']:8.3f}s {sp:>13} {pp:>14}"
        )


def write_outputs(stem: str, meta: dict, rows: list[dict]) -> None:
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{stem}.json").write_text(json.dumps({"config": meta, "results": rows}, indent=2) + "\n")
    with open(RESULTS / f"{stem}.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def plot(rows: list[dict]) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    cases = sorted({(r["n"], r["width"], r["height"]) for r in rows}, key=lambda c: (c[1] * c[2], c[0]))
    backends = list(dict.fromkeys(r["backend"] for r in rows))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    width = 0.8 / len(backends)
    for ax, key, title in zip(
        axes, ("forward_s", "fwd_bwd_s"), ("forward", "forward + backward"), strict=True
    ):
        for i, b in enumerate(backends):
            vals = [
                next(r[key] for r in rows if r["backend"] == b and (r["n"], r["width"], r["height"]) == c)
                for c in cases
            ]
            ax.bar([j + i * width for j in range(len(cases))], vals, width, label=b)
        ax.set_xticks([j + 0.4 - width / 2 for j in range(len(cases))])
        ax.set_xticklabels([f"{n // 1000}k\n{w}x{h}" for n, w, h in cases])
        ax.set_yscale("log")
        ax.set_title(title)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylabel("seconds (median)")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(RESULTS / "rasterizers.png", dpi=120)


# ------------------------------------------------------------------------------------------
# thread settings of the cpu backend (each in a fresh process: OMP_* act at start-up only)

SWEEP: dict[str, dict[str, str]] = {
    "torch 2, kernel 2 (default)": {"torch": "2", "kernel": "2"},
    "torch 2, kernel 1": {"torch": "2", "kernel": "1"},
    "torch 1, kernel 2": {"torch": "1", "kernel": "2"},
    "torch 1, kernel 1": {"torch": "1", "kernel": "1"},
    "torch 2, kernel 2, OMP_WAIT_POLICY=PASSIVE": {"torch": "2", "kernel": "2", "OMP_WAIT_POLICY": "PASSIVE"},
    "torch 2, kernel 2, GOMP_SPINCOUNT=10000": {"torch": "2", "kernel": "2", "GOMP_SPINCOUNT": "10000"},
    "torch 2, kernel 2, std::thread build": {
        "torch": "2",
        "kernel": "2",
        native_build.PARALLEL_ENV_VAR: "threads",
    },
    "torch 1, kernel 2, std::thread build": {
        "torch": "1",
        "kernel": "2",
        native_build.PARALLEL_ENV_VAR: "threads",
    },
}
SWEEP_CASES = ((10000, 160, 120), (50000, 320, 240))


def sweep_child(torch_threads: int, kernel_threads: int, repeats: int) -> None:
    torch.set_num_threads(torch_threads)
    rast = CpuRasterizer(threads=kernel_threads)
    res = {"variant": cpu_build.load_kernel().tdh_variant}
    for n, w, h in SWEEP_CASES:
        scene = make_scene(n, w, h)
        leaves = {k: v.clone().requires_grad_(k not in ("viewmats", "Ks")) for k, v in scene.items()}
        run = timer(rast, leaves, w, h, True)
        run()
        res[f"{n}@{w}x{h}"] = statistics.median(run() for _ in range(repeats))
    print(json.dumps(res))


def thread_sweep(rounds: int, repeats: int) -> None:
    samples: dict[str, list[dict]] = {name: [] for name in SWEEP}
    loads = []
    for _ in range(rounds):
        for name, setting in SWEEP.items():
            env = dict(os.environ, **{k: v for k, v in setting.items() if k not in ("torch", "kernel")})
            cmd = [
                sys.executable,
                __file__,
                "--sweep-child",
                setting["torch"],
                setting["kernel"],
                str(repeats),
            ]
            loads.append(load())
            out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=True)
            samples[name].append(json.loads(out.stdout.strip().splitlines()[-1]))
    rows = []
    for name, got in samples.items():
        row = {"setting": name, "variant": got[0]["variant"], "rounds": len(got)}
        for n, w, h in SWEEP_CASES:
            key = f"{n}@{w}x{h}"
            vals = sorted(g[key] for g in got)
            row[f"{key}_median_ms"] = round(1e3 * statistics.median(vals), 1)
            row[f"{key}_best_ms"] = round(1e3 * vals[0], 1)
            row[f"{key}_worst_ms"] = round(1e3 * vals[-1], 1)
        rows.append(row)
    meta = machine() | {"rounds": rounds, "repeats": repeats, "load_avg_1min": [min(loads), max(loads)]}
    write_outputs("rasterizers.threads", meta, rows)
    print(
        f"{'setting':45s} "
        + "  ".join(f"{n // 1000}k@{w}x{h} median [best, worst] ms" for n, w, h in SWEEP_CASES)
    )
    for r in rows:
        cells = []
        for n, w, h in SWEEP_CASES:
            k = f"{n}@{w}x{h}"
            cells.append(f"{r[k + '_median_ms']:8.1f} [{r[k + '_best_ms']:.0f}, {r[k + '_worst_ms']:.0f}]")
        print(f"{r['setting']:45s} " + "  ".join(f"{c:>34s}" for c in cells))
    print(f"load average during the sweep: {min(loads):.1f} .. {max(loads):.1f}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, nargs="+", default=[10000, 50000])
    p.add_argument("--size", nargs="+", default=["160x120", "320x240"])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    p.add_argument("--backends", nargs="+", default=None, help="default: every available backend")
    p.add_argument("--scale-mult", type=float, default=1.0, help="larger Gaussians: more blended per pixel")
    p.add_argument("--thread-sweep", action="store_true", help="compare thread settings of the cpu backend")
    p.add_argument("--rounds", type=int, default=6, help="thread sweep: interleaved rounds")
    p.add_argument(
        "--sweep-child", nargs=3, type=int, metavar=("TORCH", "KERNEL", "REPEATS"), help=argparse.SUPPRESS
    )
    args = p.parse_args()
    if args.sweep_child:
        sweep_child(*args.sweep_child)
        return
    if args.thread_sweep:
        thread_sweep(args.rounds, repeats=7)
        return
    torch.set_num_threads(args.threads)
    backends = args.backends or available_backends()
    load_before = load()
    rows = []
    for size in args.size:
        w, h = (int(s) for s in size.split("x"))
        for n in args.n:
            rows += bench_case(backends, n, w, h, args.repeats, args.scale_mult)
    meta = machine() | {
        "torch_threads": args.threads,
        "cpu_kernel_variant": cpu_build.load_kernel().tdh_variant if "cpu" in backends else None,
        "repeats": args.repeats,
        "scale_mult": args.scale_mult,
        "sh_degree": 3,
        "load_avg_1min": [load_before, load()],
    }
    print_table(rows)
    print(f"load average: {load_before:.1f} before, {load():.1f} after")
    write_outputs("rasterizers", meta, rows)
    plot(rows)


if __name__ == "__main__":
    main()
