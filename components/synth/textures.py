"""Procedural surface textures: a function of the 3D hit point and its normal only.

Because the colour depends on world position (never on the view), every view sees the same
surface: the multi-view consistency a reconstruction method needs. Each pattern carries several
octaves of value noise so surfaces have fine detail both close up and far away.
"""

from __future__ import annotations

import torch
from torch import Tensor

from components.synth.geometry import Material

_M = 0x7FFFFFFF


def hash2(ix: Tensor, iy: Tensor, seed: int) -> Tensor:
    """Deterministic pseudo-random value in [0, 1) per integer lattice point (int64 arithmetic)."""
    h = (ix * 374761393 + iy * 668265263 + seed * 2246822519) & _M
    h = ((h ^ (h >> 13)) * 1274126177) & _M
    h = h ^ (h >> 16)
    return (h & 0xFFFF).to(torch.float32) / 65536.0


def value_noise(u: Tensor, v: Tensor, seed: int) -> Tensor:
    """Smooth 2D value noise in [0, 1] with unit lattice spacing."""
    fu, fv = torch.floor(u), torch.floor(v)
    iu, iv = fu.to(torch.int64), fv.to(torch.int64)
    su, sv = u - fu, v - fv
    su, sv = su * su * (3 - 2 * su), sv * sv * (3 - 2 * sv)  # smoothstep
    a, b = hash2(iu, iv, seed), hash2(iu + 1, iv, seed)
    c, d = hash2(iu, iv + 1, seed), hash2(iu + 1, iv + 1, seed)
    return torch.lerp(torch.lerp(a, b, su), torch.lerp(c, d, su), sv)


def fbm(u: Tensor, v: Tensor, seed: int, octaves: int = 5) -> Tensor:
    """Fractal value noise in [0, 1]: octaves at doubling frequency and halving amplitude."""
    total = torch.zeros_like(u)
    amp, norm = 1.0, 0.0
    for k in range(octaves):
        f = 2.0**k
        total = total + amp * value_noise(u * f + 17.3 * k, v * f - 9.1 * k, seed + 101 * k)
        norm += amp
        amp *= 0.5
    return total / norm


def surface_uv(p: Tensor, n: Tensor) -> tuple[Tensor, Tensor]:
    """2D surface coordinates (m): the two world axes across the normal's dominant axis."""
    ax = n.abs().argmax(dim=-1)  # [R]
    u = torch.where(ax == 0, p[:, 1], p[:, 0])
    v = torch.where(ax == 2, p[:, 1], p[:, 2])
    return u, v


def _mix(a: tuple[float, ...], b: tuple[float, ...], w: Tensor) -> Tensor:  # w [R] -> [R, 3]
    ta, tb = torch.tensor(a), torch.tensor(b)
    return ta[None] + (tb - ta)[None] * w[:, None].clamp(0, 1)


def albedo(mat: Material, p: Tensor, n: Tensor) -> Tensor:
    """Surface colour [R, 3] in [0, 1] of material ``mat`` at points ``p`` [R, 3] with normals ``n``."""
    u, v = surface_uv(p, n)
    s = mat.scale
    grain = fbm(u * 40.0 / s, v * 40.0 / s, mat.seed + 7, octaves=3)  # fine detail (~1/40 of a period)
    if mat.texture == "checker":
        cell = (torch.floor(u / s) + torch.floor(v / s)).remainder(2)
        w = 0.85 * cell + 0.3 * (grain - 0.5)
    elif mat.texture == "tiles":
        fu, fv = (u / s).remainder(1.0), (v / s).remainder(1.0)
        grout = ((fu < 0.04) | (fv < 0.04)).float()
        tint = hash2(torch.floor(u / s).long(), torch.floor(v / s).long(), mat.seed)
        w = 0.35 * tint + 0.25 * grain + 0.9 * grout
    elif mat.texture == "bricks":
        h = s / 2.5  # brick height
        row = torch.floor(v / h)
        shifted = u / s + 0.5 * row.remainder(2)
        fu, fv = shifted.remainder(1.0), (v / h).remainder(1.0)
        mortar = ((fu < 0.05) | (fv < 0.1)).float()
        tint = hash2(torch.floor(shifted).long(), row.long(), mat.seed)
        w = (0.45 * tint + 0.35 * grain) * (1 - mortar) + mortar
    elif mat.texture == "stripes":
        w = 0.5 + 0.5 * torch.sin(2 * torch.pi * u / s) + 0.3 * (grain - 0.5)
    elif mat.texture == "noise":
        w = fbm(u / s, v / s, mat.seed, octaves=6)
        w = (w - 0.5) * 1.8 + 0.5
    elif mat.texture == "plain":
        w = 0.35 * grain
    else:
        raise ValueError(f"unknown texture {mat.texture!r}")
    return _mix(mat.color_a, mat.color_b, w)
