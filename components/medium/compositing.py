"""Physical compositing I = J*T + S with the medium ray-marched on a coarse grid of rays.

The medium is smooth, so evaluating it for every pixel wastes most of an iteration (~4 s at
320x240x16 on 2 cores, against ~0.1 s for the rasterizer). Instead:

1. Each pixel's end point is its own rendered z-depth blended with the far bound by the
   pixel's alpha: ``z = alpha * D + (1 - alpha) * far`` (background rays cross the whole medium).
2. Coarse rays are cast through the centres of ``stride x stride`` pixel blocks. Each marches
   K equal intervals from the camera to ``z_far``, the largest end depth among the pixels that
   use it (max-pooled, dilated by one block), evaluating the field at interval midpoints.
3. Along every coarse ray the cumulative optical depth ``Tau_k`` and scattering ``S_k`` at the
   interval boundaries form a profile in z. Each pixel reads the profiles of its four nearest
   coarse rays *at its own depth*, finishing the partial interval exactly (piecewise-constant
   medium), and blends them bilinearly. Depth edges therefore stay per-pixel sharp; only the
   medium's lateral variation is sampled at the coarse spacing.

With ``stride = 1`` every pixel marches its own ray to its own depth: the method's equations
exactly (``T = exp(-sum beta Delta)``, ``S = sum T_k (1 - exp(-beta Delta)) L_k``).

The depth the medium uses is detached by default: otherwise the photometric loss can move
surfaces to change the haze on them, a second route for the scene-medium ambiguity; geometry is
supervised by the depth prior instead (``depth_gradient`` turns the gradient on).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Annotated, Literal

import torch
from torch import Tensor
from torch.nn import functional as F

from components.data.cameras import Cameras
from components.medium.base import MediumField
from components.medium.pixel_readout import ReadoutGrid, read_pixels
from tridehaze_plugin.config import Positive, Range, check_numbers, retire_options

OPEN_SKY_COVERAGE = 0.5
"""Pixels covered less than this march their coarse rays to the far bound for the sky light; the
sky share of better covered pixels continues from their own ray's end with its last light (exact
in a homogeneous medium). Marching every not-quite-opaque pixel to the far bound spread its 16
samples over the whole box and cost courtyard-patchy 2.2 dB of reconstruction."""
MIN_FILL_PIXELS = 20
MIN_FILL_SHARE = 0.002
"""``farthest-seen`` needs at least this many (and this share of) a view's pixels just above the
fade to average; fewer say too little about the view's far surfaces, and the haze light is kept."""


