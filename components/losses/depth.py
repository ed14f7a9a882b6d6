"""Depth regularisers for the Gaussian depth render: Pearson correlation (optionally trimmed of its
worst residuals), edge-aware smoothness,
a log-depth L1 for priors that carry the scene's own scale, and the depth spread along each ray.

The first two are scale-free on purpose: most pseudo-depth priors (files, dark channel) are only
defined up to an unknown affine map. Sparse SfM depth is the exception: the points live in the
cameras' own frame, so :func:`log_depth_l1` can hold the rendered depth to it.
Masks are applied as weights (no boolean indexing, no ``.item()``), so no function here forces a
host-device sync in the training step.
"""

from __future__ import annotations

import torch
from torch import Tensor

MIN_VALID_PIXELS = 10
"""Fewer valid pixels than this and a correlation is noise: the loss returns 0 instead."""


def _masked_mean(x: Tensor, w: Tensor, n: Tensor) -> Tensor:
    return (x * w).sum() / n


def _prior_pixels(prior: Tensor, mask: Tensor | None) -> Tensor:
    """[H, W] bool: finite prior pixels inside ``mask``."""
    valid = torch.isfinite(prior)
    return valid & mask.bool() if mask is not None else valid


def _standardised(x: Tensor, valid: Tensor, w: Tensor, n: Tensor, eps: float) -> Tensor:
    """``x`` [H, W] with mean 0 and variance 1 over ``valid`` (weights ``w``, count ``n``), 0 elsewhere."""
    x = torch.where(valid, x, torch.zeros_like(x))
    x = (x - _masked_mean(x, w, n)) * w
    return x / torch.sqrt(x.square().sum() / n + eps)


def _zero_if_few(loss: Tensor, count: Tensor) -> Tensor:
    """``loss``, or a differentiable 0 where fewer than ``MIN_VALID_PIXELS`` pixels were valid."""
    return torch.where(count >= MIN_VALID_PIXELS, loss, loss * 0.0)


def pearson_depth_loss(pred: Tensor, prior: Tensor, mask: Tensor | None = None, eps: float = 1e-8) -> Tensor:
    """1 - Pearson correlation of ``pred`` and ``prior`` [H, W] over ``mask`` (bool [H, W]).

    Each map is standardised per view (mean 0, std 1), so the loss is invariant to any positive
    affine change of either input; it lies in [0, 2] (0: perfectly correlated, 2: anti-correlated).
    Non-finite prior pixels are ignored. ``eps`` is added to the variance so a constant map gives a
    finite loss (1) and finite gradients. Returns a differentiable 0 below ``MIN_VALID_PIXELS``.
    """
    valid = _prior_pixels(prior, mask)
    w = valid.to(pred.dtype)  # [H, W]
    count = w.sum()
    n = count.clamp_min(1.0)
    p = _standardised(pred, valid, w, n, eps)
    q = _standardised(prior.to(pred.dtype), valid, w, n, eps)
    loss = 1.0 - (p * q).sum() / n
    return _zero_if_few(loss, count)


def trimmed_pearson_depth_loss(
    pred: Tensor, prior: Tensor, mask: Tensor | None = None, trim: float = 0.2
) -> Tensor:
    """:func:`pearson_depth_loss` without the ``trim`` share of the prior's pixels that disagree
    most with ``pred`` [H, W] (largest squared difference of the two standardised maps, chosen
    without gradient each call, as MiDaS's trimmed loss does).

    Sparse SfM depth carries outliers (mismatches, hidden points reprojected through gaps in a
    sparse foreground), and one far outlier moves a Pearson correlation more than many good near
    pixels; dropping the worst residuals keeps the pull where prior and render roughly agree.
    ``trim`` = 0 is :func:`pearson_depth_loss`.
    """
    if trim <= 0.0:
        return pearson_depth_loss(pred, prior, mask)
    return pearson_depth_loss(pred, prior, untrimmed_pixels(pred, prior, mask, trim))


