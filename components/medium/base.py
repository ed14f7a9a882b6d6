"""The medium field interface: extinction beta(x) and medium light L(x, v), shared by all views.

A field maps world points and viewing directions to ``beta >= 0`` and ``L in [0, 1]^3``. The
spatial representation (tri-plane, voxel grid, coordinate MLP, ...) is a registered *encoder*
(kind ``medium``); the heads that turn features into beta and L are shared here so that every
ablation changes one thing only (docs/medium.md).

    beta(x)   = kappa * softplus(h_beta(f(x)))          kappa > 0 learnable, global
    L(x, v)   = sigmoid(SH_v(h_L(f(x))))                SH order 0..2, or ``rgb``: sigmoid(h_L(f(x)))
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, Literal

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from components.gaussians.sh import eval_sh, num_sh_bases
from tridehaze_plugin.config import (
    ComponentConfig,
    NonNegative,
    Positive,
    Range,
    RegistryChoice,
    check_numbers,
)
from tridehaze_plugin.errors import ConfigError
from tridehaze_plugin.registry import REGISTRY

if TYPE_CHECKING:
    from pathlib import Path

    from components.data.cameras import Cameras
    from components.data.scene import SceneTransform
    from components.gaussians.model import GaussianModel
    from components.medium.compositing import MediumCompositor, MediumRender
    from components.rasterizers.base import Rasterizer


@dataclass
class FieldBounds:
    """Axis-aligned box in which the field is resolved; coordinates are normalised to [-1, 1].

    Points outside the box are *clamped* onto its surface: the medium continues with its boundary
    value, which is what a smooth haze far away looks like and keeps the lookup finite for rays
    that reach the far bound (docs/medium.md).
    """

    center: Tensor  # [3]
    half_size: Tensor  # [3], > 0

    def normalize(self, x: Tensor) -> Tensor:
        """World points [..., 3] -> box coordinates in [-1, 1] (clamped)."""
        c, h = self.center.to(x), self.half_size.to(x)
        return ((x - c) / h).clamp(-1.0, 1.0)

    def inside(self, x: Tensor) -> Tensor:  # [...] bool
        c, h = self.center.to(x), self.half_size.to(x)
        return ((x - c).abs() <= h).all(dim=-1)

    @staticmethod
    def from_scene(
        camera_centers: Tensor,  # [C, 3]
        points: Tensor | None = None,  # [M, 3]
        quantile: float = 0.98,
        margin: float = 0.1,
    ) -> FieldBounds:
        """The box holding every camera and the central ``quantile`` of the seed points, padded.

        A few far-away SfM outliers would otherwise stretch the box and waste resolution; the
        points beyond it are covered by clamping.
        """
        pts = [camera_centers.detach().float().reshape(-1, 3)]
        if points is not None and len(points) > 0:
            p = points.detach().float().reshape(-1, 3).to(pts[0].device)
            if len(p) > 20:
                lo = torch.quantile(p, 1.0 - quantile, dim=0)
                hi = torch.quantile(p, quantile, dim=0)
                p = p[((p >= lo) & (p <= hi)).all(dim=-1)]
            pts.append(p)
        allp = torch.cat(pts)
        lo, hi = allp.min(0).values, allp.max(0).values
        center = (lo + hi) / 2
        half = (hi - lo) / 2
        extent = float(half.max()) if float(half.max()) > 0 else 1.0
        half = half.clamp_min(0.05 * extent) * (1.0 + margin) + 1e-6
        return FieldBounds(center, half)

    def to_dict(self) -> dict[str, list[float]]:
        return {"center": self.center.tolist(), "half_size": self.half_size.tolist()}


@dataclass
class MediumSample:
    """Medium quantities at P points."""

    beta: Tensor  # [P] extinction (1 / scene unit), >= 0
    light: Tensor  # [P, 3] medium light in [0, 1]


@dataclass
class MediumConfig(ComponentConfig):
    """The view-shared medium field (``none`` turns the medium off: plain 3DGS)."""

    backend: Annotated[str, RegistryChoice("medium", allow=("auto",))] = "none"
    """Medium representation: ``triplane``, ``voxel``, ``mlp``, ``fourier``, ``constant``,
    ``gaussian-bound``, ``none``, ``reference`` (a diagnosis on td-synth data: the generator's true
    medium, nothing learnt), or ``auto``: before training a haze probe of the training views
    classifies the haze (none / homogeneous / varying / unsure), picks ``none`` only for a capture
    it can show to be clear (else triplane) and logs why, with a confidence (docs/tradeoff.md)."""
    resolution: Annotated[int, Range(2, 1024)] = 64
    """Tri-plane side (three planes of resolution^2 cells); other grids match its feature budget."""
    channels: Annotated[int, Range(1, 256)] = 8
    """Feature channels per plane cell (the tri-plane feature is 3 * channels wide)."""
    hidden: Annotated[int, Range(1, 4096)] = 64
    """Width of the two-layer heads (and of the coordinate MLPs)."""
    light: Literal["sh", "rgb", "mlp", "axial"] = "sh"
    """Medium light: direction-dependent spherical harmonics, a direction-free RGB colour (the
    paper's "tri-plane RGB" ablation), ``mlp``: the light head also reads a Fourier encoding of
    the direction, for a sharper dependence than SH (a forward-scattering glow towards the sun),
    or ``axial``: the same head reads only the cosine between the direction and one learnt axis.
    Single scattering of one source (the sun, the light from above under water) depends on the
    angle to it alone; a light free in every direction can instead take up a colour the photos
    show in some directions only (the sky), as pure haze (docs/results/medium_recovery.md,
    session 29)."""
    light_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """``axial`` light: the axis it starts from, in the run's (normalised) frame; learnt from there."""
    sh_degree: Annotated[int, Range(0, 2)] = 1
    """SH order of the medium light when ``light`` is ``sh`` (0, 1 or 2)."""
    light_space: Literal["field", "smooth", "global"] = "field"
    """Where the medium light may vary: ``field`` reads it from the field's features like the
    extinction (it can change from cell to cell); ``smooth`` from a small MLP of the point's box
    coordinates alone (a slow variation, e.g. dimmer near the ground or deeper under water);
    ``global`` gives every point the same light. The light varies with the viewing direction in
    all three, and the extinction stays a field. The coarser forms cannot follow the scene's
    colours (docs/results/medium_recovery.md, session 23)."""
    num_frequencies: Annotated[int, Range(0, 32)] = 6
    """Octaves of the ``fourier`` encoder (sin/cos of 2^k pi x)."""
    lr: Annotated[float, NonNegative] = 1e-2
    """Learning rate of the field's features and heads."""
    kappa_lr: Annotated[float, NonNegative] = 1e-2
    """Learning rate of log(kappa), the global extinction scale."""
    feature_lr: Annotated[float, NonNegative] | None = None
    """Learning rate of the grid backends' features (triplane, voxel); None: ``lr``. Adam moves
    every cell by about its rate each step whatever the size of its gradient, so a cell whose
    one-view gradients change sign from step to step wanders (a random walk of rate x sqrt(steps)),
    while a consistent pull moves it rate x steps: a lower rate quiets the first far more than it
    limits the second. At 0.003 on ``tri-dehaze``, paired on the benchmark: -0.20 / +0.07 dB
    (seeds 42 / 7; room-uniform up, field-sunlit -2.0 at one seed) and the field no smoother
    (docs/results/medium_recovery.md, session 52)."""
    feature_eps: Annotated[float, Positive] | None = None
    """Adam's epsilon for the grid backends' features (triplane, voxel); None: the optimizer's
    (1e-15). With a tiny epsilon Adam moves a cell about as far for a gradient of 1e-7 as for one
    of 1e-4, so the many cells that the photos barely constrain (near the cameras, in front of the
    surfaces) wander as fast as the ones they pin. An epsilon near the typical gradient size slows
    only the weakly held cells (docs/results/medium_recovery.md, session 55)."""
    init_beta: Annotated[float, NonNegative] = 0.1
    """Initial extinction (1 / scene unit) everywhere; replaced by a dark-channel estimate when the
    pipeline initialises the medium from data."""
    init_light: tuple[float, float, float] = (0.7, 0.7, 0.7)
    """Initial medium light (RGB); replaced by the dark-channel airlight estimate when available."""
    init_feature_std: Annotated[float, NonNegative] = 0.1
    """Std of the grid backends' (triplane, voxel) random start features. The heads' last layers
    start near zero, so the start is uniform; but as they grow, whatever of this noise the
    gradient has not overwritten shows as spatial variation of the extinction. A zero start leaves
    the trained field as rough (room-uniform, session 52 of docs/results/medium_recovery.md)."""
    tv_weight: Annotated[float, NonNegative] = 0.0
    """Total-variation weight on grid features (keeps cells from drifting to extremes); 0 = off."""
    reference_scale: Annotated[tuple[float, float], NonNegative] = (1.0, 1.0)
    """``reference`` backend only (a diagnosis): multipliers on the true extinction and on the true
    light (clamped to [0, 1]). A what-if: do the hazy photos tell a denser, thinner, brighter or
    darker medium from the true one (docs/results/identifiability.md)?"""

    def check_values(self, prefix: str = "--pipeline.medium.") -> None:
        """The declared ranges, also for a config built in code rather than parsed."""
        check_numbers(self, prefix.removeprefix("--"))
        if tuple(self.reference_scale) != (1.0, 1.0) and self.backend != "reference":
            raise ConfigError(
                f"{prefix}reference-scale scales the generator's true medium; the {self.backend!r} "
                "backend has none",
                fix=f"add {prefix}backend reference, or leave {prefix}reference-scale at 1 1",
            )
        if math.hypot(*self.light_axis) < 1e-6:
            raise ConfigError(
                f"{prefix}light-axis {tuple(self.light_axis)} has no direction",
                fix=f"give {prefix}light-axis a non-zero vector, e.g. 0 0 1",
            )

    def setup(self, bounds: FieldBounds | None = None, **kwargs: Any) -> MediumField:
        if self.backend == "auto":
            raise ValueError("medium backend 'auto' is resolved by the pipeline's haze probe before setup")
        cls = REGISTRY.get("medium", self.backend)
        return cls(
            self, bounds if bounds is not None else FieldBounds(torch.zeros(3), torch.ones(3)), **kwargs
        )


@dataclass
class GaussianMediumValues:
    """A medium carried by the Gaussians, in physical units of the normalised frame."""

    beta: Tensor  # [N] extinction per Gaussian
    light: Tensor  # [N, 3] medium light per Gaussian
    background_beta: float
    """Extinction where no Gaussian covers a pixel."""
    background_light: Tensor  # [3]


class MediumField(nn.Module):
    """Base of all medium fields. Subclasses implement :meth:`forward`; everything a pipeline may
    ask of a medium is a hook declared here with the default a 3D field wants.

    ``is_field`` False means the medium is not a 3D field evaluated along rays (``none``, or
    ``gaussian-bound`` which renders through the rasterizer instead); ``has_medium`` False means
    there is no medium at all (plain 3DGS); ``renders_with_gaussians`` True means the medium lives
    on the scene's Gaussians (:meth:`attach`, :meth:`render_view`); ``recolours_light`` True means
    its light takes a per-channel factor (:meth:`recolour_light`) or one value
    (:meth:`flatten_light`); ``band_limits`` True means its
    features live on a grid that :meth:`set_band_limit` can low-pass (coarse-to-fine).
    """

    is_field: bool = True
    has_medium: bool = True
    renders_with_gaussians: bool = False
    recolours_light: bool = False
    band_limits: bool = False

    def __init__(self, config: MediumConfig, bounds: FieldBounds) -> None:
        super().__init__()
        self.config = config
        self.register_buffer("bounds_center", bounds.center.detach().float().clone())
        self.register_buffer("bounds_half", bounds.half_size.detach().float().clone())

    @property
    def bounds(self) -> FieldBounds:
        return FieldBounds(self.bounds_center, self.bounds_half)

    def forward(self, x: Tensor, dirs: Tensor) -> MediumSample:  # x, dirs: [P, 3]
        raise NotImplementedError

    def sample_rays(self, pts: Tensor, dirs: Tensor) -> MediumSample:
        """The field along R rays of K samples each: pts [R, K, 3], dirs [R, 3] unit (one per
        ray) -> beta [R, K], light [R, K, 3]. The march calls this; a field whose light depends
        on the direction alone overrides it to evaluate the light once per ray, not per sample."""
        R, K = pts.shape[:2]
        flat = self(pts.reshape(-1, 3), dirs[:, None, :].expand(-1, K, -1).reshape(-1, 3))
        return MediumSample(beta=flat.beta.reshape(R, K), light=flat.light.reshape(R, K, 3))

    def param_groups(self) -> dict[str, tuple[nn.Parameter, float]]:
        """Trainable tensors by name with learning rates (names prefixed ``medium.``)."""
        return {}

    def adam_eps(self) -> dict[str, float]:
        """Adam epsilon per parameter group where it differs from the optimizer's (by the names of
        :meth:`param_groups`)."""
        return {}

    def regularizer(self) -> Tensor | None:
        """An optional prior on the field's own parameters (e.g. TV on grids), already weighted."""
        return None

    @torch.no_grad()
    def initialize(self, beta: float, light: Tensor) -> None:  # noqa: B027 - optional
        """Set the field to a uniform extinction ``beta`` and light ``light`` [3] (data-driven init)."""

    def flatten_light(self, light: Tensor) -> None:
        """Give every point and direction the one light ``light`` [3] from now on (a run judged one
        light, at the freeze). Only where ``recolours_light`` (the same heads carry both)."""
        raise NotImplementedError(f"{type(self).__name__} cannot flatten its light")

    def recolour_light(self, gain: Tensor) -> None:
        """Multiply the medium's light by ``gain`` [3] per channel from now on (the light colour
        fit at the freeze, which the light's own parametrisation cannot take in one step). Only
        where ``recolours_light``."""
        raise NotImplementedError(f"{type(self).__name__} cannot recolour its light")

    def set_band_limit(self, sigma: float) -> None:
        """Low-pass the field's grid by a Gaussian of std ``sigma`` cells from now on (0: none).
        Only where ``band_limits``."""
        raise NotImplementedError(f"{type(self).__name__} has no grid to band-limit")

    def bind_scene(self, root: Path, transform: SceneTransform) -> None:  # noqa: B027 - optional hook
        """Read what the field needs from the dataset itself (``reference``: the generator's medium);
        ``root`` is the dataset folder, ``transform`` maps its world to the run's frame."""

    def attach(self, model: GaussianModel) -> None:  # noqa: B027 - optional hook
        """Bind to the scene's Gaussians once they exist (a medium living on them adds its attribute)."""

    def set_trainable(self, on: bool, model: GaussianModel) -> None:
        """Freeze or unfreeze everything the medium owns (Stage II freezes it), wherever it lives."""
        for p in self.parameters():
            p.requires_grad_(on)

    def render_view(
        self,
        compositor: MediumCompositor,
        camera: Cameras,
        depth: Tensor,
        alpha: Tensor,
        model: GaussianModel,
        rasterizer: Rasterizer,
    ) -> MediumRender:
        """T and S of one view given the clean render's depth and alpha [H, W, 1]: by default the
        compositor marches this field from the camera to the surface."""
        return compositor(self, camera, depth, alpha)

    def gaussian_values(self, model: GaussianModel) -> GaussianMediumValues | None:
        """The medium's values per Gaussian (for export), for a medium living on the Gaussians."""
        return None


DIR_OCTAVES = 3
"""Octaves of the direction encoding of the ``mlp`` light (sin / cos of 2^k pi v, k < 3)."""


def fourier_dim(octaves: int, dim: int = 3) -> int:
    """Width of :func:`fourier_encode` for ``dim`` input coordinates."""
    return dim * (1 + 2 * octaves)


DIR_ENCODING_DIM = fourier_dim(DIR_OCTAVES)
AXIAL_ENCODING_DIM = fourier_dim(DIR_OCTAVES, dim=1)


def fourier_encode(x: Tensor, octaves: int) -> Tensor:
    """[P, D] -> [P, D (1 + 2 K)]: x, then sin and cos of 2^k pi x for k < K (NeRF's positional
    encoding), octave-major. One encoding for the ``mlp`` light's directions and the ``fourier``
    field's box coordinates."""
    if octaves == 0:
        return x
    scaled = torch.cat([x * (math.pi * 2.0**k) for k in range(octaves)], dim=-1)  # [P, D K]
    return torch.cat([x, scaled.sin(), scaled.cos()], dim=-1)


def encode_direction(dirs: Tensor) -> Tensor:
    """Unit directions [P, 3] -> [P, DIR_ENCODING_DIM] for the ``mlp`` light."""
    return fourier_encode(dirs, DIR_OCTAVES)


class MediumHeads(nn.Module):
    """Two-layer heads from a feature vector to (beta, L); the global kappa lives here too."""

    def __init__(self, config: MediumConfig, in_dim: int) -> None:
        super().__init__()
        self.config = config
        h = config.hidden
        self.light_mode = config.light
        config.check_values()
        self.sh_degree = int(config.sh_degree)
        n_light = 3 * num_sh_bases(self.sh_degree) if self.light_mode == "sh" else 3
        dir_in = {"mlp": DIR_ENCODING_DIM, "axial": AXIAL_ENCODING_DIM}.get(self.light_mode, 0)
        self.beta_head = nn.Sequential(nn.Linear(in_dim, h), nn.ReLU(), nn.Linear(h, 1))
        self.light_space = config.light_space
        light_in = (3 if self.light_space == "smooth" else in_dim) + dir_in  # smooth: box coordinates
        self.light_head = nn.Sequential(nn.Linear(light_in, h), nn.ReLU(), nn.Linear(h, n_light))
        # a global light reads one learnt feature vector instead of the point's features. With the
        # ``mlp`` light it only adds a constant to the first layer's pre-activation (redundant with
        # its bias); it stays so every global mode keeps one parametrisation, since dropping it would
        # change the initial direction sensitivity and Adam's steps of the measured default
        self.light_feature = (
            nn.Parameter(torch.randn(in_dim) * 0.1) if self.light_space == "global" else None
        )  # [F]
        self.light_axis = (
            nn.Parameter(torch.tensor(config.light_axis, dtype=torch.float32))
            if self.light_mode == "axial"
            else None
        )  # [3], normalised where used
        self.log_kappa = nn.Parameter(torch.zeros(()))
        self.register_buffer("light_gain", torch.ones(3))  # [3] per-channel factor on the light
        self._recoloured = False  # light_gain read once, not at every call
        # [3] one light for every point and direction once set (:meth:`flatten`); negative: not set
        self.register_buffer("flat_light", torch.full((3,), -1.0))
        self._flat = False
        with torch.no_grad():  # near-uniform start: the last layers barely see the features
            for head in (self.beta_head, self.light_head):
                head[-1].weight.mul_(0.01)
        self.initialize(config.init_beta, torch.tensor(config.init_light))

    @torch.no_grad()
    def initialize(self, beta: float, light: Tensor) -> None:
        """Uniform start at ``beta`` and ``light``: the biases carry the values, kappa the scale."""
        for head in (self.beta_head, self.light_head):
            head[-1].bias.zero_()
        self.light_gain.fill_(1.0)
        self._recoloured = False
        self.flat_light.fill_(-1.0)
        self._flat = False
        # beta = kappa * softplus(0) = kappa * ln 2
        self.log_kappa.fill_(math.log(max(beta, 1e-8) / math.log(2.0)))
        logit = torch.logit(light.float().clamp(0.02, 0.98))
        bias = self.light_head[-1].bias
        if self.light_mode == "sh":
            # DC basis value is C0 = 0.28209479; eval_sh adds nothing else at zero coefficients
            bias.view(-1, 3)[0] = logit / 0.28209479177387814
        else:
            bias.copy_(logit)

    @property
    def kappa(self) -> Tensor:
        return self.log_kappa.exp()

    def _light_input(self, feat: Tensor, dirs: Tensor, coords: Tensor | None) -> Tensor:
        """The light head's input per point [P, *]: the field's features, the box coordinates or
        the global feature, with the encoded direction appended for the ``mlp`` light."""
        if self.light_space == "global":
            light_in = self.light_feature.to(feat)[None].expand(dirs.shape[0], -1)  # [P, F]
        elif self.light_space == "smooth":
            if coords is None:
                raise ValueError("a smooth medium light needs the points' box coordinates")
            light_in = coords.to(feat)  # [P, 3]
        else:
            light_in = feat
        if self.light_mode == "mlp":
            light_in = torch.cat([light_in, encode_direction(dirs.to(feat))], dim=-1)
        elif self.light_mode == "axial":
            axis = F.normalize(self.light_axis.to(feat), dim=0)  # [3]
            cosine = dirs.to(feat) @ axis  # [P]
            light_in = torch.cat([light_in, fourier_encode(cosine[:, None], DIR_OCTAVES)], dim=-1)
        return light_in

    @property
    def light_depends_on_position(self) -> bool:
        """False for a ``global`` light: a function of the direction alone, so a ray's samples share
        it (:meth:`MediumField.sample_rays` evaluates it once per ray)."""
        return self.light_space != "global"

    def extinction(self, feat: Tensor) -> Tensor:
        """feat [P, F] -> beta [P]."""
        return self.kappa * F.softplus(self.beta_head(feat)[..., 0])

    def light(self, feat: Tensor, dirs: Tensor, coords: Tensor | None = None) -> Tensor:
        """feat [P, F] (only its dtype is read for a ``global`` light, and P then may be any
        count matching dirs), dirs [P, 3] unit, coords [P, 3] (``smooth`` only) -> light [P, 3]."""
        if self._flat:
            return self.flat_light.to(feat)[None].expand(dirs.shape[0], -1)
        if self.light_space == "global" and self.light_mode in ("sh", "rgb"):
            # one input for every point: evaluate the head once
            raw = self.light_head(self.light_feature.to(feat))[None].expand(dirs.shape[0], -1)
        else:
            raw = self.light_head(self._light_input(feat, dirs, coords))  # [P, n_light]
        if self.light_mode == "sh":
            coeffs = raw.unflatten(-1, (-1, 3))  # [P, K, 3] (unflatten: P may be 0)
            raw = eval_sh(self.sh_degree, coeffs, dirs)  # [P, 3]
        light = torch.sigmoid(raw)
        return light * self.light_gain.to(light) if self._recoloured else light

    @torch.no_grad()
    def recolour(self, gain: Tensor) -> None:
        """Multiply the light by ``gain`` [3] from now on (on top of any earlier gain)."""
        self.light_gain.mul_(gain.to(self.light_gain))
        self._recoloured = True

    @torch.no_grad()
    def flatten(self, light: Tensor) -> None:
        """Give every point and direction the light ``light`` [3] from now on."""
        self.flat_light.copy_(light.to(self.flat_light).clamp(0.0, 1.0))
        self._flat = True

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:  # noqa: ANN001
        # checkpoints from before the light colour fit: the light as the head gives it
        state_dict.setdefault(prefix + "light_gain", torch.ones_like(self.light_gain))
        state_dict.setdefault(prefix + "flat_light", torch.full_like(self.flat_light, -1.0))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self._recoloured = bool((self.light_gain != 1.0).any())
        self._flat = bool((self.flat_light >= 0.0).all())

    def forward(self, feat: Tensor, dirs: Tensor, coords: Tensor | None = None) -> MediumSample:
        """feat: [P, F], dirs: [P, 3] unit, coords: [P, 3] box coordinates (``smooth`` light only)
        -> beta [P], light [P, 3]."""
        return MediumSample(beta=self.extinction(feat), light=self.light(feat, dirs, coords))
