"""Ground truth: the tiled torch rasterizer against a brute-force per-pixel loop in plain Python floats.

The loop below is written from the semantics list in docs/rasterizer.md, independently of the
implementation (no shared helpers): projection per Gaussian, opacity-aware boxes and tile coverage
per pixel, the 1/255 skip rule and the exclusive 1e-4 stop rule, front to back.
"""

from __future__ import annotations

import math

import pytest
import torch

from components.rasterizers import RasterizerConfig, TorchRasterizer


def _naive_render(means, quats, scales, opac, colors, viewmat, K, W, H, bg, *, near, far, eps2d, tile):
    """Returns (rgb [H][W][3], alpha [H][W], depth_accum [H][W], radii [N], stats)."""
    Rv = viewmat[:3, :3].tolist()
    tv = viewmat[:3, 3].tolist()
    fx, fy, cx, cy = K[0, 0].item(), K[1, 1].item(), K[0, 2].item(), K[1, 2].item()
    items, radii = [], [0] * len(means)
    for i in range(len(means)):
        w, x, y, z = (quats[i] / quats[i].norm()).tolist()
        Rq = [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
        s = scales[i].tolist()
        sig = [[sum(Rq[a][k] * s[k] ** 2 * Rq[b][k] for k in range(3)) for b in range(3)] for a in range(3)]
        mu = means[i].tolist()
        mc = [sum(Rv[a][k] * mu[k] for k in range(3)) + tv[a] for a in range(3)]
        if not (near < mc[2] < far):
            continue
        sc = [
            [sum(Rv[a][k] * sig[k][j] * Rv[b][j] for k in range(3) for j in range(3)) for b in range(3)]
            for a in range(3)
        ]
        px_, py_, pz = mc
        lxp = (W - cx) / fx + 0.3 * 0.5 * W / fx
        lxn = cx / fx + 0.3 * 0.5 * W / fx
        lyp = (H - cy) / fy + 0.3 * 0.5 * H / fy
        lyn = cy / fy + 0.3 * 0.5 * H / fy
        tx = pz * min(lxp, max(-lxn, px_ / pz))
        ty = pz * min(lyp, max(-lyn, py_ / pz))
        J = [[fx / pz, 0.0, -fx * tx / pz**2], [0.0, fy / pz, -fy * ty / pz**2]]
        cov = [
            [sum(J[a][k] * sc[k][j] * J[b][j] for k in range(3) for j in range(3)) for b in range(2)]
            for a in range(2)
        ]
        a_, b_, c_ = cov[0][0] + eps2d, cov[0][1], cov[1][1] + eps2d
        det = a_ * c_ - b_ * b_
        if det <= 0:
            continue
        conic = (c_ / det, -b_ / det, a_ / det)
        o = opac[i].item()
        if o < 1.0 / 255.0:
            continue
        # the box of the ellipse where alpha can reach 1/255: sigma <= log(255 o)
        extend = min(3.33, math.sqrt(2.0 * math.log(o * 255.0)))
        rx, ry = math.ceil(extend * math.sqrt(a_)), math.ceil(extend * math.sqrt(c_))
        u, v = fx * px_ / pz + cx, fy * py_ / pz + cy
        if rx <= 0 or ry <= 0 or u + rx <= 0 or u - rx >= W or v + ry <= 0 or v - ry >= H:
            continue
        radii[i] = max(rx, ry)
        if tile is None:  # every pixel is a candidate; the alpha test alone decides
            rect = (0, W, 0, H)
        else:
            tw, th = math.ceil(W / tile), math.ceil(H / tile)
            rect = (
                min(max(0, math.floor(u / tile - rx / tile)), tw),
                min(max(0, math.ceil(u / tile + rx / tile)), tw),
                min(max(0, math.floor(v / tile - ry / tile)), th),
                min(max(0, math.ceil(v / tile + ry / tile)), th),
            )
        items.append((pz, i, u, v, conic, o, colors[i].tolist(), rect))
    items.sort(key=lambda it: (it[0], it[1]))

    stats = {"skipped": 0, "stopped": 0, "blended": 0}
    rgb = [[[0.0] * 3 for _ in range(W)] for _ in range(H)]
    alpha = [[0.0] * W for _ in range(H)]
    dacc = [[0.0] * W for _ in range(H)]
    for py in range(H):
        for px in range(W):
            tx_, ty_ = (px, py) if tile is None else (px // tile, py // tile)
            T, out, d = 1.0, [0.0, 0.0, 0.0], 0.0
            for pz, _, u, v, (ca, cb, cc), o, col, (x0, x1, y0, y1) in items:
                if not (x0 <= tx_ < x1 and y0 <= ty_ < y1):
                    continue
                dx, dy = u - (px + 0.5), v - (py + 0.5)
                sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                a = min(0.999, o * math.exp(-sigma))
                if sigma < 0 or a < 1.0 / 255.0:
                    stats["skipped"] += 1
                    continue
                nT = T * (1.0 - a)
                if nT <= 1e-4:
                    stats["stopped"] += 1
                    break
                for k in range(3):
                    out[k] += col[k] * a * T
                d += pz * a * T
                T = nT
                stats["blended"] += 1
            for k in range(3):
                rgb[py][px][k] = out[k] + T * bg[k]
            alpha[py][px] = 1.0 - T
            dacc[py][px] = d
    return rgb, alpha, dacc, radii, stats


def _scene(seed: int, n: int = 20):
    g = torch.Generator().manual_seed(seed)
    dt = torch.float64
    means = torch.randn(n, 3, generator=g, dtype=dt) * torch.tensor([0.5, 0.4, 0.6], dtype=dt)
    means[:, 2] += 2.5
    means[0, 2] = -1.0  # behind the camera
    means[1] = torch.tensor([4.0, 0.0, 2.0], dtype=dt)  # far off-screen
    quats = torch.randn(n, 4, generator=g, dtype=dt)
    scales = torch.rand(n, 3, generator=g, dtype=dt) * 0.25 + 0.02
    scales[3] = torch.tensor([0.6, 0.02, 0.05], dtype=dt)  # elongated, spans several tiles
    opac = torch.rand(n, generator=g, dtype=dt) * 0.5 + 0.5
    opac[4] = 0.003  # below 1/255 everywhere
    opac[5:9] = 1.0  # clamped at 0.999 ...
    means[5:9] = torch.tensor([[0.0, 0.0, z] for z in (2.0, 2.4, 2.8, 3.2)], dtype=dt)  # ... and stacked
    scales[5:9] = 0.3  # wide: the stop rule triggers over many pixels
    colors = torch.rand(n, 3, generator=g, dtype=dt)
    ang = 0.1 * seed
    c, s = math.cos(ang), math.sin(ang)
    viewmat = torch.tensor(
        [[c, 0, s, 0.05], [0, 1, 0, -0.02], [-s, 0, c, 0.1], [0, 0, 0, 1]], dtype=dt
    )  # rigid world-to-camera
    K = torch.tensor([[10.0, 0, 6.2], [0, 9.0, 4.4], [0, 0, 1]], dtype=dt)
    return means, quats, scales, opac, colors, viewmat, K


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("tile", [4, 16])
def test_tiled_matches_naive_loop(seed: int, tile: int) -> None:
    W, H = 12, 9
    means, quats, scales, opac, colors, viewmat, K = _scene(seed)
    bg = torch.tensor([0.2, 0.3, 0.4], dtype=torch.float64)
    cfg = RasterizerConfig(backend="torch", tile_size=tile)
    out = TorchRasterizer(cfg).rasterize(means, quats, scales, opac, colors, viewmat[None], K[None], W, H, bg)
    rgb, alpha, dacc, radii, stats = _naive_render(
        means, quats, scales, opac, colors, viewmat, K, W, H, bg.tolist(),
        near=cfg.near_plane, far=cfg.far_plane, eps2d=cfg.eps2d, tile=tile,
    )  # fmt: skip
    # the scene must exercise every rule, or this test proves little
    assert stats["skipped"] > 0 and stats["stopped"] > 0 and stats["blended"] > 50
    assert out.radii[0].tolist() == radii
    assert not out.visible[0, :2].any()  # behind the camera, off-screen
    torch.testing.assert_close(out.rgb[0], torch.tensor(rgb, dtype=torch.float64), rtol=0, atol=1e-10)
    torch.testing.assert_close(
        out.alpha[0, ..., 0], torch.tensor(alpha, dtype=torch.float64), rtol=0, atol=1e-10
    )
    torch.testing.assert_close(
        out.depth_accum[0, ..., 0], torch.tensor(dacc, dtype=torch.float64), rtol=0, atol=1e-10
    )
    # the differentiable path recomputes alpha on the graph: it must give the very same image
    grad_in = [t.clone().requires_grad_() for t in (means, quats, scales, opac, colors)]
    out_g = TorchRasterizer(cfg).rasterize(*grad_in, viewmat[None], K[None], W, H, bg)
    assert out_g.rgb.requires_grad
    torch.testing.assert_close(out_g.rgb, out.rgb, rtol=0, atol=1e-14)
    torch.testing.assert_close(out_g.alpha, out.alpha, rtol=0, atol=1e-14)
    # the boxes hold every pair whose alpha reaches 1/255, so tiles never change the image: a loop
    # that offers every pixel every Gaussian gives the same result
    rgb_all, alpha_all, *_ = _naive_render(
        means, quats, scales, opac, colors, viewmat, K, W, H, bg.tolist(),
        near=cfg.near_plane, far=cfg.far_plane, eps2d=cfg.eps2d, tile=None,
    )  # fmt: skip
    torch.testing.assert_close(out.rgb[0], torch.tensor(rgb_all, dtype=torch.float64), rtol=0, atol=1e-10)
    torch.testing.assert_close(
        out.alpha[0, ..., 0], torch.tensor(alpha_all, dtype=torch.float64), rtol=0, atol=1e-10
    )


def test_small_chunks_do_not_change_the_result() -> None:
    """Chunking (memory bound) must be invisible in the output."""
    W, H = 12, 9
    means, quats, scales, opac, colors, viewmat, K = _scene(4)
    args = (means, quats, scales, opac, colors, viewmat[None], K[None], W, H)
    ref = TorchRasterizer().rasterize(*args)
    small = TorchRasterizer(chunk_elems=37).rasterize(*args)
    torch.testing.assert_close(small.rgb, ref.rgb, rtol=0, atol=1e-14)
    torch.testing.assert_close(small.alpha, ref.alpha, rtol=0, atol=1e-14)
