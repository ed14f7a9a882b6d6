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

PRESETS: tuple[str, ...] = ("none", "homogeneous", "height", "patchy", "dense", "uniform", "sunlit")
"""``homogeneous`` has constant extinction but light that dims near the ground; ``uniform`` is
homogeneous in both (the one medium a ``constant`` model represents exactly); ``sunlit`` is ground
fog modulated by a noise field and lit by a low sun through a strongly forward-scattering
(Henyey-Greenstein) phase function: a second haze model that shares neither the extinction nor the
light model of the others."""
BLOB_CUTOFF = 1e-9
"""A blob is skipped on rays where it stays below this (relative to beta0) along the whole segment."""


# --------------------------------------------------------------------------------------
# extinction fields: points [..., 3] (m) -> beta [...] (1/m)


@dataclass(frozen=True)
class ConstantField:
    beta: float

    def __call__(self, x: Tensor) -> Tensor:
        return torch.full(x.shape[:-1], self.beta, dtype=x.dtype, device=x.device)

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
        out = torch.full(x.shape[:-1], self.base, dtype=x.dtype, device=x.device)
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
            oc = o - torch.tensor(c, dtype=o.dtype, device=o.device)  # [R, 3]
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


@dataclass(frozen=True)
class NoisyHeightField:
    """Ground fog broken up by a noise field:
    ``beta_ground * exp(-(z - z_ground) / scale_height) * (1 + strength * n(x))``.

    ``n(x)`` in [-1, 1] is the mean of ``cos(w_i . x + phi_i)`` over random wave vectors of two
    octaves (a band-limited noise), so the field is smooth, heterogeneous in every direction and
    positive for ``strength < 1``."""

    beta_ground: float
    scale_height: float
    strength: float
    waves: tuple[tuple[float, float, float], ...]
    """Wave vectors w_i (rad / m)."""
    phases: tuple[float, ...]
    z_ground: float = 0.0

    def __call__(self, x: Tensor) -> Tensor:
        w = torch.tensor(self.waves, dtype=x.dtype, device=x.device)  # [M, 3]
        phase = torch.tensor(self.phases, dtype=x.dtype, device=x.device)  # [M]
        noise = torch.cos(x @ w.T + phase).mean(-1)  # [...]
        z = (x[..., 2] - self.z_ground).clamp_min(0.0)
        return self.beta_ground * torch.exp(z * (-1.0 / self.scale_height)) * (1.0 + self.strength * noise)

    def along(self, o: Tensor, d: Tensor, t: Tensor) -> Tensor:
        return self(o[:, None, :] + t[..., None] * d[:, None, :])


def _noise_waves(rng: np.random.Generator, wavelength: float, count: int) -> tuple[tuple, tuple]:
    """``count`` random wave vectors, half at ``wavelength`` and half at a third of it, and phases."""
    waves, phases = [], []
    for i in range(count):
        k = 2 * math.pi / (wavelength if i % 2 == 0 else wavelength / 3.0)
        v = rng.normal(size=3)
        v[2] *= 2.0  # layered: the fog varies faster in height than across
        waves.append(tuple(float(c) for c in k * v / np.linalg.norm(v)))
        phases.append(float(rng.uniform(0, 2 * math.pi)))
    return tuple(waves), tuple(phases)


Field = ConstantField | HeightField | BlobField | NoisyHeightField


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
        cos = (v * torch.tensor(self.sun, dtype=v.dtype, device=v.device)).sum(-1).clamp_min(0.0)
        w = cos**self.sharpness
        base, glow = (
            torch.tensor(self.base, dtype=v.dtype, device=v.device),
            torch.tensor(self.glow, dtype=v.dtype, device=v.device),
        )
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
class ForwardScatterLight:
    """Single scattering of a sun through a Henyey-Greenstein phase function plus a sky ambient:
    ``L(v) = ambient + sun * p_HG(v . sun; g) / p_HG(1; g)``, clipped to [0, 1].

    With ``g = 0.8`` looking into the sun is ~700x brighter than looking away from it, and the glow
    falls off over tens of degrees: a medium light that a single airlight cannot describe."""

    ambient: tuple[float, float, float]
    sun_color: tuple[float, float, float]
    sun: tuple[float, float, float]
    g: float = 0.8

    def color(self, v: Tensor) -> Tensor:  # [R, 3] unit directions -> [R, 3]
        cos = (v * torch.tensor(self.sun, dtype=v.dtype, device=v.device)).sum(-1)
        g = self.g
        ratio = ((1.0 - g) ** 2 / (1.0 + g * g - 2.0 * g * cos)) ** 1.5  # p_HG(cos) / p_HG(1) in (0, 1]
        amb, sun = (
            torch.tensor(self.ambient, dtype=v.dtype, device=v.device),
            torch.tensor(self.sun_color, dtype=v.dtype, device=v.device),
        )
        return (amb + sun * ratio[:, None]).clamp(0.0, 1.0)

    def spatial_z(self, z: Tensor) -> Tensor:
        return torch.ones_like(z)

    def spatial(self, x: Tensor) -> Tensor:  # [..., 3] -> [...]
        return torch.ones_like(x[..., 0])

    def __call__(self, x: Tensor, v: Tensor) -> Tensor:  # x [R, K, 3], v [R, 3] -> [R, K, 3]
        return self.color(v)[:, None, :] * self.spatial(x)[..., None]

    @property
    def max_value(self) -> float:
        return float(min(1.0, max(a + s for a, s in zip(self.ambient, self.sun_color, strict=True))))


Light = MediumLight | ForwardScatterLight

SUNLIT_AMBIENT = (0.45, 0.5, 0.58)
"""Sky-lit fog away from the sun: darker and bluer than the overcast presets' airlight."""
SUNLIT_SUN = (0.55, 0.45, 0.3)
"""Forward-scattered sunlight added looking into the sun (warm)."""


@dataclass(frozen=True)
class Medium:
    """A haze preset: extinction field + medium light, with the numbers that made it."""

    preset: str
    extinction: Field
    light: Light
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
    elif preset == "dense":
        c, r, a = _blobs(ctx, rng, 6, (0.15, 0.35), cover=0.6)
        fld = BlobField(2.5 * b_ref, base=1.0, centers=c, radii=r, amplitudes=a)
    else:  # sunlit
        waves, phases = _noise_waves(rng, 0.6 * ctx.ref_distance, 6)
        fld = NoisyHeightField(2.0 * b_ref, 1.5 * ctx.fog_height, 0.7, waves, phases, ctx.bounds_lo[2])
        light = ForwardScatterLight(SUNLIT_AMBIENT, SUNLIT_SUN, ctx.sun)
    return Medium(preset, fld, light, {"beta_ref": b_ref, "ref_distance": ctx.ref_distance})