@dataclass
class CompositeConfig:
    """How the medium is integrated along each pixel's ray."""

    num_samples: Annotated[int, Range(1)] = 16
    """K: medium samples per ray between the camera and the surface (far bound for background)."""
    ray_stride: Annotated[int | None, Range(1)] = None
    """The medium is marched along one ray per stride x stride pixel block (1 = every pixel);
    None: the stride that gives about ``coarse_rays`` rays, so the medium's cost does not grow with
    the image size (8 at 320x240, 3 at 128x96)."""
    coarse_rays: Annotated[int, Range(1)] = 1200
    """Target number of marched rays per view when ``ray_stride`` is None."""
    far: Annotated[float | None, Positive] = None
    """Far bound (scene units of camera z) for background pixels; None: the diagonal of the
    medium's bounding box, so background rays cross the whole modelled medium."""
    depth_gradient: bool = False
    """Let the composite's gradient flow into the rendered depth (off: depth is detached)."""
    coverage_gradient: bool = False
    """Let the composite's gradient flow into the coverage (alpha) that blends each pixel's end
    depth to the far bound. Detached, a less covered pixel marches further into the haze without
    the gradient knowing it: lowering a surface's opacity seems only to dim it, and surfaces drift
    half transparent (docs/results/coverage_diagnosis.md)."""
    fused_readout: bool = True
    """Read each pixel's T and S from the coarse rays with the compiled kernel on CPU (one pass per
    pixel, forward and backward) where a C++ compiler is available; the torch ops otherwise, and
    always on GPU. The same values to float32 rounding
    (tests/medium/test_pixel_readout.py); off: always the torch ops."""
    t_floor: Annotated[float, Range(0.0, 0.5, lo_open=True)] = 1e-6
    """Smallest transmittance returned (keeps 1/T and log T finite in opaque haze)."""
    background: Literal["far", "infinite"] = "far"
    """What a ray sees where the Gaussians do not cover it (sky, far background): ``far`` ends it
    at the far bound, so the clean render's background shows through exp(-beta * far) of haze;
    ``infinite`` continues it past the far bound through the boundary's medium to infinity (T = 0,
    in-scattering S + T L at the far end), the pixel's uncovered share is pure in-scattering, and
    the clean render shows that light there (the sky behind haze is unobservable; the dark
    channel's J = A convention)."""
    clean_sky: Literal["auto", "background", "haze-light"] = "auto"
    """What the clean render shows where the Gaussians do not cover a pixel: the background colour,
    or the haze's light arriving from infinity along the ray (the observed sky; the dark channel's
    J = A convention). It changes the clean render, not the composite's equations; with ``far``
    the coarse rays of pixels covered less than half then march to the far bound for that light,
    which moves their samples (T and S differ slightly where the medium varies across a block).
    ``auto``: the haze light with ``background infinite``, the background colour with ``far``."""
    clean_t0: Annotated[float, Range(0.0, 0.5)] = 0.0
    """Transmittance below which the clean render fades to the haze light along the ray: the dark
    channel's J = (I - A) / max(t, t0) + A applied to the model's own composite, so a pixel whose
    photos hold almost none of its clean colour (sky and far background in dense haze) shows the
    haze light rather than whatever colour the optimiser left there. Rendering only (the clean,
    not the composite, and never in training); 0: off."""
    clean_fill: Literal["haze-light", "farthest-seen", "farthest-ground", "auto"] = "haze-light"
    """What ``clean_t0`` fades to. ``haze-light``: the light along the ray (the dark channel's
    J = A, right for sky; with the fade's ramp it is the clamped inversion of the composite, which
    also pulls a too dense medium's over-dehazed colours back). ``farthest-seen``: the view's mean
    clean colour over the pixels just above the fade, T in [t0, 2 t0): the farthest surfaces the
    photos still see, standing in for the walls dense haze hides behind them (falls back to the
    haze light in a view with too few such pixels). ``farthest-ground``: the haze light above the
    horizon and, on rays that point below it (the scene's up from the training cameras), the mean
    clean colour of such pixels just above the fade: the ground runs on under the haze where the
    sky cannot be; not in ``auto``, since where the medium is too dense rather than the ground
    hidden it loses (statue). ``auto``: ``farthest-seen`` where the run judged its medium's light
    one light (the verdict at ``--pipeline.light-decision-fraction``, taken whatever the
    dark-channel weights; on every scene measured, one without open sky), else the haze light.
    On re-rendered runs (docs/results/medium_recovery.md, sessions 32 and 33) the farthest
    surfaces gain 3-5 dB on dense haze around walls and lose 3-7 dB on open sky; the farthest
    ground gains 0.3-2.8 dB on fields and rooms under the other verdict, loses 0.03-0.22 dB on
    streets and 0.4-0.7 dB on thin patchy haze over a field, and 1.0-2.5 dB on the hazed statue,
    whose background medium is too dense."""

    def check_values(self, prefix: str = "--pipeline.composite.") -> None:
        """The declared ranges, also for a config built in code rather than parsed."""
        check_numbers(self, prefix.removeprefix("--"))


# tried and removed; in the config.yml of runs trained while they existed (see retire_options)
retire_options(
    CompositeConfig,
    near_gradient=0.0,  # 6c6e05e
    per_gaussian=False,  # f7ef174
    jitter=False,  # 9e68f6f
)


