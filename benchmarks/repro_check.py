"""Bit-reproducibility check for refactors: train fixed-seed short runs, hash every tensor.

    python benchmarks/repro_check.py --output-dir OUT               # writes OUT/hashes.json
    python benchmarks/repro_check.py --output-dir OUT2 --compare OUT/hashes.json

A behaviour-preserving change must give identical hashes for the final checkpoint of each
method (Gaussians, medium, optimiser state). Runs use the cpu kernel, one thread, seed 0.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
from pathlib import Path

import torch

METHODS = ("tri-dehaze", "vanilla-gs")


def tensor_hashes(obj, prefix: str = "") -> dict[str, str]:
    """sha256 of every tensor in a nested checkpoint payload, keyed by its path."""
    out: dict[str, str] = {}
    if isinstance(obj, torch.Tensor):
        t = obj.detach().cpu().contiguous().reshape(-1)
        out[prefix] = (
            f"{tuple(obj.shape)} {t.dtype} " + hashlib.sha256(t.view(torch.uint8).numpy()).hexdigest()[:16]
        )
    elif isinstance(obj, dict):
        for k in sorted(obj, key=str):
            out.update(tensor_hashes(obj[k], f"{prefix}/{k}"))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            out.update(tensor_hashes(v, f"{prefix}/{i}"))
    return out


def run(cmd: list[str]) -> None:
    print("+", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--output-dir", type=Path, required=True)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--compare", type=Path, default=None, help="hashes.json of a reference run")
    args = ap.parse_args()
    out: Path = args.output_dir
    scene = out / "scene"
    if not (scene / "transforms.json").exists():
        run(["td-synth", "scene", "--output-dir", str(scene), "--layout", "courtyard", "--haze", "homogeneous",
             "--seed", "3", "--num-views", "12", "--width", "64", "--height", "48", "--overwrite"])  # fmt: skip
    hashes: dict[str, dict[str, str]] = {}
    for method in METHODS:
        run(["td-train", method, "--data", str(scene), "--output-dir", str(out / "runs"), "--timestamp", method,
             "--max-steps", str(args.steps), "--seed", "0", "--threads", "1", "--vis", "none",
             "--pipeline.rasterizer.backend", "cpu", "--no-eval-at-end"])  # fmt: skip
        ckpts = sorted((out / "runs" / scene.name / method / method / "checkpoints").glob("step-*.ckpt"))
        payload = torch.load(ckpts[-1], map_location="cpu", weights_only=True)
        hashes[method] = tensor_hashes({k: v for k, v in payload.items() if k != "config"})
        print(f"{method}: {len(hashes[method])} tensors from {ckpts[-1]}")
    (out / "hashes.json").write_text(json.dumps(hashes, indent=1, sort_keys=True))
    if args.compare is None:
        return 0
    ref = json.loads(args.compare.read_text())
    bad = 0
    for method in METHODS:
        a, b = ref.get(method, {}), hashes[method]
        diff = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
        print(
            f"{method}: {len(b)} tensors, {len(diff)} differ" + (f": {', '.join(diff[:8])}" if diff else "")
        )
        bad += len(diff)
    print("IDENTICAL" if bad == 0 else "DIFFERENT")
    return 0 if bad == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
