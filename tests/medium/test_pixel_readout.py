"""The compiled per-pixel read-out against the torch reference: values, gradients, threads,
and the compositor with either path (tolerances: float32 rounding; float64 to 1e-12)."""

from __future__ import annotations

import pytest
import torch

from components.medium import pixel_readout as pr
from components.medium.compositing import CompositeConfig, MediumCompositor
from components.native import build as native_build
from tests.stability.test_compositing_properties import BlobField, _camera, _depth

needs_kernel = pytest.mark.skipif(not pr.kernel_available(), reason="no C++ compiler for the kernel")


def _grid(
    dtype: torch.dtype, R: int = 30, K: int = 8, P: int = 500, seed: int = 0, empty: bool = True
) -> pr.ReadoutGrid:
    """A random table; ``empty``: some intervals and whole rays without haze (tau = 0, the
    ``den`` <= 1e-7 branch, where a finite difference straddles a kink of the read-out)."""
    g = torch.Generator().manual_seed(seed)
    tau = 0.05 + torch.rand(R, K, generator=g, dtype=torch.float64) * 0.6
    if empty:
        tau[torch.rand(R, K, generator=g) < 0.2] = 0.0
        tau[:3] = 0.0
    Tau = torch.cat([torch.zeros(R, 1, dtype=tau.dtype), tau.cumsum(1)], 1)  # [R, K+1]
    light = torch.rand(R, K + 1, 3, generator=g, dtype=tau.dtype)
    S = torch.rand(R, K + 1, 3, generator=g, dtype=tau.dtype)
    table = torch.cat(
        [
            Tau[..., None],
            torch.cat([tau, tau[:, :1] * 0], 1)[..., None],
            torch.exp(-Tau)[..., None],
            S,
            light,
        ],
        -1,
    ).reshape(R * (K + 1), 9)
    return pr.ReadoutGrid(
        table=table.to(dtype),
        rays=torch.randint(0, R, (4, P), generator=g),
        wgt=torch.rand(4, P, generator=g, dtype=dtype).softmax(0),
        pix_len=1 + 0.3 * torch.rand(P, generator=g, dtype=dtype),
        ray_len=1 + 0.3 * torch.rand(R, generator=g, dtype=dtype),
        zfar=0.5 + 4 * torch.rand(R, generator=g, dtype=dtype),
        K=K,
    )