@dataclass
class MediumRender:
    """Per-pixel medium terms of one view."""

    transmittance: Tensor  # [H, W, 1] in [t_floor, 1]: multiplies the clean render in I = J*T + S
    scattering: Tensor  # [H, W, 3] >= 0
    end_depth: Tensor  # [H, W, 1] z-depth the rays were marched to
    coverage: Tensor | None = None
    """[H, W, 1] the Gaussians' alpha (detached) wherever ``sky`` or ``at_infinity`` needs it."""
    sky: Tensor | None = None
    """[H, W, 3] light arriving from infinity along the ray, shown by the clean render where the
    Gaussians do not cover the pixel (``clean_sky``); None: the background colour is shown.
    Marched to the far bound where the coverage is below ``OPEN_SKY_COVERAGE``, continued from
    the ray's end elsewhere; weighted by 1 - coverage wherever it is used."""
    scattered_light: Tensor | None = None
    """[3] the mean light the view's rays scatter towards the camera, weighted by each sample's
    (detached) share of the in-scattering, so its gradient reaches the light only and not the
    extinction; None without a medium. The light anchor compares it with the dark
    channel's airlight of the view."""
    at_infinity: bool = False
    """The uncovered share of each pixel sees the medium to infinity (``background infinite``):
    the clean render composited is premultiplied (no background colour) and T is the
    transmittance to the covered surface; False: rays end at ``end_depth``."""

    def pixel_transmittance(self) -> Tensor:
        """[H, W, 1] the share of the pixel's clean radiance that reaches the camera (0 for sky)."""
        if not self.at_infinity or self.coverage is None:
            return self.transmittance
        return self.transmittance * self.coverage

    def ray_light(self, min_haze: float) -> Tensor:
        """[H, W, 3] the mean light each pixel's ray scatters, S / (1 - T), with 1 - T taken as at
        least ``min_haze`` (where the haze is thinner the ratio is noise)."""
        return self.scattering / (1.0 - self.pixel_transmittance()).clamp_min(min_haze)

    def clean_with_sky(self, clean: Tensor) -> Tensor:
        """The premultiplied clean render [H, W, 3] with the uncovered share filled by the sky light
        (unchanged when the clean render shows the background colour)."""
        if self.coverage is None or self.sky is None:
            return clean
        return clean + (1.0 - self.coverage) * self.sky

    def faded_clean(
        self,
        clean: Tensor,
        t0: float,
        fill: Literal["haze-light", "farthest-seen", "farthest-ground"] = "haze-light",
        below_horizon: Tensor | None = None,
    ) -> Tensor:
        """``clean`` [H, W, 3] blended by T / t0 where T < t0 to the pixel's mean haze light
        S / (1 - T) (``fill`` haze-light) or to the farthest seen surfaces' mean colour
        (``farthest-seen``; ``farthest-ground``: below the horizon only, ``below_horizon`` [H, W]
        bool, see ``CompositeConfig.clean_fill``). With I = J*T + S and S = A*(1 - T), the
        haze-light fade is exactly the clamped inversion (I - A) / max(T, t0) + A of the model's
        own composite."""
        if t0 <= 0.0:
            return clean
        T = self.pixel_transmittance()  # [H, W, 1]
        target = self.ray_light(1.0 - t0)  # [H, W, 3]
        if fill != "haze-light":
            band = ((T >= t0) & (T < 2.0 * t0))[..., 0]  # [H, W]: the farthest surfaces still seen
            if fill == "farthest-seen" and _enough(band):
                target = clean[band].mean(dim=0).expand_as(clean)  # [H, W, 3]
            elif fill == "farthest-ground" and below_horizon is not None and _enough(band & below_horizon):
                ground = clean[band & below_horizon].mean(dim=0)  # [3]
                target = torch.where(below_horizon[..., None], ground, target)  # [H, W, 3]
        w = T / T.clamp_min(t0)  # [H, W, 1]: 1 where T >= t0
        return w * clean + (1.0 - w) * target


def _enough(band: Tensor) -> bool:
    """Whether a fill's band [H, W] has the pixels to average (else the haze light stays)."""
    return int(band.sum()) >= max(MIN_FILL_PIXELS, MIN_FILL_SHARE * band.numel())


