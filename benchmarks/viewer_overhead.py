"""What watching costs: training speed without the viewer and with one headless browser connected.

The same tiny training (a generated hazy scene, same seed and steps) runs side by side as

* ``no viewer``           ``--vis none``;
* ``browser, resting``    ``--vis viewer`` with one headless Chromium connected whose camera rests
                           (the view is re-rendered as training advances, every ``refresh_seconds``);
* ``browser, orbiting``   the same browser dragging the camera all the time (renders back to back,
                           limited only by ``--viewer.render-share``: the worst case);
* ``..., renders off``     as orbiting but with a render share of 1e-4: what the browser on the same
                           machine and the websocket traffic cost without the renders.

Variants are interleaved round by round so load from other users of a shared machine hits all
alike; the training loop alone is timed (setup and the browser's start are not), medians are
reported with the ratio to ``no viewer``. The browser runs on the same machine (software WebGL),
so its own drawing competes for the CPU too; a browser on another machine costs the trainer less.

    python benchmarks/viewer_overhead.py                    # 150 steps x 2 rounds, 128x96 courtyard
    python benchmarks/viewer_overhead.py --steps 300 --rounds 3 --render-share 0.1

Needs node, chromium and playwright-core as the browser test does (docs/viewer.md).
Writes ``benchmarks/results/viewer_overhead.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from rich.console import Console  # noqa: E402

from components.synth.generate import SceneConfig, generate_scene  # noqa: E402
from pipelines.engine.trainer import Trainer  # noqa: E402
from pipelines.viewer import TrainingViewer  # noqa: E402
from tridehaze_plugin.cli.train import parse_args  # noqa: E402

RESULTS = REPO / "benchmarks" / "results"
BROWSER_CHECK = REPO / "tests" / "viewer" / "browser_check.mjs"
VARIANTS: dict[str, tuple[str | None, float | None]] = {
    "no viewer": (None, None),
    "browser, resting": ("rest", None),
    "browser, orbiting": ("orbit", None),
    "browser, orbiting, renders off": ("orbit", 1e-4),
}
"""name -> (browser mode, render share override). ``renders off``: the same browser with the viewer
all but never rendering, i.e. what the browser and the websocket traffic alone cost."""


def parse() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=150, help="training steps per variant and round")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--method", default="tri-dehaze")
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument(
        "--render-share", type=float, default=0.2, help="--viewer.render-share of the viewer runs"
    )
    ap.add_argument("--max-resolution", type=int, default=512, help="--viewer.max-resolution")
    ap.add_argument("--threads", type=int, default=1, help="torch threads of the trainer")
    ap.add_argument("--data", type=Path, default=None, help="a dataset instead of the generated scene")
    ap.add_argument("--out", type=Path, default=RESULTS / "viewer_overhead.json")
    return ap.parse_args()


def start_browser(url: str, mode: str, workdir: Path) -> subprocess.Popen:
    """Headless Chromium connected to ``url``; returns once it shows its first frame."""
    node = shutil.which("node")
    if node is None:
        raise SystemExit("node is not installed (see docs/viewer.md)")
    cmd = [node, str(BROWSER_CHECK), "--url", url, "--out", str(workdir), "--outputs", "clean", "--hold"]
    if mode == "orbit":
        cmd.append("--orbit")
    proc = subprocess.Popen(
        cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    for line in proc.stdout:
        if line.strip() == "ready":
            return proc
    raise SystemExit(f"the browser did not connect (exit {proc.wait()})")


def run_once(
    args: argparse.Namespace, data: Path, out: Path, name: str, mode: str | None, share: float | None
) -> dict:
    argv = [
        args.method, "--data", str(data), "--output-dir", str(out), "--timestamp", name.replace(",", "").replace(" ", "-"),
        "--max-steps", str(args.steps), "--threads", str(args.threads), "--no-eval-at-end",
        "--steps-per-save", str(10 * args.steps), "--steps-per-log", str(args.steps),
        "--vis", "none" if mode is None else "viewer", "--viewer.port", "0", "--viewer.no-wait-at-end",
        "--viewer.render-share", str(share or args.render_share), "--viewer.max-resolution", str(args.max_resolution),
    ]  # fmt: skip
    trainer = Trainer(parse_args(argv), console=Console(quiet=True), live_view=TrainingViewer())
    trainer.setup()
    browser = None
    try:
        if mode is not None:
            browser = start_browser(trainer.viewer.url, mode, out / "browser")
            time.sleep(1.0)  # settle: the first full-resolution frame is out
        loop = trainer.viewer.loop if trainer.viewer is not None else None
        frames0, busy0 = (loop.total_frames, loop.total_seconds) if loop else (0, 0.0)
        result = trainer.train()
    finally:
        if browser is not None:
            browser.stdin.close()
            try:
                browser.wait(30)
            except subprocess.TimeoutExpired:
                browser.kill()
    row = {"seconds": result.seconds, "its": args.steps / result.seconds}
    if loop is not None:
        row["frames"] = loop.total_frames - frames0
        row["render_seconds"] = loop.total_seconds - busy0
        row["render_share"] = row["render_seconds"] / result.seconds
    return row


def main() -> None:
    args = parse()
    torch_threads = args.threads
    with tempfile.TemporaryDirectory(prefix="viewer-overhead-") as tmp:
        tmp = Path(tmp)
        data = args.data
        if data is None:
            data = tmp / "scene"
            generate_scene(
                SceneConfig(output_dir=data, layout="courtyard", haze="patchy", seed=3, num_views=24,
                            width=args.width, height=args.height, samples=32, supersample=1, num_points=2000)
            )  # fmt: skip
        runs: dict[str, list[dict]] = {name: [] for name in VARIANTS}
        load_before = os.getloadavg()
        for r in range(args.rounds):
            order = list(VARIANTS) if r % 2 == 0 else list(VARIANTS)[::-1]
            for name in order:
                row = run_once(args, data, tmp / f"round{r}", name, *VARIANTS[name])
                runs[name].append(row)
                print(f"round {r + 1}/{args.rounds}  {name:<31} {row['seconds']:7.2f} s  {row['its']:6.2f} it/s"
                      + (f"  {row['frames']} frames, {row['render_share']:.0%} of the time rendering"
                         if "frames" in row else ""), flush=True)  # fmt: skip
    base = statistics.median(x["seconds"] for x in runs["no viewer"])
    summary = {}
    for name, rows in runs.items():
        secs = statistics.median(x["seconds"] for x in rows)
        summary[name] = {
            "median_seconds": secs,
            "its": args.steps / secs,
            "slowdown": secs / base,
            "frames": statistics.median(x.get("frames", 0) for x in rows),
            "render_share": statistics.median(x.get("render_share", 0.0) for x in rows),
        }
    print(f"\n{args.method}, {args.steps} steps, median of {args.rounds} round(s), {torch_threads} torch thread(s), "
          f"render share limit {args.render_share:.0%}")  # fmt: skip
    print(f"{'variant':<32}{'seconds':>9}{'it/s':>8}{'slowdown':>10}{'frames':>8}{'rendering':>11}")
    for name, s in summary.items():
        print(f"{name:<32}{s['median_seconds']:>9.2f}{s['its']:>8.2f}{s['slowdown']:>9.2f}x"
              f"{s['frames']:>8.0f}{s['render_share']:>10.0%}")  # fmt: skip
    report = {
        "method": args.method,
        "steps": args.steps,
        "rounds": args.rounds,
        "scene": str(args.data) if args.data else f"generated courtyard {args.width}x{args.height}, 24 views",
        "threads": torch_threads,
        "render_share_limit": args.render_share,
        "max_resolution": args.max_resolution,
        "machine": {
            "cpus": os.cpu_count(),
            "platform": platform.platform(),
            "load_before": load_before,
            "load_after": os.getloadavg(),
        },  # fmt: skip
        "summary": summary,
        "runs": runs,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
