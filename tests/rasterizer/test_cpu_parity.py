"""Backend ``cpu`` against the torch reference: forward outputs, edge cases, options.

Tolerances (float32, both backends; colours in [0, 1]): rgb / alpha within ``5e-5`` absolute,
``depth_accum`` within ``5e-5`` relative to the largest camera z, ``depth`` where ``alpha > 0.01``
within ``1e-4`` relative; ``radii`` / ``visible`` identical. The backends differ only by float32
rounding (product order, ``exp`` polynomial vs torch's); typical differences are ~1e-7, the worst
(~2e-5) sit on long thin splats whose ``sigma`` terms cancel, where the float32 torch reference is
itself ~1e-5 away from float64.
"""

from __future__ import annotations

import math

import pytest
import torch

from components.rasterizers import CpuRasterizer, RasterizerConfig, TorchRasterizer

pytestmark = pytest.mark.skipif(not CpuRasterizer.available(), reason="no C++ compiler for the cpu kernel")


def random_scene(
    seed: int, n: int, width: int, height: int, *, cams: int = 2, sh_degree: int | None = 3, D: int = 3
):
    """Random Gaussians around C slightly different cameras: some behind, some off-screen, mixed sizes."""
    g = torch.Generator().manual_seed(seed)
    f = 0.8 * width
    z = torch.rand(n, generator=g) * 6.0 - 0.5  # about 8 % behind the camera
    u = torch.rand(n, generator=g) * 1.6 - 0.3  # about 35 % centred off-screen
    v = torch.rand(n, generator=g) * 1.6 - 0.3
    zc = z.clamp_min(0.3)
    means = torch.stack([(u - 0.5) * width * zc / f, (v - 0.5) * height * zc / f, z], dim=-1)
    scales = torch.exp(torch.rand(n, 3, generator=g) * 4.0 - 5.5)  # 4 mm .. 22 cm
    quats = torch.randn(n, 4, generator=g)
    opacities = torch.rand(n, generator=g)
    if sh_degree is None:
        colors = torch.rand(n, D, generator=g)
    else:
        colors = torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g) * 0.05
        colors[:, 0] = (torch.rand(n, 3, generator=g) * 0.8 - 0.4) / 0.28209479177387814
    viewmats = torch.eye(4).repeat(cams, 1, 1)
    for c in range(cams):
        a = 0.1 * c
        viewmats[c, :3, :3] = torch.tensor(
            [[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]]
        )
        viewmats[c, :3, 3] = torch.tensor([0.05 * c, -0.02 * c, 0.1 * c])
    K = torch.tensor([[f, 0.0, width / 2 + 0.3], [0.0, 1.05 * f, height / 2 - 0.2], [0.0, 0.0, 1.0]])
    scene = dict(
        means=means, quats=quats, scales=scales, opacities=opacities, colors=colors,
        viewmats=viewmats, Ks=K.expand(cams, 3, 3).clone(),
    )  # fmt: skip
    background = torch.rand(cams, 3 if sh_degree is not None else D, generator=g)
    return scene, background


def render(rast, scene, width, height, **kw):
    return rast.rasterize(**scene, width=width, height=height, **kw)


def assert_same_images(ref, out, zmax: float = 6.0) -> None:
    assert torch.equal(ref.radii, out.radii) and torch.equal(ref.visible, out.visible)
    torch.testing.assert_close(out.rgb, ref.rgb, atol=5e-5, rtol=0)
    torch.testing.assert_close(out.alpha, ref.alpha, atol=5e-5, rtol=0)
    torch.testing.assert_close(out.depth_accum, ref.depth_accum, atol=5e-5 * zmax, rtol=0)
    hit = ref.alpha > 0.01
    torch.testing.assert_close(out.depth[hit], ref.depth[hit], atol=0, rtol=1e-4)
    torch.testing.assert_close(out.depths, ref.depths)


@pytest.mark.parametrize("size", [(37, 23), (64, 48), (160, 120)])
@pytest.mark.parametrize("sh_degree", [0, 3])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_forward_matches_torch(size, sh_degree, seed) -> None:
    width, height = size
    scene, bg = random_scene(seed, 300, width, height, sh_degree=sh_degree)
    kw = dict(background=bg if seed != 1 else None, sh_degree=sh_degree)
    ref = render(TorchRasterizer(), scene, width, height, **kw)
    out = render(CpuRasterizer(), scene, width, height, **kw)
    assert out.rgb.shape == (2, height, width, 3) and out.rgb.dtype == torch.float32
    assert ref.visible.any() and (~ref.visible).any()
    assert_same_images(ref, out)