def below_horizon(cam: Cameras, H: int, W: int, up: Tensor) -> Tensor:
    """[H, W] bool: pixel rays pointing below the horizontal plane of the unit ``up`` [3]."""
    dirs, _ = pixel_rays(cam, H, W, up.device, up.dtype)  # [H, W, 3]
    return (dirs @ up) < 0.0


def _normalised_coords(cam: Cameras, xs: Tensor, ys: Tensor) -> tuple[Tensor, Tensor]:
    """Pixel coordinates xs [w], ys [h] (pixel centres at +0.5) -> x / z [w] and y / z [h]."""
    fx, fy, cx, cy = (float(v[0]) for v in (cam.fx, cam.fy, cam.cx, cam.cy))
    return (xs - cx) / fx, (ys - cy) / fy


def _pixel_dirs(cam: Cameras, xs: Tensor, ys: Tensor) -> tuple[Tensor, Tensor]:
    """Camera-space directions with unit z for pixel coordinates (pixel centres at +0.5).

    xs: [w], ys: [h] -> world dirs [h, w, 3] (z-normalised: a point at camera z is o + z * d),
    origin [3].
    """
    c2w = cam.camtoworlds[0].to(xs)  # [4, 4]
    dx, dy = _normalised_coords(cam, xs, ys)  # [w], [h]
    d_cam = torch.stack(
        [
            dx[None, :].expand(len(ys), -1),
            dy[:, None].expand(-1, len(xs)),
            torch.ones(len(ys), len(xs)).to(xs),
        ],
        dim=-1,
    )  # [h, w, 3]
    return d_cam @ c2w[:3, :3].T, c2w[:3, 3]


def pixel_rays(
    cam: Cameras, H: int, W: int, device: torch.device, dtype: torch.dtype
) -> tuple[Tensor, Tensor]:
    """Every pixel centre's ray as the compositor marches it: world directions [H, W, 3] with unit
    camera z (a point at camera z is origin + z * dir) and the origin [3]."""
    xs = torch.arange(W, device=device, dtype=dtype) + 0.5
    ys = torch.arange(H, device=device, dtype=dtype) + 0.5
    return _pixel_dirs(cam, xs, ys)


