"""Spherical harmonics: hand-written reference polynomials and colour helpers."""

from __future__ import annotations

import math

import pytest
import torch

from components.gaussians.sh import eval_sh, eval_sh_bases, num_sh_bases, rgb_to_sh, sh_to_colors, sh_to_rgb

F64 = torch.float64


def _reference_bases(x: float, y: float, z: float) -> list[float]:
    """Real SH in the 3DGS sign convention, written out from the textbook normalisations
    (sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!)), and in gsplat's Sloan-style factored forms for l=3."""
    pi = math.pi
    b0 = [0.5 / math.sqrt(pi)]
    k1 = math.sqrt(3 / (4 * pi))
    b1 = [-k1 * y, k1 * z, -k1 * x]
    k2 = 0.5 * math.sqrt(15 / pi)
    b2 = [
        k2 * x * y,
        -k2 * y * z,
        0.25 * math.sqrt(5 / pi) * (3 * z * z - 1),
        -k2 * x * z,
        0.25 * math.sqrt(15 / pi) * (x * x - y * y),
    ]
    fc1, fs1 = x * x - y * y, 2 * x * y
    fc2, fs2 = x * fc1 - y * fs1, x * fs1 + y * fc1
    b3 = [
        -0.25 * math.sqrt(35 / (2 * pi)) * fs2,
        0.25 * math.sqrt(105 / pi) * z * fs1,
        -0.25 * math.sqrt(21 / (2 * pi)) * y * (5 * z * z - 1),
        0.25 * math.sqrt(7 / pi) * z * (5 * z * z - 3),
        -0.25 * math.sqrt(21 / (2 * pi)) * x * (5 * z * z - 1),
        0.25 * math.sqrt(105 / pi) * z * fc1,
        -0.25 * math.sqrt(35 / (2 * pi)) * fc2,
    ]
    return b0 + b1 + b2 + b3


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_eval_sh_matches_hand_written_polynomials(degree: int) -> None:
    d = torch.tensor([0.3, -0.5, 0.8], dtype=F64)
    d = d / d.norm()
    k = num_sh_bases(degree)
    ref = torch.tensor(_reference_bases(*d.tolist())[:k], dtype=F64)
    torch.testing.assert_close(eval_sh_bases(degree, d), ref, rtol=0, atol=1e-14)
    gen = torch.Generator().manual_seed(degree)
    coeffs = torch.randn(16, 3, generator=gen, dtype=F64)  # extra bands beyond the degree are ignored
    expect = (ref[:, None] * coeffs[:k]).sum(0)
    torch.testing.assert_close(eval_sh(degree, coeffs, d), expect, rtol=0, atol=1e-14)
    # directions are normalised inside, and leading dims broadcast
    out = eval_sh(degree, coeffs[None, None], 7.0 * d[None, None].expand(2, 5, 3))
    torch.testing.assert_close(out, expect.expand(2, 5, 3), rtol=0, atol=1e-13)


def test_bases_are_orthonormal_on_the_sphere() -> None:
    """Monte Carlo check that the constants are the orthonormal ones (catches a wrong factor)."""
    gen = torch.Generator().manual_seed(0)
    dirs = torch.randn(400_000, 3, generator=gen, dtype=F64)
    b = eval_sh_bases(3, dirs)  # [M, 16]
    gram = (b.T @ b) * (4 * math.pi / dirs.shape[0])
    torch.testing.assert_close(gram, torch.eye(16, dtype=F64), rtol=0, atol=0.02)


def test_rgb_sh_round_trip_and_colour() -> None:
    rgb = torch.tensor([[0.0, 0.25, 1.0], [0.5, 0.9, 0.1]], dtype=F64)
    torch.testing.assert_close(sh_to_rgb(rgb_to_sh(rgb)), rgb, rtol=0, atol=1e-15)
    coeffs = torch.zeros(2, 16, 3, dtype=F64)
    coeffs[:, 0] = rgb_to_sh(rgb)
    dirs = torch.tensor([[1.0, 2.0, 3.0], [-1.0, 0.0, 0.5]], dtype=F64)
    for degree in range(4):
        torch.testing.assert_close(sh_to_colors(degree, coeffs, dirs), rgb, rtol=0, atol=1e-15)
    coeffs[:, 0] = rgb_to_sh(torch.full((2, 3), -0.3, dtype=F64))
    assert (sh_to_colors(0, coeffs, dirs) == 0).all()  # clamped at 0 like gsplat


def test_invalid_degrees() -> None:
    with pytest.raises(ValueError):
        eval_sh(4, torch.zeros(25, 3), torch.ones(3))
    with pytest.raises(ValueError):
        eval_sh(2, torch.zeros(4, 3), torch.ones(3))
