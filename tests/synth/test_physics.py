"""The medium and the march: the physics the issue asks for, checked against closed forms."""

from __future__ import annotations

import math

import pytest
import torch

from components.synth.layouts import LAYOUTS, make_layout
from components.synth.march import march
from components.synth.medium import (
    PRESETS,
    BlobField,
    ConstantField,
    HeightField,
    Medium,
    MediumLight,
    make_medium,
)

SUN = (0.0, 0.6, 0.8)
LIGHT = MediumLight(base=(0.7, 0.75, 0.8), glow=(1.0, 0.9, 0.7), sun=SUN)
FLAT_LIGHT = MediumLight(base=(0.6, 0.7, 0.8), glow=(0.6, 0.7, 0.8), sun=SUN, ground_dim=0.0)
BLOBS = BlobField(
    beta0=0.2,
    base=0.3,
    centers=((0.0, 5.0, 1.0), (1.5, 9.0, 2.0), (-2.0, 14.0, 0.5)),
    radii=(1.0, 2.0, 1.5),
    amplitudes=(2.0, 1.0, 3.0),
)


def rays(n: int = 64, seed: int = 0):
    """Rays from around the origin into the +y half-space, with distances 0.5 .. 40."""
    g = torch.Generator().manual_seed(seed)
    o = torch.randn(n, 3, generator=g) * 0.5 + torch.tensor([0.0, 0.0, 1.5])
    d = torch.randn(n, 3, generator=g) * 0.4 + torch.tensor([0.0, 1.0, 0.0])
    d = d / d.norm(dim=-1, keepdim=True)
    t = 0.5 + torch.rand(n, generator=g) * 39.5
    return o, d, t


def test_no_medium_is_exactly_clear():
    o, d, t = rays()
    res = march(Medium("none", ConstantField(0.0), LIGHT), o, d, t)
    assert torch.equal(res.transmittance, torch.ones(len(t)))
    assert torch.equal(res.scattering, torch.zeros(len(t), 3))
    # the generic march path with beta = 0 is exact too (no special case needed)
    res = march(Medium("zero", BlobField(0.0, 0.0, (), (), ()), LIGHT), o, d, t)
    assert torch.equal(res.transmittance, torch.ones(len(t)))
    assert torch.equal(res.scattering, torch.zeros(len(t), 3))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_homogeneous_matches_closed_form(dtype):
    beta = 0.07
    o, d, t = rays()
    res = march(Medium("h", ConstantField(beta), FLAT_LIGHT), o, d, t, samples=128, dtype=dtype)
    T_true = torch.exp(-beta * t.to(dtype))
    tol = 1e-12 if dtype == torch.float64 else 2e-6
    torch.testing.assert_close(res.transmittance, T_true, atol=tol, rtol=0)
    # constant L: S = L (1 - T) exactly (the discrete sum telescopes)
    L = torch.tensor(FLAT_LIGHT.base, dtype=dtype)
    torch.testing.assert_close(res.scattering, L * (1 - T_true)[:, None], atol=tol * 10, rtol=0)


def test_homogeneous_transmittance_decreases_with_distance():
    o = torch.zeros(50, 3)
    d = torch.tensor([[0.0, 1.0, 0.0]]).expand(50, 3).contiguous()
    t = torch.linspace(0.1, 100.0, 50)
    T = march(Medium("h", ConstantField(0.05), LIGHT), o, d, t).transmittance
    assert bool((T[1:] < T[:-1]).all())
    assert bool((T > 0).all()) and bool((T <= 1).all())


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("layout", LAYOUTS)
def test_presets_bounded(preset, layout):
    lay = make_layout(layout, seed=3)
    med = make_medium(preset, lay.medium_context(), seed=3, beta_scale=4.0)  # thick: stresses the bounds
    o, d, t = rays(128, seed=1)
    res = march(med, o, d, t * lay.far / 40.0, samples=64)
    T, S = res.transmittance, res.scattering
    assert bool(((T > 0) & (T <= 1)).all())
    assert bool((S >= 0).all())
    assert float(S.max()) <= med.light.max_value + 1e-6  # S is bounded by the medium light
    assert bool((S <= med.light.max_value * (1 - T)[:, None] + 1e-5).all())  # and by L_max (1 - T)


def test_light_is_bounded_and_brighter_towards_sun():
    v = torch.randn(500, 3)
    v = v / v.norm(dim=-1, keepdim=True)
    x = torch.randn(500, 4, 3) * 5
    L = LIGHT(x, v)  # [R, K, 3]
    assert float(L.min()) >= 0 and float(L.max()) <= LIGHT.max_value
    sun = torch.tensor([SUN])
    away = -sun
    assert float(LIGHT.color(sun).sum()) > float(LIGHT.color(away).sum())