def pixel_path_lengths(cam: Cameras, H: int, W: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    """[H, W] path length per unit z of each pixel-centre ray, sqrt(1 + x^2 + y^2) in normalised
    image coordinates: the rotation leaves lengths alone, so only the intrinsics matter."""
    xs = torch.arange(W, device=device, dtype=dtype) + 0.5
    ys = torch.arange(H, device=device, dtype=dtype) + 0.5
    dx, dy = _normalised_coords(cam, xs, ys)  # [W], [H]
    return torch.sqrt(1.0 + dx[None, :].square() + dy[:, None].square())


def _scattered_light(share: Tensor, light: Tensor) -> Tensor:
    """[3] the mean of ``light`` [..., 3] weighted by each sample's scattered fraction ``share``
    [...], detached so that the gradient reaches the light only (``MediumRender.scattered_light``)."""
    w = share.detach()
    return (w[..., None] * light).flatten(0, -2).sum(0) / w.sum().clamp_min(1e-6)


@functools.lru_cache(maxsize=8)
def _bilinear_neighbours(
    H: int, W: int, h: int, w: int, s: int, device: torch.device, dtype: torch.dtype
) -> tuple[Tensor, Tensor]:
    """For each pixel, the 4 nearest coarse rays (block centres) and bilinear weights: [4, H*W] each.

    Cached: they depend on the image and grid sizes only (a few per run), and rebuilding them cost
    ~10 small ops per step. Callers must not write into the returned tensors."""
    px = (torch.arange(W, device=device, dtype=dtype) + 0.5) / s - 0.5  # [W] in coarse-ray units
    py = (torch.arange(H, device=device, dtype=dtype) + 0.5) / s - 0.5  # [H]
    x0 = px.floor().clamp(0, w - 1).long()
    y0 = py.floor().clamp(0, h - 1).long()
    x1, y1 = (x0 + 1).clamp(max=w - 1), (y0 + 1).clamp(max=h - 1)
    wx = (px - x0.to(px)).clamp(0, 1)  # [W]
    wy = (py - y0.to(py)).clamp(0, 1)  # [H]
    rays, wgts = [], []
    for yy, wyy in ((y0, 1 - wy), (y1, wy)):
        for xx, wxx in ((x0, 1 - wx), (x1, wx)):
            rays.append((yy[:, None] * w + xx[None, :]).reshape(-1))
            wgts.append((wyy[:, None] * wxx[None, :]).reshape(-1))
    return torch.stack(rays), torch.stack(wgts)


class MediumCompositor:
    """Computes T and S for a view from a medium field and the clean render's depth and alpha."""

    def __init__(self, config: CompositeConfig) -> None:
        config.check_values()
        self.config = config

    def stride_for(self, height: int, width: int) -> int:
        """Block size of the coarse ray grid for an image of this size."""
        if self.config.ray_stride is not None:
            return self.config.ray_stride
        return max(1, round(math.sqrt(height * width / self.config.coarse_rays)))

    def far_bound(self, field: MediumField) -> float:
        if self.config.far is not None:
            return float(self.config.far)
        return float(2.0 * field.bounds_half.norm())

    def end_depth(self, depth: Tensor, alpha: Tensor, far: float) -> Tensor:
        """Per-pixel z where the ray stops: the surface, blended to ``far`` by transparency."""
        d = depth if self.config.depth_gradient else depth.detach()
        a = (alpha if self.config.coverage_gradient else alpha.detach()).clamp(0.0, 1.0)
        return (a * d.clamp(min=0.0, max=far) + (1.0 - a) * far).clamp_min(1e-6)  # [H, W, 1]

    def __call__(self, field: MediumField, camera: Cameras, depth: Tensor, alpha: Tensor) -> MediumRender:
        """camera: [1]; depth, alpha: [H, W, 1] from the clean render."""
        H, W = depth.shape[:2]
        far = self.far_bound(field)
        infinite = self.config.background == "infinite"
        sky_shown = self.shows_sky()
        if infinite:  # the covered share ends at the surface; the rest is read at the far bound
            z = self.surface_depth(depth, far)[..., 0]  # [H, W]
        else:
            z = self.end_depth(depth, alpha, far)[..., 0]  # [H, W]
        z_rays = z
        if infinite or sky_shown:  # rays of uncovered pixels reach the far bound for the sky light
            open_px = alpha.detach()[..., 0] < OPEN_SKY_COVERAGE  # [H, W]
            z_rays = torch.where(open_px, torch.full_like(z, far), z)
        if not field.has_medium:
            return MediumRender(torch.ones_like(z)[..., None], z.new_zeros(H, W, 3), z[..., None])
        s, K = self.stride_for(H, W), self.config.num_samples
        h, w = math.ceil(H / s), math.ceil(W / s)
        # --- coarse rays: block centres, marched to the farthest end depth they serve
        zpad = F.pad(z_rays[None, None].detach(), (0, w * s - W, 0, h * s - H), mode="replicate")
        zfar = zpad  # [1, 1, h, w]; stride 1: each ray ends at its own pixel's depth
        if s > 1:  # the block's farthest depth, then one block further for the bilinear neighbours
            zfar = F.max_pool2d(F.max_pool2d(zpad, s), 3, stride=1, padding=1)
        zfar = zfar[0, 0]  # [h, w]
        xs = (torch.arange(w, device=z.device, dtype=z.dtype) + 0.5) * s  # block centres, pixels
        ys = (torch.arange(h, device=z.device, dtype=z.dtype) + 0.5) * s
        dirs, origin = _pixel_dirs(camera, xs, ys)  # [h, w, 3], [3]
        step_len = dirs.norm(dim=-1)  # [h, w] path length per unit z
        u = (torch.arange(K, device=z.device, dtype=z.dtype) + 0.5) / K  # [K]
        zs = zfar[..., None] * u  # [h, w, K]
        pts = origin + zs[..., None] * dirs[:, :, None, :]  # [h, w, K, 3]
        unit = (dirs / step_len[..., None]).reshape(-1, 3)  # [R, 3]
        sample = field.sample_rays(pts.reshape(h * w, K, 3), unit)
        beta, light = sample.beta, sample.light  # [R, K], [R, K, 3]
        dz = (zfar / K).reshape(-1)  # [R] interval length in z
        tau = beta * (dz * step_len.reshape(-1))[:, None]  # [R, K] optical depth per interval
        Tau = torch.cat([tau.new_zeros(h * w, 1), torch.cumsum(tau, dim=1)], dim=1)  # [R, K+1]
        Tb = torch.exp(-Tau)  # [R, K+1] transmittance at interval boundaries
        share = Tb[:, :-1] * -torch.expm1(-tau)  # [R, K] each sample's scattered fraction of S
        dS = share[..., None] * light  # [R, K, 3]
        Scum = torch.cat([dS.new_zeros(h * w, 1, 3), torch.cumsum(dS, dim=1)], dim=1)  # [R, K+1, 3]
        # one table per boundary k: Tau_k, tau_k, T_k, S_k (3), L_k (3) -> a single gather per pixel
        pad = tau.new_zeros(h * w, 1)
        table = torch.cat(
            [Tau[..., None], torch.cat([tau, pad], 1)[..., None], Tb[..., None], Scum,
             torch.cat([light, light[:, :1]], 1)],
            dim=-1,
        ).reshape(h * w * (K + 1), 9)  # fmt: skip
        # --- per pixel: the four nearest coarse rays, each read at the pixel's own depth and
        # rescaled to the pixel's own path length (exact for a homogeneous medium)
        rays, wgt = _bilinear_neighbours(H, W, h, w, s, z.device, z.dtype)  # [4, H*W] each
        pix_len = pixel_path_lengths(camera, H, W, z.device, z.dtype).reshape(-1)  # [H*W]
        grid = ReadoutGrid(table, rays, wgt, pix_len, step_len.reshape(-1), zfar.reshape(-1), K)

        fused = self.config.fused_readout
        tau_p, S_p, _ = read_pixels(grid, z.reshape(1, -1), fused=fused)  # [H*W], [H*W, 3]
        T = torch.exp(-tau_p).clamp_min(self.config.t_floor).reshape(H, W, 1)
        scattered = _scattered_light(share, light)  # [3]
        surface = MediumRender(T, S_p.reshape(H, W, 3), z[..., None], scattered_light=scattered)
        if not (infinite or sky_shown):
            return surface
        # past the far bound the field keeps its boundary value (clamped lookup): the rest of the
        # ray to infinity adds exp(-tau_far) * L_last and leaves nothing of what lies behind
        z_far = torch.full_like(z, far).reshape(1, -1)
        tau_f, S_f, L_last = read_pixels(grid, z_far, last_light=True, fused=fused)
        sky = (S_f + torch.exp(-tau_f)[:, None] * L_last).reshape(H, W, 3)
        return self.with_sky(surface, alpha, sky)

    def clean_view(
        self,
        med: MediumRender,
        clean: Tensor,
        one_light: bool = False,
        camera: Cameras | None = None,
        up: Tensor | None = None,
    ) -> Tensor:
        """The clean render [H, W, 3] as shown and evaluated: the sky filled (``clean_sky``) and
        faded where the photos cannot see it (``clean_t0``, to ``clean_fill``); ``one_light``: the
        run judged its medium's light the same along every ray (``clean_fill`` auto); ``camera``
        and the scene's unit ``up`` [3] place the horizon for ``farthest-ground`` (without them it
        is the haze-light fade)."""
        fill = self.fill(one_light)
        below = None
        if fill == "farthest-ground" and camera is not None and up is not None:
            below = below_horizon(camera, clean.shape[0], clean.shape[1], up.to(clean))
        return med.faded_clean(med.clean_with_sky(clean), self.config.clean_t0, fill, below)

    def fill(self, one_light: bool) -> Literal["haze-light", "farthest-seen", "farthest-ground"]:
        """The fade's target ``clean_fill`` resolves to for a run with this light verdict."""
        fill = self.config.clean_fill
        if fill == "auto":
            return "farthest-seen" if one_light else "haze-light"
        return fill

    def shows_sky(self) -> bool:
        """Whether the clean render shows the haze light where nothing covers a pixel."""
        mode = self.config.clean_sky
        return mode == "haze-light" or (mode == "auto" and self.config.background == "infinite")

    def surface_depth(self, depth: Tensor, far: float) -> Tensor:
        """[H, W, 1] where the covered share of each pixel ends (``background infinite``)."""
        d = depth if self.config.depth_gradient else depth.detach()
        return d.clamp(min=1e-6, max=far)

    def with_sky(self, surface: MediumRender, alpha: Tensor, sky: Tensor) -> MediumRender:
        """``surface`` (the medium to each pixel's end depth) completed with the light from
        infinity ``sky`` [H, W, 3] as the config asks: blended in by coverage (``background
        infinite``), kept for the clean render only (``clean_sky``), or dropped."""
        if self.config.background == "infinite":
            return self.open_sky(surface, alpha, sky)
        if self.shows_sky():
            return replace(surface, coverage=alpha.detach().clamp(0.0, 1.0), sky=sky)
        return surface

    def open_sky(self, surface: MediumRender, alpha: Tensor, sky: Tensor) -> MediumRender:
        """Blend the medium to the covered surface with the light from infinity ``sky`` [H, W, 3]
        by the pixel's coverage ``alpha`` [H, W, 1] (``background infinite``).

        Alpha keeps its gradient here: a hole in a surface shows the haze's own light, and only
        this derivative tells the optimizer so (detached, opacity resets left hazy holes that
        pruning then made permanent: docs/results/medium_recovery.md).
        """
        cover = alpha.clamp(0.0, 1.0)
        S = cover * surface.scattering + (1.0 - cover) * sky
        shown = sky if self.shows_sky() else None
        return MediumRender(
            surface.transmittance, S, surface.end_depth, coverage=cover.detach(), sky=shown,
            scattered_light=surface.scattered_light, at_infinity=True,
        )  # fmt: skip


def homogeneous_along_rays(
    beta: Tensor, light: Tensor, camera: Cameras, end_depth: Tensor, t_floor: float = 1e-6
) -> MediumRender:
    """Per-pixel homogeneous medium: beta [H, W], light [H, W, 3], end_depth [H, W, 1] (z).

    Used by media that give one value per pixel (``gaussian-bound``): T = exp(-beta * path),
    S = L (1 - T), path = z * |d| for the pixel's ray direction d with unit z.
    """
    H, W = beta.shape
    path = end_depth[..., 0] * pixel_path_lengths(camera, H, W, beta.device, beta.dtype)  # [H, W]
    tau = beta * path
    T = torch.exp(-tau).clamp_min(t_floor)
    share = -torch.expm1(-tau)  # [H, W] scattered fraction
    scattered = _scattered_light(share, light)  # [3]
    return MediumRender(T[..., None], light * share[..., None], end_depth, scattered_light=scattered)


def composite(clean: Tensor, medium: MediumRender) -> Tensor:
    """Hazy image I = J*T + S: clean [H, W, 3] -> [H, W, 3]."""
    return clean * medium.transmittance + medium.scattering


def composite_over_backdrop(surface: Tensor, backdrop: Tensor, medium: MediumRender) -> Tensor:
    """I = (surface + backdrop) T + S, with T held constant in the backdrop's term.

    surface [H, W, 3] is the Gaussians' premultiplied colour, backdrop [H, W, 3] the training
    background showing through their uncovered share, (1 - alpha) * bg. A random backdrop is a
    training device, not data: through T its variance rewards any extinction that hides it, so the
    medium thickens wherever coverage is still incomplete; here only the Gaussians' coverage answers
    for it (``--pipeline.medium-ignores-backdrop``, docs/results/medium_recovery.md, session 34).
    """
    return surface * medium.transmittance + backdrop * medium.transmittance.detach() + medium.scattering
