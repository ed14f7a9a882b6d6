"""Registered medium field backends (kind ``medium``): encoders from world points to features.

Every backend shares :class:`~components.medium.base.MediumHeads`, so the ablations in the paper
(tri-plane vs voxel vs coordinate MLP vs Fourier MLP vs constant) change the spatial encoder only.
Grid backends share one feature budget: the voxel grid has as many cells x channels as the three
planes together, so the comparison is about the factorisation, not the parameter count.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from components.medium.band_limit import blur_grid
from components.medium.base import (
    FieldBounds,
    MediumConfig,
    MediumField,
    MediumHeads,
    MediumSample,
    fourier_dim,
    fourier_encode,
)
from tridehaze_plugin.registry import register

GRID_INIT_STD = 0.1
"""Std of the constant field's random start feature (the grids take ``init_feature_std``)."""


class HeadedField(MediumField):
    """A field made of an encoder ``encode(x) -> [P, F]`` followed by the shared heads."""

    feature_dim: int
    recolours_light = True

    def _build_heads(self) -> None:
        self.heads = MediumHeads(self.config, self.feature_dim)

    def encode(self, x: Tensor) -> Tensor:  # x: [P, 3] world -> [P, F]
        raise NotImplementedError

    def forward(self, x: Tensor, dirs: Tensor) -> MediumSample:
        coords = self.bounds.normalize(x) if self.heads.light_space == "smooth" else None  # [P, 3]
        return self.heads(self.encode(x), dirs, coords)

    def sample_rays(self, pts: Tensor, dirs: Tensor) -> MediumSample:
        if self.heads.light_depends_on_position:
            return super().sample_rays(pts, dirs)
        R, K = pts.shape[:2]
        feat = self.encode(pts.reshape(-1, 3))  # [R K, F]
        beta = self.heads.extinction(feat).reshape(R, K)
        light = self.heads.light(feat, dirs)  # [R, 3]: the ray's samples share it
        return MediumSample(beta=beta, light=light[:, None, :].expand(-1, K, -1))

    def param_groups(self) -> dict[str, tuple[nn.Parameter, float]]:
        """One entry per parameter (one optimizer each); log(kappa) and grid features may have their
        own lr."""
        return {f"medium.{name}": (p, self._lr(name)) for name, p in self.named_parameters()}

    def _lr(self, name: str) -> float:
        return self.config.kappa_lr if name.endswith("log_kappa") else self.config.lr

    @torch.no_grad()
    def initialize(self, beta: float, light: Tensor) -> None:
        """Uniform start; the heads' near-zero last layers hide the random feature variation."""
        self.heads.initialize(beta, light)

    def recolour_light(self, gain: Tensor) -> None:
        self.heads.recolour(gain)

    def flatten_light(self, light: Tensor) -> None:
        self.heads.flatten(light)


class GridField(HeadedField):
    """A headed field whose features live on a grid (``features`` [B, C, *S]), read through an
    optional Gaussian low-pass whose width the pipeline anneals (coarse-to-fine)."""

    band_limits = True
    features: nn.Parameter

    def _register_band_limit(self) -> None:
        # a buffer, so a checkpoint resumes at the blur it was saved with
        self.register_buffer("band_sigma", torch.zeros(()))

    def set_band_limit(self, sigma: float) -> None:
        self.band_sigma.fill_(max(float(sigma), 0.0))

    def _lr(self, name: str) -> float:
        if name == "features" and self.config.feature_lr is not None:
            return self.config.feature_lr
        return super()._lr(name)

    def adam_eps(self) -> dict[str, float]:
        eps = self.config.feature_eps
        return {} if eps is None else {"medium.features": eps}

    def grid(self) -> Tensor:
        """The features as the lookup sees them: low-passed while a band limit is set."""
        return blur_grid(self.features, float(self.band_sigma))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:  # noqa: ANN001
        # checkpoints from before the band limit: none
        state_dict.setdefault(prefix + "band_sigma", torch.zeros(()))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


def _tv(grid: Tensor, dims: tuple[int, ...]) -> Tensor:
    """Mean squared finite difference along ``dims`` (smooth L2 TV, as in K-Planes / Plenoxels)."""
    return torch.stack([(grid.diff(dim=d) ** 2).mean() for d in dims]).sum()


