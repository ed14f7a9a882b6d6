"""The 3D Gaussian scene model (3DGS parameterisation) and its config.

Parameters are stored *unconstrained* (log-scales, opacity logits, raw quaternions) in one
``nn.ParameterDict`` so that a densification strategy can replace any of them by name and the
trainer can build its optimizer from :meth:`GaussianModel.param_groups` without knowing them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any

import torch
from torch import Tensor, nn

from components.gaussians.knn import knn_distances
from components.gaussians.sh import MAX_SH_DEGREE, num_sh_bases, rgb_to_sh
from tridehaze_plugin.config import ComponentConfig, NonNegative, Positive, Range, RegistryChoice
from tridehaze_plugin.registry import REGISTRY, register

if TYPE_CHECKING:
    from components.data.cameras import Cameras
    from components.rasterizers.base import RasterizeOutput, Rasterizer

PARAM_NAMES: tuple[str, ...] = ("means", "quats", "log_scales", "opacity_logits", "sh0", "shN")
"""Every parameter of a :class:`GaussianModel`, in a fixed order (first dim is always N)."""
GEOMETRY_NAMES: tuple[str, ...] = ("means", "quats", "log_scales", "opacity_logits")
"""The parameters that place and shape each Gaussian; :meth:`GaussianModel.set_geometry_trainable`
holds them while the colours go on learning."""
COLOUR_NAMES: tuple[str, ...] = ("sh0", "shN")
"""The colour parameters; :meth:`GaussianModel.set_colour_trainable` holds them."""


@dataclass
class GaussianModelConfig(ComponentConfig):
    """How the Gaussians are initialised and how fast each of their parameters learns."""

    backend: Annotated[str, RegistryChoice("gaussian_model")] = "3dgs"
    """Gaussian model implementation (registry name)."""
    sh_degree: Annotated[int, Range(0, MAX_SH_DEGREE)] = 3
    """Highest spherical-harmonics degree of the view-dependent colour (0..3)."""
    sh_degree_interval: int = 1000
    """One more SH band becomes active every this many steps (degree 0 at step 0)."""
    init_opacity: Annotated[float, Range(0.0, 1.0, lo_open=True)] = 0.1
    """Opacity of every Gaussian at initialisation."""
    init_scale_mult: Annotated[float, Positive] = 1.0
    """Multiplier on the initial scale (RMS distance to the 3 nearest seed points)."""
    random_init_points: int = 20000
    """Number of random Gaussians when the dataset has no seed point cloud."""
    random_init_extent: float = 1.5
    """Random Gaussians fill a cube of half-size ``random_init_extent * scene_extent``."""
    max_init_points: int | None = None
    """Randomly subsample the seed cloud to at most this many points (None: keep all)."""
    means_lr: Annotated[float, NonNegative] = 1.6e-4
    """Learning rate of the centres, multiplied by the scene extent."""
    scales_lr: Annotated[float, NonNegative] = 5e-3
    """Learning rate of the log-scales."""
    quats_lr: Annotated[float, NonNegative] = 1e-3
    """Learning rate of the quaternions."""
    opacities_lr: Annotated[float, NonNegative] = 5e-2
    """Learning rate of the opacity logits."""
    sh0_lr: Annotated[float, NonNegative] = 2.5e-3
    """Learning rate of the DC colour coefficients."""
    shN_lr: Annotated[float | None, NonNegative] = None
    """Learning rate of the higher SH bands (None: ``sh0_lr / 20``)."""

    def setup(  # type: ignore[override]
        self,
        points: Tensor | None = None,
        colors: Tensor | None = None,
        scene_extent: float = 1.0,
        **kwargs: Any,
    ) -> GaussianModel:
        """Build the model from a seed cloud ``points [M, 3]`` / ``colors [M, 3]`` (or randomly)."""
        cls = REGISTRY.get("gaussian_model", self.backend)
        return cls.from_points(self, points, colors, scene_extent, **kwargs)


class GaussianModel(nn.Module):
    """N anisotropic 3D Gaussians with SH colour (the 3DGS model).

    Registered as a class under kind ``"gaussian_model"``; :meth:`GaussianModelConfig.setup` calls
    its ``from_points(config, points, colors, scene_extent)``, which other models must provide too.
    """

    def __init__(
        self, config: GaussianModelConfig, params: dict[str, Tensor], scene_extent: float = 1.0
    ) -> None:
        super().__init__()
        self.config = config
        self.scene_extent = float(scene_extent)
        missing = set(PARAM_NAMES) - set(params)
        if missing:
            raise ValueError(f"missing Gaussian parameters: {sorted(missing)}")
        self.params = nn.ParameterDict({k: nn.Parameter(params[k].contiguous()) for k in PARAM_NAMES})
        self.extra_lrs: dict[str, float] = {}
        """Learning rates of per-Gaussian attributes added by other components (see add_attribute)."""

    # ---------------------------------------------------------------- construction

    @classmethod
    def from_points(
        cls,
        config: GaussianModelConfig,
        points: Tensor | None,
        colors: Tensor | None,
        scene_extent: float = 1.0,
        generator: torch.Generator | None = None,
    ) -> GaussianModel:
        """Initialise from a seed cloud (3DGS recipe) or, without one, uniformly at random."""
        if points is None or len(points) == 0:
            n = config.random_init_points
            half = config.random_init_extent * scene_extent
            points = (torch.rand(n, 3, generator=generator) * 2.0 - 1.0) * half
            colors = torch.rand(n, 3, generator=generator)
        else:
            points = torch.as_tensor(points).detach().to(torch.float32)
            colors = torch.as_tensor(colors) if colors is not None else None
            if points.dim() != 2 or points.shape[1] != 3:
                raise ValueError(f"points must be [M, 3], got {list(points.shape)}")
            if config.max_init_points is not None and points.shape[0] > config.max_init_points:
                idx = torch.randperm(points.shape[0], generator=generator)[: config.max_init_points]
                points = points[idx.to(points.device)]
                colors = colors[idx.to(colors.device)] if colors is not None else None
            if colors is None:
                colors = torch.full_like(points, 0.5)
            elif colors.dtype == torch.uint8:
                colors = colors.to(points.device, torch.float32) / 255.0
            colors = colors.to(points.device, torch.float32).clamp(0.0, 1.0)
        n = points.shape[0]
        dist = knn_distances(points, k=3)  # [N, 3]
        if n > 1:
            rms = dist.square().mean(dim=-1).sqrt()
        else:
            rms = torch.full((n,), 0.01 * scene_extent, device=points.device)
        rms = rms.clamp_min(1e-7)  # duplicate points must not give log(0)
        log_scales = torch.log(rms * config.init_scale_mult)[:, None].repeat(1, 3)
        k = num_sh_bases(config.sh_degree)
        params = {
            "means": points.clone(),
            "quats": torch.tensor([1.0, 0.0, 0.0, 0.0], device=points.device).repeat(n, 1),
            "log_scales": log_scales,
            "opacity_logits": torch.full((n,), logit(config.init_opacity), device=points.device),
            "sh0": rgb_to_sh(colors)[:, None, :],
            "shN": torch.zeros(n, k - 1, 3, device=points.device),
        }
        return cls(config, params, scene_extent)

    # ---------------------------------------------------------------- views of the parameters

    @property
    def means(self) -> Tensor:
        return self.params["means"]  # [N, 3]

    @property
    def quats(self) -> Tensor:
        return self.params["quats"]  # [N, 4] (w, x, y, z), unnormalised

    @property
    def log_scales(self) -> Tensor:
        return self.params["log_scales"]  # [N, 3]

    @property
    def opacity_logits(self) -> Tensor:
        return self.params["opacity_logits"]  # [N]

    @property
    def sh0(self) -> Tensor:
        return self.params["sh0"]  # [N, 1, 3]

    @property
    def shN(self) -> Tensor:  # noqa: N802 - conventional name
        return self.params["shN"]  # [N, K-1, 3]

    @property
    def scales(self) -> Tensor:
        return torch.exp(self.log_scales)  # [N, 3]

    @property
    def opacities(self) -> Tensor:
        return torch.sigmoid(self.opacity_logits)  # [N]

    @property
    def normalized_quats(self) -> Tensor:
        return self.quats / self.quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)  # [N, 4]

    @property
    def sh_coeffs(self) -> Tensor:
        return torch.cat([self.sh0, self.shN], dim=1)  # [N, K, 3]

    @property
    def num_gaussians(self) -> int:
        return self.means.shape[0]

    def active_sh_degree(self, step: int) -> int:
        """SH degree in use at a training step: one more band every ``sh_degree_interval`` steps."""
        interval = max(1, self.config.sh_degree_interval)
        return min(self.config.sh_degree, max(0, step) // interval)

    # ---------------------------------------------------------------- training helpers

    @property
    def param_names(self) -> tuple[str, ...]:
        """The core parameters then any added attributes; all share the first dimension N."""
        return PARAM_NAMES + tuple(self.extra_lrs)

    def add_attribute(self, name: str, values: Tensor, lr: float) -> None:
        """Carry an extra per-Gaussian tensor ``values [N, ...]`` (e.g. a Gaussian-bound medium).

        It is optimised with ``lr`` and cloned, split and pruned with the Gaussians, so a component
        that needs per-Gaussian state never edits the model's own parameters.
        """
        if name in self.params:
            raise KeyError(f"Gaussian attribute {name!r} already exists")
        if values.shape[0] != self.num_gaussians:
            raise ValueError(f"attribute {name!r} needs {self.num_gaussians} rows, got {values.shape[0]}")
        self.params[name] = nn.Parameter(values.detach().to(self.means).contiguous())
        self.extra_lrs[name] = float(lr)

    def attribute(self, name: str) -> Tensor:
        return self.params[name]

    def set_geometry_trainable(self, on: bool) -> None:
        """Hold or free the geometry (:data:`GEOMETRY_NAMES`). Held parameters get no gradient, so
        Adam leaves them as they are (no momentum step) and densification sees no statistics."""
        for name in GEOMETRY_NAMES:
            self.params[name].requires_grad_(on)

    def set_colour_trainable(self, on: bool) -> None:
        """Hold or free the colours (:data:`COLOUR_NAMES`), as :meth:`set_geometry_trainable`."""
        for name in COLOUR_NAMES:
            self.params[name].requires_grad_(on)

    def param_groups(self) -> dict[str, tuple[nn.Parameter, float]]:
        """Every parameter with its learning rate, so the trainer builds optimizers generically."""
        cfg = self.config
        lrs = {
            "means": cfg.means_lr * self.scene_extent,
            "quats": cfg.quats_lr,
            "log_scales": cfg.scales_lr,
            "opacity_logits": cfg.opacities_lr,
            "sh0": cfg.sh0_lr,
            "shN": cfg.shN_lr if cfg.shN_lr is not None else cfg.sh0_lr / 20.0,
        }
        lrs.update(self.extra_lrs)
        return {name: (self.params[name], lrs[name]) for name in self.param_names}

    def replace_params(self, new: dict[str, Tensor]) -> None:
        """Swap parameters by name (e.g. after densification); all must keep one common N."""
        for name, value in new.items():
            if name not in self.param_names:
                raise KeyError(f"unknown Gaussian parameter {name!r}")
            self.params[name] = value if isinstance(value, nn.Parameter) else nn.Parameter(value)
        sizes = {self.params[k].shape[0] for k in self.param_names}
        if len(sizes) != 1:
            raise ValueError(f"Gaussian parameters disagree on N: {sizes}")

    def _load_from_state_dict(
        self, state_dict: dict[str, Any], prefix: str, *args: Any, **kwargs: Any
    ) -> None:
        # checkpoints saved after densification hold a different N: resize before copying, once the
        # stored shapes are known to agree with each other and with this model's per-Gaussian shapes
        stored = {
            n: state_dict[f"{prefix}params.{n}"]
            for n in self.param_names
            if f"{prefix}params.{n}" in state_dict
        }
        counts = {v.shape[0] if v.dim() else None for v in stored.values()}
        wrong = [n for n, v in stored.items() if v.dim() == 0 or v.shape[1:] != self.params[n].shape[1:]]
        if wrong or len(counts) > 1:
            shapes = ", ".join(f"{n} {tuple(v.shape)}" for n, v in stored.items())
            raise RuntimeError(f"stored Gaussian parameters do not fit this model: {shapes}")
        resized = {
            n: torch.empty_like(v, device=self.params[n].device)
            for n, v in stored.items()
            if v.shape != self.params[n].shape
        }
        if resized:
            self.replace_params(resized)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def render_attribute(self, rasterizer: Rasterizer, cameras: Cameras, name: str) -> Tensor:
        """Alpha-blend the per-Gaussian attribute ``name`` [N, D] like a colour, with the geometry of
        :meth:`render` and a zero background: [C, H, W, D]."""
        return self.render_values(rasterizer, cameras, self.attribute(name))

    def render_values(self, rasterizer: Rasterizer, cameras: Cameras, attr: Tensor) -> Tensor:
        """Alpha-blend per-Gaussian values ``attr`` [N, D] (differentiable) like a colour, with the
        geometry of :meth:`render` and a zero background: [C, H, W, D]."""
        return rasterizer.rasterize(
            self.means, self.quats, self.scales, self.opacities, attr,
            cameras.viewmats().to(attr), cameras.Ks().to(attr), int(cameras.width[0]), int(cameras.height[0]),
            background=torch.zeros(attr.shape[-1], device=attr.device),
        ).rgb  # fmt: skip

    def render(
        self,
        rasterizer: Rasterizer,
        cameras: Cameras,
        step: int,
        background: Tensor | None = None,
    ) -> RasterizeOutput:
        """Render all ``cameras`` (they must share one image size) at the SH degree of ``step``."""
        widths, heights = cameras.width.unique(), cameras.height.unique()
        if widths.numel() != 1 or heights.numel() != 1:
            raise ValueError("render() needs cameras of one size; rasterize each size separately")
        dtype = self.means.dtype
        return rasterizer.rasterize(
            self.means,
            self.quats,
            self.scales,
            self.opacities,
            self.sh_coeffs,
            cameras.viewmats().to(self.means.device, dtype),
            cameras.Ks().to(self.means.device, dtype),
            int(widths[0]),
            int(heights[0]),
            background=background,
            sh_degree=self.active_sh_degree(step),
        )


def logit(p: float) -> float:
    """Inverse sigmoid of a probability, clamped away from 0 and 1 so it stays finite."""
    p = min(max(p, 1e-6), 1.0 - 1e-6)
    return math.log(p / (1.0 - p))


register("gaussian_model", "3dgs", GaussianModel)
