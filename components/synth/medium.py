"""The participating medium: a known extinction field beta(x) and a medium light L(x, v).

Presets are scaled by the layout's reference distance ``d_ref`` (a typical viewing distance),
so a preset means the same visibility in a room (metres) and a street (tens of metres):
homogeneous fog lets half the light through over ``d_ref``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import torch
from torch import Tensor

PRESETS: tuple[str, ...] = ("none", "homogeneous", "height", "patchy", "dense", "uniform")
"""``homogeneous`` has constant extinction but light that dims near the ground; ``uniform`` is
homogeneous in both (the one medium a ``constant`` model represents exactly)."""
BLOB_CUTOFF = 1e-9
"""A blob is skipped on rays where it stays below this (relative to beta0) along the whole segment."""


# --------------------------------------------------------------------------------------
# extinction fields: points [..., 3] (m) -> beta [...] (1/m)


@dataclass(frozen=True)
class ConstantField:
    beta: float

    def __call__(self, x: Tensor) -> Tensor:
        return torch.full(x.shape[:-1], self.beta, dtype=x.dtype)

    def along(self, o: Tensor, d: Tensor, t: Tensor) -> Tensor:
        return torch.full_like(t, self.beta)


@dataclass(frozen=True)
class HeightField:
    """Ground fog: ``beta_ground * exp(-(z - z_ground) / scale_height)``, capped at ``beta_ground`` below."""

    beta_ground: float
    scale_height: float
    z_ground: float = 0.0

    def __call__(self, x: Tensor) -> Tensor:
        return self._of_z(x[..., 2])

    def along(self, o: Tensor, d: Tensor, t: Tensor) -> Tensor:
        return self._of_z(o[:, 2:3] + t * d[:, 2:3])

    def _of_z(self, z: Tensor) -> Tensor:
        return self.beta_ground * torch.exp((z - self.z_ground).clamp_min(0.0) * (-1.0 / self.scale_height))


@dataclass(frozen=True)
class BlobField:
    """``beta0 * (base + sum_i a_i exp(-|x - c_i|^2 / (2 r_i^2)))``: smooth heterogeneous patches."""

    beta0: float
    base: float
    centers: tuple[tuple[float, float, float], ...]
    radii: tuple[float, ...]
    amplitudes: tuple[float, ...]

    def __call__(self, x: Tensor) -> Tensor:
        out = torch.full(x.shape[:-1], self.base, dtype=x.dtype)
        for c, r, a in zip(self.centers, self.radii, self.amplitudes, strict=True):
            q = (x[..., 0] - c[0]) ** 2 + (x[..., 1] - c[1]) ** 2 + (x[..., 2] - c[2]) ** 2
            out = out + a * torch.exp(q * (-0.5 / (r * r)))
        return self.beta0 * out

    def along(self, o: Tensor, d: Tensor, t: Tensor) -> Tensor:
        """The same field at ``o + t d`` [R, K], factorised per ray (``d`` unit): a blob seen along a
        ray is a 1D Gaussian in t around the closest approach ``t_c`` at distance ``m``."""
        out = torch.full_like(t, self.base)
        t_lo, t_hi = t[:, 0], t[:, -1]
        for c, r, a in zip(self.centers, self.radii, self.amplitudes, strict=True):
            oc = o - torch.tensor(c, dtype=o.dtype)  # [R, 3]
            tc = -(oc * d).sum(-1)  # [R] closest approach along the ray
            m2 = ((oc * oc).sum(-1) - tc * tc).clamp_min(0.0)  # [R] squared miss distance
            k = -0.5 / (r * r)
            gap = tc - tc.clamp(t_lo, t_hi)  # distance from the sampled segment to the closest approach
            near = (a * torch.exp((m2 + gap * gap) * k) > BLOB_CUTOFF).nonzero().squeeze(1)
            if len(near) == 0:
                continue  # the blob is negligible on every sampled segment
            log_peak = m2 * k + math.log(a)  # [R]
            if len(near) > 0.7 * len(tc):  # most rays: cheaper without gathering
                out += _gauss(t, tc, log_peak, k)
            else:
                out[near] += _gauss(t[near], tc[near], log_peak[near], k)
        return self.beta0 * out


def _gauss(t: Tensor, tc: Tensor, log_peak: Tensor, k: float) -> Tensor:
    """``exp(k (t - tc)^2 + log_peak)`` [R, K] in four fused passes (this is the march's hot loop)."""
    e = t - tc[:, None]
    e = torch.addcmul(log_peak[:, None], e, e, value=k)
    return e.exp_()


Field = ConstantField | HeightField | BlobField


# --------------------------------------------------------------------------------------
# medium light


@dataclass(frozen=True)
class MediumLight:
    """``L(x, v) = c(v) * g(x)``, each factor in [0, 1], so L <= max(base, glow) <= 1.

    ``c(v)`` blends the ambient airlight towards a warm sun glow as the viewing direction ``v``
    (the ray direction) approaches the sun: ``base + (glow - base) * max(0, v . sun)^sharpness``.
    ``g(x) = 1 - ground_dim * exp(-z / dim_height)`` darkens the medium near the ground a little,
    so L varies in space too.
    """

    base: tuple[float, float, float]
    glow: tuple[float, float, float]
    sun: tuple[float, float, float]
    sharpness: float = 8.0
    ground_dim: float = 0.12
    dim_height: float = 2.0

    def color(self, v: Tensor) -> Tensor:  # [R, 3] unit directions -> [R, 3]
        cos = (v * torch.tensor(self.sun, dtype=v.dtype)).sum(-1).clamp_min(0.0)
        w = cos**self.sharpness
        base, glow = torch.tensor(self.base, dtype=v.dtype), torch.tensor(self.glow, dtype=v.dtype)
        return base + (glow - base) * w[:, None]

    def spatial(self, x: Tensor) -> Tensor:  # [..., 3] -> [...]
        return self.spatial_z(x[..., 2])

    def spatial_z(self, z: Tensor) -> Tensor:
        return 1.0 - self.ground_dim * torch.exp(z.clamp_min(0.0) * (-1.0 / self.dim_height))

    def __call__(self, x: Tensor, v: Tensor) -> Tensor:  # x [R, K, 3], v [R, 3] -> [R, K, 3]
        return self.color(v)[:, None, :] * self.spatial(x)[..., None]

    @property
    def max_value(self) -> float:
        return float(max(max(self.base), max(self.glow)))


@dataclass(frozen=True)
class Medium:
    """A haze preset: extinction field + medium light, with the numbers that made it."""

    preset: str
    extinction: Field
    light: MediumLight
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def is_clear(self) -> bool:
        return isinstance(self.extinction, ConstantField) and self.extinction.beta == 0.0

    def describe(self) -> dict[str, Any]:
        return {
            "preset": self.preset,
            "extinction": {"kind": type(self.extinction).__name__, **asdict(self.extinction)},
            "light": asdict(self.light),
            **self.params,
        }


@dataclass(frozen=True)
class MediumContext:
    """What a preset needs to know about the scene it fills."""

    ref_distance: float
    """Typical viewing distance (m)."""
    bounds_lo: tuple[float, float, float]
    bounds_hi: tuple[float, float, float]
    """Box where patches of haze are placed (m)."""
    fog_height: float
    """Scale height of ground fog (m)."""
    sun: tuple[float, float, float]
    """Unit vector towards the sun (or the main light)."""


AIRLIGHT_BASE = (0.72, 0.76, 0.82)
"""Ambient medium light: bluish grey (what an overcast-lit haze looks like)."""
AIRLIGHT_GLOW = (1.0, 0.92, 0.74)
"""Medium light looking into the sun: warm and bright (forward scattering)."""


def _blobs(ctx: MediumContext, rng: np.random.Generator, n: int, radius: tuple[float, float], cover: float):
    """``n`` random blobs in the lower part of the bounds, radii ``radius`` x d_ref, amplitudes scaled so
    the blobs add ``cover`` to the field's mean over that region (so a small room and a long street
    get equally thick patches)."""
    lo, hi = np.asarray(ctx.bounds_lo), np.asarray(ctx.bounds_hi)
    hi = hi.copy()
    hi[2] = lo[2] + 0.6 * (hi[2] - lo[2])  # patches hang low, where the scene is
    centers = tuple(tuple(float(v) for v in lo + rng.random(3) * (hi - lo)) for _ in range(n))
    radii = np.array([ctx.ref_distance * rng.uniform(*radius) for _ in range(n)])
    amps = rng.uniform(0.5, 1.5, n)
    mass = float(np.sum(amps * (2 * np.pi) ** 1.5 * radii**3))  # integral of the blobs over space
    amps *= cover * float(np.prod(hi - lo)) / mass
    return centers, tuple(float(r) for r in radii), tuple(float(a) for a in amps)


def make_medium(preset: str, ctx: MediumContext, seed: int = 0, beta_scale: float = 1.0) -> Medium:
    """The medium of a named preset in a scene described by ``ctx`` (deterministic in ``seed``)."""
    if preset not in PRESETS:
        raise ValueError(f"unknown haze preset {preset!r}; use one of {', '.join(PRESETS)}")
    rng = np.random.default_rng([seed, PRESETS.index(preset), 7919])
    light = MediumLight(AIRLIGHT_BASE, AIRLIGHT_GLOW, ctx.sun)
    b_ref = math.log(2.0) / ctx.ref_distance * beta_scale  # half the light survives over d_ref
    if preset == "none":
        fld: Field = ConstantField(0.0)
    elif preset == "homogeneous":
        fld = ConstantField(b_ref)
    elif preset == "uniform":
        fld = ConstantField(b_ref)
        light = replace(light, ground_dim=0.0)
    elif preset == "height":
        fld = HeightField(beta_ground=3.0 * b_ref, scale_height=ctx.fog_height)
    elif preset == "patchy":
        c, r, a = _blobs(ctx, rng, 12, (0.12, 0.3), cover=1.0)
        fld = BlobField(b_ref, base=0.25, centers=c, radii=r, amplitudes=a)
    else:  # dense
        c, r, a = _blobs(ctx, rng, 6, (0.15, 0.35), cover=0.6)
        fld = BlobField(2.5 * b_ref, base=1.0, centers=c, radii=r, amplitudes=a)
    return Medium(preset, fld, light, {"beta_ref": b_ref, "ref_distance": ctx.ref_distance})