@pytest.mark.parametrize("tile_size", [4, 8, 32])
def test_other_tile_sizes(tile_size) -> None:
    """Tiles narrower than a vector row (masked lanes) and wider (two vector chunks per row)."""
    scene, bg = random_scene(3, 200, 45, 31, sh_degree=1)
    cfg = RasterizerConfig(tile_size=tile_size)
    ref = render(TorchRasterizer(cfg), scene, 45, 31, background=bg, sh_degree=1)
    out = render(CpuRasterizer(cfg), scene, 45, 31, background=bg, sh_degree=1)
    assert_same_images(ref, out)


@pytest.mark.parametrize("D", [1, 3, 5])
def test_plain_colours_of_any_width(D) -> None:
    """[N, D] and [C, N, D] colours (D + depth = 2, 4: compiled widths; 6: the generic path)."""
    scene, bg = random_scene(4, 200, 40, 30, sh_degree=None, D=D)
    per_cam = scene | {"colors": torch.rand(2, 200, D, generator=torch.Generator().manual_seed(9))}
    for sc in (scene, per_cam):
        ref = render(TorchRasterizer(), sc, 40, 30, background=bg)
        out = render(CpuRasterizer(), sc, 40, 30, background=bg)
        assert out.rgb.shape == (2, 30, 40, D)
        assert_same_images(ref, out)


def _one(means, scales, opacity, colour=(0.9, 0.3, 0.1)):
    n = len(means)
    return dict(
        means=torch.tensor(means, dtype=torch.float32).reshape(n, 3),
        quats=torch.tensor([[1.0, 0.2, -0.1, 0.3]] * n).reshape(n, 4),
        scales=torch.tensor(scales, dtype=torch.float32).reshape(n, 3),
        opacities=torch.tensor(opacity, dtype=torch.float32),
        colors=torch.tensor([colour] * n).reshape(n, 3),
        viewmats=torch.eye(4)[None],
        Ks=torch.tensor([[[30.0, 0.0, 20.0], [0.0, 30.0, 15.0], [0.0, 0.0, 1.0]]]),
    )


EDGE_CASES = {
    "behind the camera": _one([[0.0, 0.0, -1.0], [0.1, 0.0, 0.005]], [[0.1] * 3] * 2, [0.9, 0.9]),
    "off-screen": _one([[5.0, 0.0, 1.0], [0.0, -4.0, 1.0], [0.8, 0.6, 1.0]], [[0.05] * 3] * 3, [0.9] * 3),
    "huge splat": _one([[0.1, 0.0, 1.0]], [[3.0, 2.0, 0.5]], [0.7]),
    "tiny splats": _one([[0.0, 0.0, 2.0], [0.1, 0.05, 3.0]], [[1e-6] * 3, [1e-4] * 3], [0.9, 1.0]),
    "zero opacity": _one([[0.0, 0.0, 2.0], [0.02, 0.0, 2.5]], [[0.2] * 3] * 2, [0.0, 0.5]),
    "opacity one (0.999 clamp, stop rule)": _one(
        [[0.0, 0.0, 2.0], [0.01, 0.0, 2.2], [0.0, 0.01, 2.4]], [[0.3] * 3] * 3, [1.0, 1.0, 1.0]
    ),
    "all culled": _one([[0.0, 0.0, -2.0], [9.0, 9.0, 1.0]], [[0.1] * 3] * 2, [0.9, 0.9]),
    "empty scene": _one([], [], []),
}


