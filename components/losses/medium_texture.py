"""A prior against surface texture in the medium: neighbouring rays that end on the same surface
should cross about the same mean extinction.

The photometric loss cannot tell a darker patch of wall from a thicker patch of haze in front of it
(I = J T + S fits either), and the trained extinction field ends up carrying the walls' and
floors' texture (docs/results/medium_recovery.md, session 50). A smoothness prior on the field
itself (``medium.tv-weight``) also flattens real patchy haze. This one acts in the image: the mean
extinction along each pixel's ray, tau / z, compared between neighbouring pixels whose end depths
are close (a depth edge may change it: the rays then cross different haze). A homogeneous medium
gives a constant map whatever the geometry, so the prior does not thin or thicken the haze; large
patches change it slowly from pixel to pixel; texture changes it at the texture's scale.
"""

from __future__ import annotations

from torch import Tensor


def relative_mean_extinction(transmittance: Tensor, end_depth: Tensor, surface: Tensor) -> Tensor:
    """The mean extinction tau / z along each pixel's ray over its mean on the ``surface`` pixels
    [H, W]; transmittance, end_depth, surface: [H, W]."""
    z = end_depth.clamp_min(1e-6)  # [H, W]
    mean_ext = -transmittance.clamp_min(1e-12).log() / z  # [H, W] tau / z
    on = surface.to(mean_ext.dtype)
    # not detached: with it, a medium scaled by c costs c^2 as much, and the prior thinned every
    # scene's haze (mean T +0.05 to +0.13, street-sunlit's T MAE 0.08 -> 0.15)
    scale = ((mean_ext * on).sum() / on.sum().clamp_min(1.0)).clamp_min(1e-6)
    return mean_ext / scale


def same_surface_pairs(end_depth: Tensor, surface: Tensor, dim: int, max_depth_step: float) -> Tensor:
    """1 for each pair of pixels adjacent along ``dim`` that are both ``surface`` and whose end
    depths differ by less than ``max_depth_step`` in log depth, else 0: [H-1, W] or [H, W-1]."""
    on = surface.to(end_depth.dtype)
    log_z = end_depth.detach().clamp_min(1e-6).log()
    both = on.narrow(dim, 0, on.shape[dim] - 1) * on.narrow(dim, 1, on.shape[dim] - 1)
    return (log_z.diff(dim=dim).abs() < max_depth_step).to(on.dtype) * both


def path_extinction_roughness(
    transmittance: Tensor, end_depth: Tensor, surface: Tensor, max_depth_step: float
) -> Tensor:
    """Mean squared difference, relative to the view's mean, of the mean extinction tau / z between
    horizontally and vertically adjacent ``surface`` pixels whose end depths differ by less than
    ``max_depth_step`` in log depth.

    transmittance, end_depth: [H, W] (T in (0, 1], z > 0); surface: [H, W] bool, the pixels whose
    ray ends on the scene. Rays that leave the scene (the sky) cross other haze, of which the
    photos show only the sum: holding them to the surfaces' thinned the sky's haze and lost the
    sunlit scenes 3-5 dB. Relative to the view's mean over the surface pixels the prior is
    scale-free in value and gradient: it neither thins nor thickens the haze. 0 where no pair qualifies.
    """
    rel = relative_mean_extinction(transmittance, end_depth, surface)  # [H, W]
    total = rel.new_zeros(())
    pairs = rel.new_zeros(())
    for dim in (0, 1):
        same = same_surface_pairs(end_depth, surface, dim, max_depth_step).to(rel.dtype)
        total = total + (rel.diff(dim=dim).square() * same).sum()
        pairs = pairs + same.sum()
    return total / pairs.clamp_min(1.0)
