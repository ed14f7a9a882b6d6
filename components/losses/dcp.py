"""Dark channel prior (He et al., CVPR 2009): transmittance and airlight from one hazy image.

Under I = J t + A (1 - t), haze-free outdoor patches have a colour channel near 0 (shadows,
saturated colours), so the patch-wise minimum of I / A gives 1 - t. The estimate supervises the
medium's transmittance in Stage I (``dcp_transmittance_loss``) and yields a pseudo-depth
(-ln t, see ``depth_priors``). The core is numpy/OpenCV: it runs once per view, not per step.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch
from torch import Tensor

try:  # opencv-contrib's module; absent where a plain opencv build shadows it
    from cv2 import ximgproc
except ImportError:  # pragma: no cover - depends on the installed OpenCV build
    ximgproc = None

BRIGHTEST_FRACTION = 1e-3
"""Share of the dark channel's brightest pixels whose mean colour is the airlight (He et al.: 0.1%)."""


@dataclass
class DCPResult:
    """Per-image dark-channel estimates."""

    transmittance: np.ndarray  # [H, W] float32, guided-filter refined, in [t0, 1]
    airlight: np.ndarray  # [3] float32, RGB
    dark: np.ndarray  # [H, W] float32, dark channel of the input image


def default_patch(height: int, width: int) -> int:
    """Odd patch size scaling with the image (15 at 600 px as in He et al.; >= 3)."""
    return max(3, round(min(height, width) / 40)) | 1


def dark_channel(image: np.ndarray, patch: int) -> np.ndarray:
    """[H, W, C] -> [H, W]: min over channels, then min over a ``patch`` x ``patch`` square."""
    mins = np.ascontiguousarray(image.min(axis=2), dtype=np.float32)  # [H, W]
    # erode = min filter; its default border value never wins a min, so edges are not darkened
    return cv2.erode(mins, np.ones((patch, patch), np.uint8))


def estimate_airlight(image: np.ndarray, dark: np.ndarray) -> np.ndarray:
    """Mean colour [3] of the input at the brightest 0.1% of the dark channel (the haziest pixels)."""
    flat = dark.reshape(-1)
    n = max(1, round(BRIGHTEST_FRACTION * flat.size))
    idx = np.argpartition(flat, flat.size - n)[flat.size - n :]  # [n]
    return image.reshape(-1, image.shape[2])[idx].mean(axis=0).astype(np.float32)


def _as_float(image: np.ndarray) -> np.ndarray:
    """uint8 or float [H, W, 3] -> float32 in [0, 1]."""
    if image.dtype == np.uint8:
        return image.astype(np.float32) / 255.0
    return np.clip(image.astype(np.float32), 0.0, 1.0)


