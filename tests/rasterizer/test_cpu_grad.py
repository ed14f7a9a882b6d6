"""Gradients of backend ``cpu``: parity with the torch reference and finite differences.

The kernel is float32 only, so there is no float64 gradcheck of it. Instead:

* against the float32 torch reference on random scenes (behind / off-screen Gaussians, C=2,
  SH 0 and 3): every input gradient (viewmats and Ks included) and ``means2d.grad`` within ``1e-3 * max|reference|`` per
  tensor (observed up to 3e-4, mostly the reference's own float32 error: on such scenes the cpu
  gradients are as close to float64 as the reference's);
* against the float64 torch reference on well-conditioned scenes (everything in front, no
  decision near its threshold): within ``2e-5 * max|reference|`` (observed ~3e-6);
* central finite differences of the compositing Function itself in float32 (step 1e-2 on a
  smooth tiny scene): directional derivatives within 1e-2 relative.
"""

from __future__ import annotations

import pytest
import torch

from components.rasterizers import CpuRasterizer, TorchRasterizer, cpu_build
from components.rasterizers.bench import make_scene
from components.rasterizers.cpu_kernel import CompositeFn, bin_gaussians
from components.rasterizers.projection import project_gaussians
from tests.rasterizer.test_cpu_parity import random_scene

pytestmark = pytest.mark.skipif(not CpuRasterizer.available(), reason="no C++ compiler for the cpu kernel")


def grads(rast, scene, width, height, dtype=torch.float32, **kw):
    """Input gradients of a random weighting of rgb, alpha and depth (weights drawn in float64)."""
    leaves = {k: v.to(dtype).clone().requires_grad_() for k, v in scene.items()}
    kw = {k: v.to(dtype) if isinstance(v, torch.Tensor) else v for k, v in kw.items()}
    out = rast.rasterize(**leaves, width=width, height=height, **kw)
    g = torch.Generator().manual_seed(7)
    w = [
        torch.rand(t.shape, generator=g, dtype=torch.float64).to(dtype)
        for t in (out.rgb, out.alpha, out.depth)
    ]
    ((out.rgb * w[0]).sum() + (out.alpha * w[1]).sum() + 0.1 * (out.depth * w[2]).sum()).backward()
    res = {k: v.grad for k, v in leaves.items() if v.requires_grad}
    res["means2d"] = out.means2d.grad
    return res


def assert_grads_close(got: dict, ref: dict, rel: float) -> None:
    for k in got:
        r = ref[k]
        scale = float(r.abs().max())
        torch.testing.assert_close(
            got[k].to(r.dtype), r, atol=rel * scale, rtol=0, msg=lambda m, k=k: f"{k}: {m}"
        )


@pytest.mark.parametrize("size", [(37, 23), (96, 64)])
@pytest.mark.parametrize("sh_degree", [0, 3])
@pytest.mark.parametrize("seed", [0, 1])
def test_gradients_match_torch(size, sh_degree, seed) -> None:
    width, height = size
    scene, bg = random_scene(seed, 300, width, height, sh_degree=sh_degree)
    kw = dict(background=bg, sh_degree=sh_degree)
    ref = grads(TorchRasterizer(), scene, width, height, **kw)
    got = grads(CpuRasterizer(), scene, width, height, **kw)
    assert set(got) == {"means", "quats", "scales", "opacities", "colors", "viewmats", "Ks", "means2d"}
    assert_grads_close(got, ref, 1e-3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gradients_match_float64_reference(seed) -> None:
    scene = make_scene(200, 48, 32, seed=seed, sh_degree=2, scale_mult=3.0)
    scene["opacities"] = scene["opacities"] * 0.9  # away from the 0.999 clamp
    bg = torch.tensor([0.3, 0.5, 0.7])
    ref = grads(TorchRasterizer(), scene, 48, 32, torch.float64, background=bg, sh_degree=2)
    got = grads(CpuRasterizer(), scene, 48, 32, background=bg, sh_degree=2)
    assert_grads_close(got, ref, 2e-5)


def test_two_threads_sum_gradients_like_one() -> None:
    """Per-thread buffers are summed in another order (and tiles go to threads dynamically): the
    kernel's own gradients agree to ~1e-7; the projection backward amplifies that for thin splats."""
    scene, bg = random_scene(3, 400, 64, 48)
    one = grads(CpuRasterizer(threads=1), scene, 64, 48, background=bg, sh_degree=3)
    two = grads(CpuRasterizer(threads=2), scene, 64, 48, background=bg, sh_degree=3)
    assert_grads_close({k: two[k] for k in ("means2d", "opacities", "colors")}, one, 2e-6)
    assert_grads_close(two, one, 1e-4)


def test_composite_function_against_finite_differences() -> None:
    """Directional derivatives of the compiled Function (float32, central differences)."""
    W, H = 10, 8
    means = torch.tensor([[0.05, -0.03, 2.0], [-0.04, 0.02, 2.3], [0.0, 0.04, 2.6]])
    quats = torch.tensor([[1.0, 0.1, -0.2, 0.3], [0.9, -0.3, 0.2, 0.1], [0.8, 0.2, 0.4, -0.1]])
    scales = torch.tensor([[0.5, 0.35, 0.45], [0.4, 0.6, 0.5], [0.55, 0.45, 0.5]])
    viewmat, K = torch.eye(4)[None], torch.tensor([[[20.0, 0, 5.1], [0, 18.0, 3.9], [0, 0, 1]]])
    opacities = torch.tensor([0.5, 0.6, 0.4])
    proj = project_gaussians(means, quats, scales, viewmat, K, W, H, opacities=opacities)
    # every 1/255 box reaches far past the 10x8 image from centres near its middle: no pixel is at
    # the coverage edge, so the finite differences see no discontinuity
    assert (proj.radii >= 10).all()
    lib = cpu_build.load_kernel()
    bins = bin_gaussians(lib, proj.means2d, proj.depths, proj.radii, W, H, 16)
    colors = torch.tensor([[[0.9, 0.2, 0.1], [0.1, 0.8, 0.3], [0.2, 0.3, 0.9]]])
    inputs = [
        proj.means2d.detach(),
        proj.conics.detach(),
        opacities[None],
        torch.cat([colors, proj.depths.detach()[..., None]], dim=-1),
    ]
    g = torch.Generator().manual_seed(0)
    w_acc, w_t = torch.rand(1, H, W, 4, generator=g), torch.rand(1, H, W, 1, generator=g)

    def loss(*xs):
        acc, trans = CompositeFn.apply(*xs, lib, bins, W, H, 2)
        return (acc * w_acc).sum() + (trans * w_t).sum()

    leaves = [x.clone().requires_grad_() for x in inputs]
    loss(*leaves).backward()
    for i, leaf in enumerate(leaves):
        for trial in range(3):
            u = torch.randn(leaf.shape, generator=g)
            eps = 1e-2 / float(u.abs().max()) * (0.1 if i == 1 else 1.0)  # conics are ~0.01-0.1
            xs_p = [x + eps * u if j == i else x for j, x in enumerate(inputs)]
            xs_m = [x - eps * u if j == i else x for j, x in enumerate(inputs)]
            with torch.no_grad():
                fd = (loss(*xs_p).double() - loss(*xs_m).double()) / (2 * eps)
            an = float((leaf.grad * u).sum())
            assert abs(fd - an) <= 1e-2 * max(abs(an), 1e-2), f"input {i} trial {trial}: fd {fd} vs {an}"
