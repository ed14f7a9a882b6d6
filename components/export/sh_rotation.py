"""Rotating view-dependent colour: real SH coefficients under a rotation of the world.

Each SH band l is closed under rotation: ``Y_l(R d) = D_l(R) Y_l(d)`` with an orthogonal
``(2l+1) x (2l+1)`` matrix D_l. Rather than hand-coding Wigner matrices in the sign convention of
``components.gaussians.sh``, D_l is *solved* from that identity at a fixed set of directions with
the very basis the rasterizers evaluate, so the convention cannot drift (exact to float64 round-off,
tested).

Rotating a scene by R carries its colour function along: ``c'(d) = c(R^-1 d)``, whose band-l
coefficients are ``D_l(R^-1)^T c_l = D_l(R) c_l`` (D_l is orthogonal and a representation).
"""

from __future__ import annotations

import numpy as np
import torch

from components.gaussians.sh import eval_sh_bases


def _directions(m: int = 64) -> np.ndarray:
    """``m`` well-spread unit directions (Fibonacci sphere) [m, 3]."""
    i = np.arange(m) + 0.5
    phi = np.arccos(1 - 2 * i / m)
    theta = np.pi * (1 + 5**0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)


def sh_band_rotations(R: np.ndarray, degree: int) -> list[np.ndarray]:  # noqa: N803
    """[D_1, ..., D_degree] for the rotation ``R`` [3, 3]: ``Y_l(R d) = D_l Y_l(d)``."""
    if degree == 0:
        return []
    d = torch.from_numpy(_directions())  # [M, 3] float64
    rd = d @ torch.from_numpy(np.asarray(R, np.float64)).T  # [M, 3]
    a = eval_sh_bases(degree, d).numpy()  # [M, K]
    b = eval_sh_bases(degree, rd).numpy()  # [M, K]
    out = []
    for band in range(1, degree + 1):
        lo, hi = band * band, (band + 1) * (band + 1)
        dt, *_ = np.linalg.lstsq(a[:, lo:hi], b[:, lo:hi], rcond=None)  # b = a D^T
        out.append(dt.T)
    return out


def rotate_sh(shN: np.ndarray, R: np.ndarray) -> np.ndarray:  # noqa: N803
    """The higher-band coefficients ``shN [N, K-1, C]`` after rotating the whole scene by ``R``.

    Returns c' with ``sum_l c'_l . Y_l(d) = sum_l c_l . Y_l(R^-1 d)`` for every direction d: the
    colour seen along d after the rotation is the one seen along ``R^-1 d`` before it.
    """
    k = shN.shape[1] + 1
    degree = round(k**0.5) - 1
    if (degree + 1) ** 2 != k:
        raise ValueError(f"{k} SH coefficients is not a full set of bands")
    out = np.empty_like(shN)
    # c(R^-1 d) with coefficients c: sum c_l^T D_l(R^-1) Y_l(d) -> c'_l = D_l(R^-1)^T c_l = D_l(R) c_l
    for band, D in enumerate(sh_band_rotations(R, degree), start=1):
        lo, hi = band * band - 1, (band + 1) * (band + 1) - 1
        out[:, lo:hi, :] = np.einsum("ij,njc->nic", D, shN[:, lo:hi, :])
    return out