def guided_filter(guide: np.ndarray, src: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """He et al.'s guided filter of ``src`` [H, W] by a grey ``guide`` [H, W] (float32).

    OpenCV's contrib build (``cv2.ximgproc``) when it is importable; else the same filter on base
    OpenCV's box filter (equal within 2e-5, tests/losses/test_dcp.py). A plain
    opencv-python(-headless) installed beside or instead of the contrib build (GPU images ship one)
    hides ``ximgproc``, and the dark channel should not fail for it."""
    if ximgproc is not None:
        return ximgproc.guidedFilter(guide, src, radius, eps)
    return box_guided_filter(guide, src, radius, eps)


def box_guided_filter(guide: np.ndarray, src: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """The guided filter from means over (2r+1)^2 windows, reflected at the border as ximgproc does."""
    size = (2 * radius + 1, 2 * radius + 1)

    def mean(x: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(x, -1, size, normalize=True, borderType=cv2.BORDER_REFLECT)

    g, p = guide.astype(np.float32), src.astype(np.float32)  # [H, W]
    mg, mp = mean(g), mean(p)
    a = (mean(g * p) - mg * mp) / (mean(g * g) - mg * mg + eps)  # [H, W] local linear model
    b = mp - a * mg
    return (mean(a) * g + mean(b)).astype(np.float32)


def estimate_dcp(
    image: np.ndarray,
    patch: int | None = None,
    omega: float = 0.95,
    t0: float = 0.05,
    guided_radius: int | None = None,
    guided_eps: float = 1e-3,
    airlight: np.ndarray | None = None,
) -> DCPResult:
    """Transmittance and airlight of a hazy RGB image [H, W, 3] (float in [0, 1] or uint8).

    ``omega`` < 1 keeps a little haze so far objects still look far (He et al.); ``t0`` bounds t
    away from 0 (sky and airlight-coloured pixels, where the prior fails, end up there). The coarse
    patch-wise t is refined by a guided filter on the grey image (``guided_radius`` default: 4
    patches), which restores object edges that the min filter blurred. ``airlight`` [3]: a known
    haze light, used instead of the brightest dark-channel pixels (which under-estimate it where no
    pixel is opaque haze).
    """
    img = _as_float(image)  # [H, W, 3]
    h, w = img.shape[:2]
    patch = default_patch(h, w) if patch is None else int(patch)
    radius = 4 * patch if guided_radius is None else int(guided_radius)
    dark = dark_channel(img, patch)  # [H, W]
    if airlight is None:
        airlight = estimate_airlight(img, dark)  # [3]
    else:
        airlight = np.asarray(airlight, dtype=np.float32).reshape(3)
    t = 1.0 - omega * dark_channel(img / np.maximum(airlight, 1e-3), patch)  # [H, W]
    if radius > 0:
        grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)  # [H, W]
        t = guided_filter(grey, t.astype(np.float32), radius, guided_eps)
    t = np.clip(t, t0, 1.0).astype(np.float32)
    return DCPResult(transmittance=t, airlight=airlight, dark=dark)


def dehaze(image: np.ndarray, result: DCPResult, t0: float = 0.05) -> np.ndarray:
    """Single-image DCP dehazing J = (I - A) / max(t, t0) + A, clipped to [0, 1] (a baseline)."""
    img = _as_float(image)  # [H, W, 3]
    t = np.maximum(result.transmittance, t0)[..., None]  # [H, W, 1]
    a = result.airlight[None, None, :]  # [1, 1, 3]
    return np.clip((img - a) / t + a, 0.0, 1.0).astype(np.float32)


def dcp_transmittance_loss(
    T_hat: Tensor,  # noqa: N803
    T_dcp: Tensor,  # noqa: N803
    mask: Tensor | None = None,
    lower_bound: bool = False,
    upper_weight: float = 0.0,
    weight: Tensor | None = None,
) -> Tensor:
    """Mean squared error between the rendered transmittance and the DCP estimate, both [H, W].

    ``lower_bound``: penalise only T below the estimate. With the true airlight and omega = 1 the
    dark channel can only under-estimate t (min(I / A) = t min(J / A) + 1 - t >= 1 - t), and it
    does so wherever the clean patch has no dark pixel (bright or textured surfaces, indoors).
    ``upper_weight``: with ``lower_bound``, T above the estimate still costs this fraction of the
    squared error (most clean patches do have a dark pixel, so the bound is usually close; 0: a
    pure bound, 1: the two-sided loss).
    The mask is a weight (no boolean indexing, so no host sync); an empty mask gives 0.
    ``weight`` [H, W]: a per-pixel factor on the penalty; the mean is still over the mask's pixels,
    so a weight below 1 takes force off a pixel rather than moving it to the others.
    """
    diff = T_dcp.to(T_hat) - T_hat  # [H, W]
    if lower_bound:
        diff = diff.clamp_min(0.0).square() + upper_weight * diff.clamp_max(0.0).square()
    else:
        diff = diff.square()
    if mask is None and weight is None:
        return diff.mean()
    w = torch.ones_like(diff) if mask is None else mask.to(diff.dtype)
    count = w.sum().clamp_min(1.0)
    if weight is not None:
        w = w * weight.to(diff)
    return (diff * w).sum() / count


def dark_channel_bound(
    image: Tensor,
    light: Tensor,
    patch: int,
    omega: float = 0.95,
) -> Tensor:
    """The dark channel's lower bound on T [H, W] with a per-pixel airlight (torch, differentiable
    in nothing: both inputs are detached by the caller).

    image, light: [H, W, 3]. t >= 1 - omega * min_patch min_c I_c / A_c holds wherever the clean
    patch has a dark pixel and A is the light the haze scatters *along that ray*. One airlight per
    image over-estimates t where the haze's light is dimmer than that (away from the sun in
    forward-scattering haze); the medium's own light per pixel does not.
    """
    ratio = (image / light.clamp_min(1e-3)).amin(dim=-1)  # [H, W]
    return (1.0 - omega * min_filter(ratio, patch)).clamp(0.0, 1.0)


def _sliding_min(x: Tensor, size: int, dim: int) -> Tensor:
    """Centred min over ``size`` (odd) along ``dim``, +inf beyond the border; same length."""
    pad_shape = list(x.shape)
    pad_shape[dim] = size // 2
    pad = x.new_full(pad_shape, float("inf"))
    m, width = torch.cat([pad, x, pad], dim=dim), 1
    while 2 * width <= size:  # m[i] = min of the width values from i, doubling
        n = m.shape[dim]
        m = torch.minimum(m.narrow(dim, 0, n - width), m.narrow(dim, width, n - width))
        width *= 2
    if width < size:  # two overlapping windows of ``width`` cover ``size``
        rest, n = size - width, m.shape[dim]
        m = torch.minimum(m.narrow(dim, 0, n - rest), m.narrow(dim, rest, n - rest))
    return m


def min_filter(x: Tensor, patch: int) -> Tensor:
    """[H, W] -> [H, W]: min over the ``patch`` x ``patch`` square around each pixel (odd patch),
    the image's border not extended. Min is separable and exact, so two 1-D passes of log2(patch)
    element-wise minima give max_pool2d's values at a fraction of its cost (it ran every step)."""
    return _sliding_min(_sliding_min(x, patch, 0), patch, 1)


def dcp_transmittance_tensor(image: np.ndarray, **kwargs) -> torch.Tensor:
    """Convenience: ``estimate_dcp(image, **kwargs).transmittance`` as a float32 tensor [H, W]."""
    return torch.from_numpy(estimate_dcp(image, **kwargs).transmittance)