@pytest.mark.parametrize("fld", [BLOBS, HeightField(beta_ground=0.3, scale_height=2.0)])
def test_field_along_ray_matches_pointwise(fld):
    o, d, t_end = rays(32)
    t = t_end[:, None] * torch.linspace(0.01, 1.0, 17)[None]  # [R, K]
    x = o[:, None] + t[..., None] * d[:, None]
    torch.testing.assert_close(fld.along(o, d, t), fld(x), atol=1e-6, rtol=1e-5)


def test_march_converges_as_samples_grow():
    med = Medium("blobs", BLOBS, LIGHT)
    o, d, t = rays(64)
    o, d, t = o.double(), d.double(), t.double()
    ref = march(med, o, d, t, samples=1024, dtype=torch.float64)
    errs = []
    for k in (8, 16, 32, 64, 128, 256):
        res = march(med, o, d, t, samples=k, dtype=torch.float64)
        err = float((res.transmittance - ref.transmittance).abs().max())
        err += float((res.scattering - ref.scattering).abs().max())
        errs.append(err)
    assert all(b < a for a, b in zip(errs, errs[1:], strict=False)), errs
    assert errs[-1] < errs[0] / 100  # midpoint rule: ~4x per doubling
    assert errs[4] < 1e-3  # the default 128 samples are well converged


def test_height_fog_transmittance_matches_integral():
    """Exponential height fog has a closed-form optical depth along a straight ray."""
    fld = HeightField(beta_ground=0.2, scale_height=3.0)
    o = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    d = torch.tensor([[0.0, math.cos(0.2), math.sin(0.2)]], dtype=torch.float64)
    dist = torch.tensor([50.0], dtype=torch.float64)
    dz = d[0, 2].item()
    tau = 0.2 * 3.0 / dz * (math.exp(-1.0 / 3.0) - math.exp(-(1.0 + 50.0 * dz) / 3.0))
    T = march(Medium("h", fld, LIGHT), o, d, dist, samples=1024, dtype=torch.float64).transmittance
    assert abs(float(T[0]) - math.exp(-tau)) < 1e-6


def test_sunlit_preset_light_is_forward_scattering_and_bounded():
    """Henyey-Greenstein g = 0.8: into the sun is ambient + sun colour, 90 degrees off it keeps under
    1 % of the sun term, and the ratio follows the closed form."""
    from components.synth.medium import ForwardScatterLight

    light = ForwardScatterLight((0.4, 0.5, 0.6), (0.5, 0.4, 0.3), SUN, g=0.8)
    sun = torch.tensor([SUN])
    side = torch.tensor([[1.0, 0.0, 0.0]])  # orthogonal to SUN
    assert torch.allclose(light.color(sun), torch.tensor([[0.9, 0.9, 0.9]]), atol=1e-6)
    side_sun = light.color(side) - torch.tensor(light.ambient)
    expected = ((1 - 0.8) ** 2 / (1 + 0.64)) ** 1.5  # p_HG(0) / p_HG(1)
    assert torch.allclose(side_sun, torch.tensor([light.sun_color]) * expected, atol=1e-6)
    assert expected < 0.01
    v = torch.nn.functional.normalize(torch.randn(400, 3), dim=-1)
    c = light.color(v)
    assert float(c.min()) >= 0 and float(c.max()) <= light.max_value + 1e-6


def test_sunlit_preset_fog_falls_with_height_and_varies_along_rays():
    from components.synth.medium import NoisyHeightField

    lay = make_layout("courtyard", seed=3)
    med = make_medium("sunlit", lay.medium_context(), seed=3)
    fld = med.extinction
    assert isinstance(fld, NoisyHeightField) and 0 < fld.strength < 1
    xy = torch.rand(2000, 2) * 20 - 10
    low = fld(torch.cat([xy, torch.full((2000, 1), 0.2)], -1))
    high = fld(torch.cat([xy, torch.full((2000, 1), 3 * fld.scale_height)], -1))
    assert bool((low > 0).all()) and float(low.mean()) > 5 * float(high.mean())
    assert float(low.std() / low.mean()) > 0.1  # the noise field makes it heterogeneous at one height
    o, d, t_end = rays(64, seed=2)
    t = t_end[:, None] * torch.linspace(0.05, 1.0, 8)[None]  # [R, K] sample distances
    along = fld.along(o, d, t)  # [R, K]
    assert along.shape == (64, 8)
    direct = fld(o[:, None, :] + t[..., None] * d[:, None, :])
    assert torch.allclose(along, direct)