class TriplaneField(GridField):
    """Three axis-aligned feature planes (xy, xz, yz), bilinear lookup, features concatenated."""

    def __init__(self, config: MediumConfig, bounds: FieldBounds) -> None:
        super().__init__(config, bounds)
        r, c = int(config.resolution), int(config.channels)
        self.features = nn.Parameter(torch.randn(3, c, r, r) * config.init_feature_std)  # [3, C, R, R]
        self.feature_dim = 3 * c
        self._build_heads()
        self._register_band_limit()

    def encode(self, x: Tensor) -> Tensor:
        n = self.bounds.normalize(x)  # [P, 3] in [-1, 1]
        # grid_sample reads (u, v) = (width, height): plane i is indexed by the coordinate pair below
        uv = torch.stack([n[:, [0, 1]], n[:, [0, 2]], n[:, [1, 2]]])  # [3, P, 2]
        feat = F.grid_sample(self.grid(), uv.unsqueeze(1), mode="bilinear", align_corners=True)
        return feat[:, :, 0].permute(2, 0, 1).reshape(-1, self.feature_dim)  # [3, C, 1, P] -> [P, 3C]

    def regularizer(self) -> Tensor | None:
        w = self.config.tv_weight
        return w * _tv(self.features, (2, 3)) if w > 0 else None


class VoxelField(GridField):
    """One dense 3D grid with the tri-plane's feature budget, trilinear lookup.

    Side ``G = round((3 R^2)^(1/3))`` at the same C channels (23^3 x 8 for R=64, C=8): the grid
    keeps the spatial resolution the budget allows, so its features are C wide (not 3C).
    """

    def __init__(self, config: MediumConfig, bounds: FieldBounds) -> None:
        super().__init__(config, bounds)
        r, c = int(config.resolution), int(config.channels)
        g = max(2, round((3 * r * r) ** (1.0 / 3.0)))
        self.features = nn.Parameter(torch.randn(1, c, g, g, g) * config.init_feature_std)  # [1, C, G, G, G]
        self.feature_dim = c
        self._build_heads()
        self._register_band_limit()

    def encode(self, x: Tensor) -> Tensor:
        n = self.bounds.normalize(x)  # [P, 3]; grid_sample's (x, y, z) index (W, H, D)
        feat = F.grid_sample(self.grid(), n.view(1, 1, 1, -1, 3), mode="bilinear", align_corners=True)
        return feat[0, :, 0, 0].t()  # [1, C, 1, 1, P] -> [P, C]

    def regularizer(self) -> Tensor | None:
        w = self.config.tv_weight
        return w * _tv(self.features, (2, 3, 4)) if w > 0 else None


def _coord_mlp(in_dim: int, hidden: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU())


class MLPField(HeadedField):
    """Coordinate MLP on the normalised position: smooth by construction, no grid."""

    def __init__(self, config: MediumConfig, bounds: FieldBounds) -> None:
        super().__init__(config, bounds)
        self.encoder = _coord_mlp(3, int(config.hidden))
        self.feature_dim = int(config.hidden)
        self._build_heads()

    def encode(self, x: Tensor) -> Tensor:
        return self.encoder(self.bounds.normalize(x))  # [P, hidden]


class FourierField(HeadedField):
    """Coordinate MLP on ``[x, sin(2^k pi x), cos(2^k pi x)]``, k < num_frequencies (NeRF-style)."""

    def __init__(self, config: MediumConfig, bounds: FieldBounds) -> None:
        super().__init__(config, bounds)
        self.num_frequencies = int(config.num_frequencies)
        self.encoder = _coord_mlp(fourier_dim(self.num_frequencies), int(config.hidden))
        self.feature_dim = int(config.hidden)
        self._build_heads()

    def encode(self, x: Tensor) -> Tensor:
        return self.encoder(fourier_encode(self.bounds.normalize(x), self.num_frequencies))  # [P, hidden]


class ConstantField(HeadedField):
    """One global feature vector: a homogeneous medium (global beta, light varies with v only)."""

    def __init__(self, config: MediumConfig, bounds: FieldBounds) -> None:
        super().__init__(config, bounds)
        self.feature_dim = 3 * int(config.channels)
        self.features = nn.Parameter(torch.randn(self.feature_dim) * GRID_INIT_STD)  # [F]
        self._build_heads()

    def encode(self, x: Tensor) -> Tensor:
        return self.features.to(x).expand(x.shape[0], -1)  # [P, F]


class NoMedium(MediumField):
    """No medium: zero extinction and zero light (plain 3DGS)."""

    is_field = False
    has_medium = False

    def forward(self, x: Tensor, dirs: Tensor) -> MediumSample:
        return MediumSample(beta=x.new_zeros(x.shape[0]), light=x.new_zeros(x.shape[0], 3))


register("medium", "triplane", TriplaneField)
register("medium", "voxel", VoxelField)
register("medium", "mlp", MLPField)
register("medium", "fourier", FourierField)
register("medium", "constant", ConstantField)
register("medium", "none", NoMedium)