@pytest.mark.parametrize("case", list(EDGE_CASES))
def test_edge_cases(case) -> None:
    scene = EDGE_CASES[case]
    bg = torch.tensor([0.2, 0.4, 0.6])
    outs = []
    for rast in (TorchRasterizer(), CpuRasterizer()):
        leaves = {k: v.clone().requires_grad_(k not in ("viewmats", "Ks")) for k, v in scene.items()}
        out = render(rast, leaves, 40, 30, background=bg)
        (out.rgb.sum() + out.alpha.sum() + out.depth.sum()).backward()  # must work even with nothing drawn
        outs.append((out, leaves))
    (ref, ref_leaves), (out, leaves) = outs
    assert_same_images(ref, out)
    for k, leaf in leaves.items():
        if leaf.requires_grad:
            expect = ref_leaves[k].grad if ref_leaves[k].grad is not None else torch.zeros_like(leaf)
            got = leaf.grad if leaf.grad is not None else torch.zeros_like(leaf)
            scale = float(expect.abs().max()) if expect.numel() else 0.0
            torch.testing.assert_close(got, expect, atol=1e-4 * (1 + scale), rtol=0)
    if case in ("all culled", "empty scene", "behind the camera"):
        assert not out.visible.any() and (out.alpha == 0).all()
        torch.testing.assert_close(out.rgb, bg.expand(1, 30, 40, 3))
    if case.startswith("opacity one"):
        assert out.alpha.max() > 0.999  # stacked nearly opaque splats saturate, each clamped at 0.999


def test_threads_and_grad_modes_agree() -> None:
    """1 or 2 kernel threads, no_grad and inference_mode: same images (forward is deterministic)."""
    scene, bg = random_scene(5, 400, 64, 48)
    base = render(CpuRasterizer(threads=1), scene, 64, 48, background=bg, sh_degree=3)
    for rast in (CpuRasterizer(threads=2), CpuRasterizer(threads=3)):
        out = render(rast, scene, 64, 48, background=bg, sh_degree=3)
        assert torch.equal(out.rgb, base.rgb) and torch.equal(out.alpha, base.alpha)
    with torch.no_grad():
        assert torch.equal(render(CpuRasterizer(), scene, 64, 48, background=bg, sh_degree=3).rgb, base.rgb)
    with torch.inference_mode():
        assert torch.equal(render(CpuRasterizer(), scene, 64, 48, background=bg, sh_degree=3).rgb, base.rgb)


def test_backward_is_bit_reproducible_for_a_thread_count() -> None:
    """Repeated backwards give bit-identical gradients (fixed tile schedule): training with one seed
    is reproducible. With first-come scheduling this fails nearly every time on 2+ cores."""
    scene, bg = random_scene(7, 20000, 160, 120, cams=1)
    grads = []
    for _ in range(4):
        leaves = {k: v.clone().requires_grad_(k not in ("viewmats", "Ks")) for k, v in scene.items()}
        out = render(CpuRasterizer(threads=2), leaves, 160, 120, background=bg, sh_degree=3)
        (out.rgb.square().sum() + out.alpha.sum()).backward()
        grads.append([leaves[k].grad for k in ("means", "quats", "scales", "opacities", "colors")])
    assert float(grads[0][0].abs().max()) > 0
    for other in grads[1:]:
        assert all(torch.equal(a, b) for a, b in zip(grads[0], other, strict=True))


def test_float64_inputs_use_the_exact_reference() -> None:
    scene, bg = random_scene(6, 100, 30, 20)
    scene64 = {k: v.double() for k, v in scene.items()}
    out = render(CpuRasterizer(), scene64, 30, 20, background=bg.double(), sh_degree=3)
    ref = render(TorchRasterizer(), scene64, 30, 20, background=bg.double(), sh_degree=3)
    assert out.rgb.dtype == torch.float64 and torch.equal(out.rgb, ref.rgb)


def test_blended_per_pixel_counts_the_composited_gaussians() -> None:
    """One Gaussian: blended exactly where it changes alpha; three opaque ones: the stop rule cuts."""
    one = EDGE_CASES["huge splat"]
    counts = CpuRasterizer().blended_per_pixel(**one, width=40, height=30)
    ref = TorchRasterizer().rasterize(**one, width=40, height=30)
    assert counts.shape == (1, 30, 40) and torch.equal(counts > 0, ref.alpha[..., 0] > 0)
    assert counts.max() == 1
    stack = EDGE_CASES["opacity one (0.999 clamp, stop rule)"]
    counts = CpuRasterizer().blended_per_pixel(**stack, width=40, height=30)
    assert counts.max() == 3
    # at the centre all three reach the 0.999 clamp: T = 1e-3 after two, a third would give 1e-6
    assert counts[0, 15, 20] == 2