@torch.no_grad()
def untrimmed_pixels(pred: Tensor, prior: Tensor, mask: Tensor | None, trim: float) -> Tensor:
    """[H, W] bool: the prior's pixels (finite, inside ``mask``) that
    :func:`trimmed_pearson_depth_loss` keeps, i.e. all but the ``trim`` share with the largest
    squared difference of ``pred`` and ``prior`` standardised over them."""
    valid = _prior_pixels(prior, mask)
    w = valid.to(pred.dtype)  # [H, W]
    n = w.sum().clamp_min(1.0)
    p = _standardised(pred, valid, w, n, 1e-8)
    q = _standardised(prior.to(pred.dtype), valid, w, n, 1e-8)
    resid = torch.where(valid, (p - q).square(), torch.full_like(p, float("nan")))  # [H, W]
    cut = torch.nanquantile(resid.flatten(), 1.0 - trim)
    return valid & (resid <= cut)  # NaN compares False: invalid pixels stay out


def edge_aware_smoothness(
    depth: Tensor, image: Tensor, mask: Tensor | None = None, gamma: float = 10.0, eps: float = 1e-8
) -> Tensor:
    """Mean of |dx D| exp(-gamma |dx I|) + |dy D| exp(-gamma |dy I|), depth [H, W], image [H, W, 3].

    Depth discontinuities are allowed where the image has an edge and penalised in flat regions.
    The depth is divided by its (masked) mean first, so the term does not depend on the world scale
    and cannot be lowered by shrinking the scene. A finite difference counts only where both of its
    pixels are in ``mask``; with no valid pair the term is a differentiable 0.
    """
    valid = torch.ones_like(depth, dtype=torch.bool) if mask is None else mask.bool()
    w = valid.to(depth.dtype)  # [H, W]
    scale = _masked_mean(depth.abs(), w, w.sum().clamp_min(1.0)).clamp_min(eps)
    d = depth / scale  # [H, W]
    img = image.to(d.dtype)
    dx_i = (img[:, 1:] - img[:, :-1]).abs().mean(-1)  # [H, W-1]
    dy_i = (img[1:, :] - img[:-1, :]).abs().mean(-1)  # [H-1, W]
    wx = (d[:, 1:] - d[:, :-1]).abs() * torch.exp(-gamma * dx_i)  # [H, W-1]
    wy = (d[1:, :] - d[:-1, :]).abs() * torch.exp(-gamma * dy_i)  # [H-1, W]
    vx = w[:, 1:] * w[:, :-1]  # [H, W-1]
    vy = w[1:, :] * w[:-1, :]  # [H-1, W]
    return (wx * vx).sum() / vx.sum().clamp_min(1.0) + (wy * vy).sum() / vy.sum().clamp_min(1.0)


def log_depth_l1(pred: Tensor, prior: Tensor, mask: Tensor | None = None, eps: float = 1e-6) -> Tensor:
    """Mean |ln pred - ln prior| over ``mask`` [H, W]: the relative depth error, for a prior in the
    rendered depth's own units (sparse SfM z). L1 so that the SfM cloud's outliers pull like a
    median, not a mean. Non-finite or non-positive prior pixels are ignored; a differentiable 0
    below ``MIN_VALID_PIXELS``."""
    valid = _prior_pixels(prior, mask) & (prior > 0)
    w = valid.to(pred.dtype)  # [H, W]
    count = w.sum()
    q = torch.where(valid, prior.to(pred.dtype), torch.ones_like(pred))
    err = (pred.clamp_min(eps).log() - q.log()).abs()  # [H, W]
    return _zero_if_few(_masked_mean(err, w, count.clamp_min(1.0)), count)


def depth_spread(moments: Tensor, min_alpha: float = 0.5) -> Tensor:
    """Mean over pixels covered at least ``min_alpha`` of Var[z] / E[z]^2, the squared coefficient
    of variation of the depths blended into each pixel. ``moments`` [H, W, 3] holds the blended
    sums of 1, z and z^2 (alpha, alpha E[z], alpha E[z^2]: the values rendered like a colour on a
    zero background). Scale-free, 0 for a pixel whose weight sits at one depth. Like Mip-NeRF 360's
    distortion loss it draws the Gaussians along a ray onto one surface."""
    alpha, first, second = moments.unbind(-1)  # [H, W] each
    w = (alpha > min_alpha).to(moments.dtype)
    a = alpha.clamp_min(1e-6)
    mean = first / a
    var = second / a - mean * mean
    ratio = var.clamp_min(0.0) / (mean * mean).clamp_min(1e-8)
    return _masked_mean(ratio, w, w.sum().clamp_min(1.0))