def _zq(grid: pr.ReadoutGrid, seed: int = 1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    P = grid.rays.shape[1]
    return (5.5 * torch.rand(1, P, generator=g, dtype=torch.float64)).to(grid.table.dtype)  # past zfar too


def _read(
    grid: pr.ReadoutGrid,
    zq: torch.Tensor,
    last_light: bool,
    fused: bool,
    dtype: torch.dtype,
    depth_grad: bool = False,
):
    """Outputs and the table's (and, ``depth_grad``, the depth's) gradient under a fixed random
    upstream gradient, in ``dtype``."""
    table = grid.table.to(dtype).clone().requires_grad_(True)
    zq = zq.to(dtype).clone().requires_grad_(depth_grad)
    g = pr.ReadoutGrid(
        table, grid.rays, grid.wgt.to(dtype), grid.pix_len.to(dtype), grid.ray_len.to(dtype),
        grid.zfar.to(dtype), grid.K,
    )  # fmt: skip
    out = [o for o in pr.read_pixels(g, zq, last_light, fused=fused) if o is not None]
    gen = torch.Generator().manual_seed(5)
    sum(
        (o * torch.randn(o.shape, generator=gen, dtype=torch.float64).to(dtype)).sum() for o in out
    ).backward()
    grads = [table.grad.double()] + ([zq.grad.double()] if depth_grad else [])
    return [o.detach().double() for o in out] + grads


@needs_kernel
@pytest.mark.parametrize("last_light", [False, True])
def test_kernel_matches_torch_in_float64(last_light) -> None:
    grid = _grid(torch.float64)
    zq = _zq(grid)
    ref = _read(grid, zq, last_light, False, torch.float64)
    got = _read(grid, zq, last_light, True, torch.float64)
    assert len(got) == (4 if last_light else 3) and got[-1].abs().sum() > 0
    for a, b in zip(got, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-13)


@needs_kernel
@pytest.mark.parametrize("last_light", [False, True])
def test_kernel_depth_gradient_matches_torch_in_float64(last_light) -> None:
    """The gradient into each pixel's depth (``composite.depth_gradient``), pixels past their rays'
    far ends (zero gradient there) included."""
    grid = _grid(torch.float64)
    zq = _zq(grid)
    ref = _read(grid, zq, last_light, False, torch.float64, depth_grad=True)
    got = _read(grid, zq, last_light, True, torch.float64, depth_grad=True)
    assert got[-1].shape == zq.shape and (got[-1] != 0).float().mean() > 0.3
    assert (got[-1] == 0).any()  # beyond every neighbour's far end
    for a, b in zip(got, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-11, atol=1e-12)


@needs_kernel
def test_kernel_depth_gradient_in_float32_is_as_close_to_float64_as_torch() -> None:
    grid = _grid(torch.float64)
    zq = _zq(grid)
    truth = _read(grid, zq, False, False, torch.float64, depth_grad=True)[-1]
    ref = _read(grid, zq, False, False, torch.float32, depth_grad=True)[-1]
    got = _read(grid, zq, False, True, torch.float32, depth_grad=True)[-1]
    err_ref, err_got = float((ref - truth).abs().max()), float((got - truth).abs().max())
    assert err_got <= 2 * err_ref + 1e-5, (err_got, err_ref)
    torch.testing.assert_close(got, truth, rtol=1e-3, atol=1e-4)


@needs_kernel
@pytest.mark.parametrize("last_light", [False, True])
def test_kernel_in_float32_is_as_close_to_float64_as_torch(last_light) -> None:
    """In float32 the gradient through the rescaled fraction (1 - e^-rt) / (1 - e^-t) cancels
    for thin rays, so both paths round differently there; neither may be further from the float64
    values than twice the other (plus 1e-6), and both stay within 1e-3 of them."""
    grid = _grid(torch.float64)
    zq = _zq(grid)
    truth = _read(grid, zq, last_light, False, torch.float64)
    ref = _read(grid, zq, last_light, False, torch.float32)
    got = _read(grid, zq, last_light, True, torch.float32)
    for t, r, g in zip(truth, ref, got, strict=True):
        err_ref, err_got = float((r - t).abs().max()), float((g - t).abs().max())
        assert err_got <= 2 * err_ref + 1e-6, (err_got, err_ref)
        torch.testing.assert_close(g, t, rtol=1e-3, atol=1e-4)


@needs_kernel
@pytest.mark.parametrize("last_light", [False, True])
def test_kernel_gradcheck_float64(last_light) -> None:
    grid = _grid(torch.float64, R=6, K=4, P=40, empty=False)
    zq = _zq(grid)
    table = grid.table.clone().requires_grad_(True)

    def f(t):
        g = pr.ReadoutGrid(t, grid.rays, grid.wgt, grid.pix_len, grid.ray_len, grid.zfar, grid.K)
        return tuple(o for o in pr.read_pixels(g, zq, last_light) if o is not None)

    assert torch.autograd.gradcheck(f, (table,), eps=1e-6, atol=1e-7)


@needs_kernel
def test_kernel_depth_gradcheck_float64() -> None:
    """Depths inside their rays, off the interval boundaries (where the read-out has kinks)."""
    grid = _grid(torch.float64, R=6, K=4, P=40, empty=False)
    u = 0.05 + 0.9 * torch.rand(1, 40, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    zq = (u * grid.zfar.min()).requires_grad_(True)
    pos = zq.detach() / grid.zfar[grid.rays] * grid.K
    assert ((pos - pos.round()).abs() > 1e-4).all()

    def f(z):
        return tuple(o for o in pr.read_pixels(grid, z, True) if o is not None)

    assert pr.uses_kernel(grid, zq)
    assert torch.autograd.gradcheck(f, (zq,), eps=1e-7, atol=1e-6)


@needs_kernel
def test_threads_give_repeatable_sums_close_to_one_thread() -> None:
    grid = _grid(torch.float32, R=200, K=16, P=20_000)
    zq = _zq(grid)

    def run(threads: int):
        table = grid.table.clone().requires_grad_(True)
        g = pr.ReadoutGrid(table, grid.rays, grid.wgt, grid.pix_len, grid.ray_len, grid.zfar, grid.K)
        tau, S = pr._ReadoutFn.apply(table, g, zq, False, threads)
        (tau.sum() + S.sum()).backward()
        return tau, S, table.grad

    one, two, again = run(1), run(3), run(3)
    for a, b in zip(two, again, strict=True):
        assert torch.equal(a, b)  # fixed per-thread chunks, summed in thread order
    for a, b in zip(one, two, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize(
    ("background", "depth_gradient"), [("far", False), ("infinite", False), ("far", True)]
)
def test_compositor_same_with_either_read_out(background, depth_gradient) -> None:
    """T, S, the sky light and the gradients of the field (and of the depth) agree between the
    kernel and the torch ops."""
    results = []
    for fused in (False, True):
        field = BlobField(0.3, 2.0, (0.7, 0.6, 0.5))
        field.b_param = torch.nn.Parameter(torch.tensor(1.0))
        inner = field.forward

        def forward(x, dirs, inner=inner, field=field):
            out = inner(x, dirs)
            return type(out)(beta=out.beta * field.b_param, light=out.light * field.b_param.sqrt())

        field.forward = forward
        z, alpha = _depth(3, torch.device("cpu"))
        z = z.clone().requires_grad_(depth_gradient)
        cfg = CompositeConfig(
            ray_stride=3, background=background, fused_readout=fused, depth_gradient=depth_gradient
        )
        med = MediumCompositor(cfg)(field, _camera(torch.device("cpu")), z, alpha)
        sky = med.sky if med.sky is not None else med.scattering
        (med.transmittance.sum() + med.scattering.sum() + sky.sum()).backward()
        z_grad = z.grad if depth_gradient else torch.zeros(())
        assert not depth_gradient or z_grad.abs().sum() > 0
        results.append((med.transmittance, med.scattering, sky, field.b_param.grad, z_grad))
    for ref, got in zip(*results, strict=True):
        torch.testing.assert_close(got, ref, rtol=2e-5, atol=2e-6)


def test_without_a_compiler_the_torch_path_serves(monkeypatch) -> None:
    native_build.forget()
    monkeypatch.setenv("CXX", "/nonexistent/c++")
    try:
        grid = _grid(torch.float32)
        zq = _zq(grid)
        assert not pr.kernel_available() and not pr.uses_kernel(grid, zq)
        ref = pr.read_torch(grid, zq)
        got = pr.read_pixels(grid, zq)
        assert torch.equal(got[0], ref[0]) and torch.equal(got[1], ref[1])
    finally:
        native_build.forget()
