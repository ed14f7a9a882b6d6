"""Forward+backward timing of a rasterizer backend on a synthetic scene.

Usage: ``python -m components.rasterizers.bench --backend torch --n 1000 10000 --size 160x120 320x240``.
The scene fills the view frustum with random Gaussians (scene scale ~ an SfM-initialised model)
so that numbers are comparable between backends and machines.
"""

from __future__ import annotations

import argparse
import time

import torch

from components.rasterizers.base import RasterizerConfig


def make_scene(
    n: int,
    width: int,
    height: int,
    seed: int = 0,
    device: str = "cpu",
    sh_degree: int = 3,
    scale_mult: float = 1.0,
):
    """Random Gaussians inside the frustum of one camera at the origin looking along +z."""
    g = torch.Generator().manual_seed(seed)
    f = 0.9 * width
    z = torch.rand(n, generator=g) * 4.0 + 2.0
    u = torch.rand(n, generator=g) * 1.2 - 0.1
    v = torch.rand(n, generator=g) * 1.2 - 0.1
    means = torch.stack([(u * width - width / 2) * z / f, (v * height - height / 2) * z / f, z], dim=-1)
    scales = torch.exp(torch.rand(n, 3, generator=g) * 2.3 - 5.3) * scale_mult  # 5 mm .. 5 cm
    quats = torch.randn(n, 4, generator=g)
    opacities = torch.rand(n, generator=g) * 0.95 + 0.05
    k = (sh_degree + 1) ** 2
    sh = torch.randn(n, k, 3, generator=g) * 0.1
    sh[:, 0] = (torch.rand(n, 3, generator=g) - 0.5) / 0.28209479177387814
    viewmats = torch.eye(4)[None]
    Ks = torch.tensor([[[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]]])
    tensors = dict(
        means=means, quats=quats, scales=scales, opacities=opacities, colors=sh, viewmats=viewmats, Ks=Ks
    )
    return {k_: t.to(device) for k_, t in tensors.items()}


def time_backend(
    backend: str,
    n: int,
    width: int,
    height: int,
    repeats: int = 3,
    device: str = "cpu",
    scale_mult: float = 1.0,
) -> dict:
    """Median forward and forward+backward seconds (after one warm-up)."""
    rast = RasterizerConfig(backend=backend).setup()
    scene = make_scene(n, width, height, device=device, scale_mult=scale_mult)
    leaves = {k: v.clone().requires_grad_(k not in ("viewmats", "Ks")) for k, v in scene.items()}

    def run(backward: bool) -> float:
        t0 = time.perf_counter()
        with torch.set_grad_enabled(backward):
            out = rast.rasterize(**leaves, width=width, height=height, sh_degree=3)
            if backward:
                (out.rgb.sum() + out.alpha.sum()).backward()
        if device != "cpu":
            torch.cuda.synchronize()
        return time.perf_counter() - t0

    run(True)
    fwd = sorted(run(False) for _ in range(repeats))[repeats // 2]
    both = sorted(run(True) for _ in range(repeats))[repeats // 2]
    return {"backend": backend, "n": n, "width": width, "height": height, "forward_s": fwd, "fwd_bwd_s": both}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--backend", default="torch")
    p.add_argument("--n", type=int, nargs="+", default=[1000, 10000])
    p.add_argument("--size", type=str, nargs="+", default=["160x120", "320x240"])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--device", default="cpu")
    p.add_argument("--scale-mult", type=float, default=1.0, help="larger Gaussians: more overlap per pixel")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    import components.rasterizers  # noqa: F401  (registers backends)

    for size in args.size:
        w, h = (int(s) for s in size.split("x"))
        for n in args.n:
            r = time_backend(args.backend, n, w, h, device=args.device, scale_mult=args.scale_mult)
            print(
                f"{r['backend']:>6} N={n:>6} {w}x{h}: forward {r['forward_s']:.3f} s, fwd+bwd {r['fwd_bwd_s']:.3f} s"
            )


if __name__ == "__main__":
    main()
