"""Medium field backends: shapes, ranges, uniform init, gradients, clamping, light modes, budgets."""

from __future__ import annotations

import math

import pytest
import torch
from torch.nn import functional as F

import components.medium  # noqa: F401  (registers the backends)
from components.medium.base import (
    DIR_ENCODING_DIM,
    DIR_OCTAVES,
    FieldBounds,
    MediumConfig,
    MediumField,
    encode_direction,
    fourier_dim,
    fourier_encode,
)
from components.medium.fields import TriplaneField, VoxelField
from tridehaze_plugin.errors import ConfigError
from tridehaze_plugin.registry import REGISTRY

BACKENDS = ["triplane", "voxel", "mlp", "fourier", "constant", "none"]
FIELDS = [b for b in BACKENDS if b != "none"]
BOUNDS = FieldBounds(torch.tensor([1.0, -2.0, 0.5]), torch.tensor([2.0, 1.0, 3.0]))
COLOUR = torch.tensor([0.8, 0.6, 0.4])


def _make(backend: str, device: torch.device, **kw) -> MediumField:
    torch.manual_seed(0)  # built on the cpu, then moved: the same initial values on every device
    return MediumConfig(backend=backend, **kw).setup(BOUNDS).to(device)


def _points(
    device: torch.device, n: int = 512, spread: float = 1.0, seed: int = 1
) -> tuple[torch.Tensor, torch.Tensor]:
    """Random world points in (spread x) the box and random unit directions (drawn on the cpu)."""
    g = torch.Generator().manual_seed(seed)
    u = (torch.rand(n, 3, generator=g) * 2 - 1) * spread
    x = BOUNDS.center + u * BOUNDS.half_size  # [n, 3]
    d = F.normalize(torch.randn(n, 3, generator=g), dim=-1)  # [n, 3]
    return x.to(device), d.to(device)


def _perturb_heads(field: MediumField, scale: float = 1.0) -> None:
    """Undo the near-zero init of the last layers so spatial / directional variation shows."""
    with torch.no_grad():
        for head in (field.heads.beta_head, field.heads.light_head):
            head[-1].weight.normal_(0.0, scale)


@pytest.mark.parametrize("backend", BACKENDS)
def test_registry_builds_each_backend(device, backend: str) -> None:
    field = MediumConfig(backend=backend).setup(BOUNDS).to(device)
    assert isinstance(field, REGISTRY.get("medium", backend))
    assert isinstance(field, MediumField)
    assert field.is_field == field.has_medium == (backend != "none")


@pytest.mark.parametrize("light", ["sh", "rgb", "mlp"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_shapes_and_ranges(device, backend: str, light: str) -> None:
    field = _make(backend, device, light=light)
    if field.has_medium:
        _perturb_heads(field, 0.5)  # exercise the non-trivial range, not only the uniform init
    x, d = _points(device, 300, spread=1.5)
    s = field(x, d)
    assert s.beta.shape == (300,) and s.light.shape == (300, 3)
    assert s.beta.dtype == s.light.dtype == torch.float32
    assert torch.isfinite(s.beta).all() and torch.isfinite(s.light).all()
    assert (s.beta >= 0).all()
    assert (s.light >= 0).all() and (s.light <= 1).all()
    empty = field(x[:0], d[:0])
    assert empty.beta.shape == (0,) and empty.light.shape == (0, 3)


def test_none_is_zero_and_parameter_free(device) -> None:
    field = _make("none", device)
    x, d = _points(device, 64)
    s = field(x, d)
    assert (s.beta == 0).all() and (s.light == 0).all()
    assert len(list(field.parameters())) == 0
    assert field.param_groups() == {} and field.regularizer() is None


@pytest.mark.parametrize("light", ["sh", "rgb", "mlp"])
@pytest.mark.parametrize("backend", FIELDS)
def test_initialize_is_uniform(device, backend: str, light: str) -> None:
    """Last layers start ~0.01-scaled, so the random features leave < 1e-3 of variation."""
    field = _make(backend, device, light=light)
    field.initialize(0.3, COLOUR.to(device))
    x, d = _points(device, 1000, spread=1.2)
    s = field(x, d)
    torch.testing.assert_close(s.beta, torch.full_like(s.beta, 0.3), atol=1e-3, rtol=0)
    torch.testing.assert_close(s.light, COLOUR.to(device).expand_as(s.light), atol=1e-3, rtol=0)
    # the config's init is applied at construction too (one 0.01 scaling only)
    fresh = _make(backend, device, light=light, init_beta=0.3, init_light=(0.8, 0.6, 0.4))(x, d)
    torch.testing.assert_close(fresh.beta, torch.full_like(s.beta, 0.3), atol=1e-3, rtol=0)
    torch.testing.assert_close(fresh.light, COLOUR.to(device).expand_as(s.light), atol=1e-3, rtol=0)


@pytest.mark.parametrize("backend", FIELDS)
def test_gradients_reach_every_parameter(device, backend: str) -> None:
    field = _make(backend, device, tv_weight=0.0)
    x, d = _points(device, 512)
    s = field(x, d)
    (s.beta.sum() + (s.light * torch.tensor([1.0, -2.0, 3.0], device=device)).sum()).backward()
    for name, p in field.named_parameters():
        assert p.grad is not None, name
        assert torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, name


@pytest.mark.parametrize("backend", FIELDS)
def test_param_groups_cover_every_parameter(device, backend: str) -> None:
    cfg = dict(lr=3e-3, kappa_lr=7e-4)
    field = _make(backend, device, **cfg)
    groups = field.param_groups()
    params = dict(field.named_parameters())
    assert set(groups) == {f"medium.{n}" for n in params}
    for name, (p, lr) in groups.items():
        assert isinstance(p, torch.nn.Parameter)
        assert lr == (cfg["kappa_lr"] if name == "medium.heads.log_kappa" else cfg["lr"])
    assert groups["medium.heads.log_kappa"][0] is field.heads.log_kappa


@pytest.mark.parametrize("backend", BACKENDS)
def test_outside_points_clamp_onto_the_box(device, backend: str) -> None:
    field = _make(backend, device)
    if field.has_medium:
        _perturb_heads(field, 0.5)
    x, d = _points(device, 256, spread=50.0)  # almost all far outside
    assert (~BOUNDS.inside(x)).float().mean() > 0.9
    c, h = BOUNDS.center.to(device), BOUNDS.half_size.to(device)
    projected = c + ((x - c) / h).clamp(-1, 1) * h
    far, near = field(x, d), field(projected, d)
    assert torch.isfinite(far.beta).all() and torch.isfinite(far.light).all()
    torch.testing.assert_close(far.beta, near.beta, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(far.light, near.light, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("backend", FIELDS)
def test_rgb_light_ignores_direction(device, backend: str) -> None:
    field = _make(backend, device, light="rgb")
    _perturb_heads(field)
    x, d = _points(device, 128)
    torch.testing.assert_close(field(x, d).light, field(x, -d.roll(1, dims=-1)).light)


@pytest.mark.parametrize("backend", FIELDS)
def test_sh_light_depends_on_direction(device, backend: str) -> None:
    field = _make(backend, device, light="sh", sh_degree=1)
    x, d = _points(device, 128)
    # near-zero band-1 coefficients at init: almost isotropic
    assert (field(x, d).light - field(x, -d).light).abs().max() < 1e-2
    _perturb_heads(field)
    assert (field(x, d).light - field(x, -d).light).abs().max() > 0.05


@pytest.mark.parametrize("backend", ["triplane", "voxel", "mlp", "fourier"])
def test_global_light_varies_with_direction_only(device, backend: str) -> None:
    """``light_space global``: one light for every point (per direction); the extinction stays spatial."""
    field = _make(backend, device, light_space="global", sh_degree=1)
    _perturb_heads(field)
    x, _ = _points(device, 256)
    d = F.normalize(torch.tensor([0.3, -0.2, 1.0], device=device), dim=0).expand_as(x)  # [256, 3]
    s = field(x, d)
    torch.testing.assert_close(s.light, s.light[:1].expand_as(s.light))
    assert s.beta.std() > 1e-3
    assert (field(x, -d).light - s.light).abs().max() > 0.02  # untrained: < 1e-2 (above)
    s.light.sum().backward()
    assert field.heads.light_feature.grad is not None and field.heads.light_feature.grad.abs().sum() > 0
    spatial = _make(backend, device, sh_degree=1)
    _perturb_heads(spatial)
    assert spatial.heads.light_feature is None
    assert spatial(x, d).light.std(0).max() > 1e-3  # the default field light does vary in space


@pytest.mark.parametrize("backend", ["triplane", "mlp", "constant"])
def test_smooth_light_reads_the_position_not_the_features(device, backend: str) -> None:
    """``light_space smooth``: the light is a function of the box coordinates and the direction."""
    field = _make(backend, device, light_space="smooth", sh_degree=1)
    _perturb_heads(field)
    x, _ = _points(device, 256)
    d = torch.tensor([0.0, 0.0, 1.0], device=device).expand_as(x)
    s = field(x, d)
    assert s.light.std(0).max() > 1e-3  # varies in space, even on the constant field
    with torch.no_grad():  # move every parameter but the light head's: the light must not change
        for name, p in field.named_parameters():
            if not name.startswith("heads.light_head"):
                p.add_(torch.randn_like(p))
    moved = field(x, d)
    assert (moved.beta - s.beta).abs().max() > 1e-3
    torch.testing.assert_close(moved.light, s.light)


def _fit_light(field: MediumField, x: torch.Tensor, d: torch.Tensor, target: torch.Tensor) -> float:
    """Final squared error of the field's light after 200 Adam steps towards ``target`` [P, 3]."""
    opt = torch.optim.Adam(field.parameters(), lr=1e-2)
    for _ in range(200):
        opt.zero_grad()
        loss = (field(x, d).light - target).square().mean()
        loss.backward()
        opt.step()
    return loss.item()


def test_mlp_light_can_be_sharper_than_sh1(device) -> None:
    """``light mlp`` (on a global light, which cannot fit each point apart): a near-uniform start,
    then a glow around one direction that SH order 1 cannot follow, fitted in 200 steps."""
    field = _make("constant", device, light="mlp", light_space="global", hidden=32)
    x, d = _points(device, 512)
    s0 = field(x, d).light
    assert (s0 - s0.mean(0)).abs().max() < 2e-2  # near-uniform start
    sun = F.normalize(torch.tensor([1.0, 0.5, 0.2], device=device), dim=0)
    glow = ((d @ sun).clamp_min(0.0) ** 16)[:, None]  # [P, 1]: a lobe of about 25 degrees
    target = 0.4 + 0.5 * glow
    sh1 = _make("constant", device, light="sh", sh_degree=1, light_space="global", hidden=32)
    assert _fit_light(field, x, d, target) < 0.5 * _fit_light(sh1, x, d, target)


def test_axial_light_depends_on_the_angle_to_its_axis_only(device) -> None:
    """``light axial``: directions at the same angle to the axis get the same light, other angles
    another; the axis itself learns (it gets a gradient), and it starts where the config says."""
    axis = F.normalize(torch.tensor([0.3, -0.9, 0.3]), dim=0)
    field = _make("constant", device, light="axial", light_space="global", light_axis=tuple(axis.tolist()))
    _perturb_heads(field)
    torch.testing.assert_close(F.normalize(field.heads.light_axis.detach().cpu(), dim=0), axis)
    a, d = (
        axis.to(device),
        F.normalize(torch.randn(64, 3, generator=torch.Generator().manual_seed(3)), dim=-1),
    )
    d = d.to(device)
    turn = torch.linalg.matrix_exp(  # rotations about the axis keep the angle to it
        torch.tensor([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]], device=device) * 1.3
    )
    x = BOUNDS.center.to(device).expand(64, 3)
    light, turned = field(x, d).light, field(x, d @ turn.T).light
    torch.testing.assert_close(light, turned, rtol=1e-5, atol=1e-6)
    assert (light - field(x, -d).light).abs().max() > 1e-4  # another angle, another light
    light.sum().backward()
    assert field.heads.light_axis.grad is not None and field.heads.light_axis.grad.abs().sum() > 0


def test_spatial_variation_after_perturbation(device) -> None:
    """Grids and MLPs vary in space once the heads are non-trivial; the constant field never does."""
    x, _ = _points(device, 256)
    d = torch.tensor([0.0, 0.0, 1.0], device=device).expand_as(x)
    for backend in ["triplane", "voxel", "mlp", "fourier"]:
        field = _make(backend, device)
        _perturb_heads(field)
        assert field(x, d).beta.std() > 1e-3, backend
    const = _make("constant", device)
    _perturb_heads(const)
    s = const(x, d)
    assert torch.allclose(s.beta, s.beta[:1].expand_as(s.beta))
    assert torch.allclose(s.light, s.light[:1].expand_as(s.light))


def test_triplane_planes_read_the_right_axes(device) -> None:
    """Plane 0 is indexed by (x, y), plane 1 by (x, z), plane 2 by (y, z), with corners at +-1."""
    field = _make("triplane", device, resolution=5, channels=2)
    assert isinstance(field, TriplaneField)
    ramp = torch.linspace(-1, 1, 5, device=device)
    with torch.no_grad():
        field.features[:, 0] = ramp.view(1, 1, 5)  # varies along width: first coordinate of the pair
        field.features[:, 1] = ramp.view(1, 5, 1)  # varies along height: second coordinate
    x, _ = _points(device, 64, spread=1.3)
    n = BOUNDS.normalize(x)
    feat = field.encode(x).view(-1, 3, 2)  # [P, plane, channel]
    expected = torch.stack([n[:, [0, 1]], n[:, [0, 2]], n[:, [1, 2]]], dim=1)  # [P, 3, 2]
    torch.testing.assert_close(feat, expected, atol=1e-5, rtol=0)


def test_voxel_reads_the_right_axes(device) -> None:
    field = _make("voxel", device, channels=3)
    assert isinstance(field, VoxelField)
    g = field.features.shape[-1]
    ramp = torch.linspace(-1, 1, g, device=device)
    with torch.no_grad():
        field.features[0, 0] = ramp.view(1, 1, g)  # W <- x
        field.features[0, 1] = ramp.view(1, g, 1)  # H <- y
        field.features[0, 2] = ramp.view(g, 1, 1)  # D <- z
    x, _ = _points(device, 64, spread=1.3)
    torch.testing.assert_close(field.encode(x), BOUNDS.normalize(x), atol=1e-5, rtol=0)


def test_voxel_matches_the_triplane_budget(device) -> None:
    tri, vox = _make("triplane", device), _make("voxel", device)
    assert tuple(tri.features.shape) == (3, 8, 64, 64)
    assert tuple(vox.features.shape) == (1, 8, 23, 23, 23)
    n_tri = tri.features.numel()
    assert abs(vox.features.numel() - n_tri) / n_tri < 0.05
    n_vox_total = sum(p.numel() for p in vox.parameters())
    assert abs(n_vox_total - n_tri) / n_tri < 0.05


def test_fourier_input_width(device) -> None:
    field = _make("fourier", device, num_frequencies=4)
    assert field.encoder[0].in_features == 3 * (1 + 2 * 4)


def test_fourier_encode_values() -> None:
    """The shared encoding: x, then sin / cos of 2^k pi x, octave-major (light and fourier field)."""
    x = torch.tensor([[0.25, -0.5, 1.0]])
    enc = fourier_encode(x, 2)  # [1, 15]
    assert enc.shape == (1, fourier_dim(2)) == (1, 15)
    ang = torch.tensor([[0.25, -0.5, 1.0, 0.5, -1.0, 2.0]]) * math.pi  # octave 0, then octave 1
    torch.testing.assert_close(enc, torch.cat([x, ang.sin(), ang.cos()], dim=-1))
    torch.testing.assert_close(encode_direction(x), fourier_encode(x, DIR_OCTAVES))
    assert torch.equal(fourier_encode(x, 0), x) and fourier_dim(0) == 3  # --num-frequencies 0
    field = _make("fourier", torch.device("cpu"), num_frequencies=0)
    assert field(*_points(torch.device("cpu"), n=4)).beta.shape == (4,)
    assert DIR_ENCODING_DIM == fourier_dim(DIR_OCTAVES)


@pytest.mark.parametrize("backend", ["triplane", "voxel"])
def test_tv_regularizer(device, backend: str) -> None:
    assert _make(backend, device).regularizer() is None
    field = _make(backend, device, tv_weight=0.5)
    reg = field.regularizer()
    assert reg is not None and reg.ndim == 0 and reg > 0
    reg.backward()
    assert field.features.grad is not None and field.features.grad.abs().sum() > 0
    with torch.no_grad():
        field.features.fill_(0.3)
    assert field.regularizer() == 0
    unweighted = _make(backend, device, tv_weight=1.0).regularizer()
    torch.testing.assert_close(_make(backend, device, tv_weight=0.5).regularizer(), 0.5 * unweighted)


@pytest.mark.parametrize("backend", ["mlp", "fourier", "constant"])
def test_no_regularizer_without_grid(device, backend: str) -> None:
    assert _make(backend, device, tv_weight=1.0).regularizer() is None


def test_grid_init_follows_the_global_seed(device) -> None:
    a, b = _make("triplane", device), _make("triplane", device)
    assert torch.equal(a.features, b.features)
    torch.manual_seed(123)
    c = MediumConfig(backend="triplane").setup(BOUNDS).to(device)
    assert not torch.equal(a.features, c.features)
    assert 0.05 < float(a.features.detach().std()) < 0.2


def test_bounds_from_scene_hold_cameras_and_ignore_outliers(device) -> None:
    g = torch.Generator().manual_seed(0)
    angles = torch.linspace(0, 6.28, 12, device=device)
    cams = torch.stack([4 * angles.cos(), 4 * angles.sin(), torch.full_like(angles, 1.5)], dim=-1)
    points = torch.randn(2000, 3, generator=g).to(device)  # drawn on the cpu: the same cloud everywhere
    points = torch.cat([points, torch.tensor([[500.0, -300.0, 800.0]], device=device)])
    bounds = FieldBounds.from_scene(cams, points)
    assert bounds.inside(cams).all()
    assert (bounds.half_size < 10).all()  # the outlier did not stretch the box
    assert not bounds.inside(points[-1:]).any()
    assert bounds.inside(points[:-1]).float().mean() > 0.9
    # the outlier is still finite through clamping
    field = MediumConfig(backend="triplane").setup(bounds).to(device)
    s = field(points[-1:], torch.tensor([[0.0, 0.0, 1.0]], device=device))
    assert torch.isfinite(s.beta).all() and torch.isfinite(s.light).all()


def test_gaussian_bound_pixel_medium_is_over_compositing(device) -> None:
    """Covered pixels take the Gaussians' values, uncovered ones the background, partial a mix."""
    field = _make("gaussian-bound", device)
    with torch.no_grad():
        field.background.copy_(torch.tensor([0.5, -1.0, 0.0, 1.0], device=device))
    value = torch.tensor([2.0, 1.0, -2.0, 0.5], device=device)  # one Gaussian's raw medium
    alpha = torch.tensor([1.0, 0.0, 0.25], device=device).view(3, 1, 1)  # [H=3, W=1, 1]
    blended = alpha * value  # [3, 1, 4] what the rasterizer returns for a single splat
    beta, light = field.pixel_medium(blended, alpha)
    kappa = field.log_kappa.exp()
    expect = torch.stack([value, field.background.detach(), 0.25 * value + 0.75 * field.background.detach()])
    torch.testing.assert_close(beta[:, 0], kappa * F.softplus(expect[:, 0]))
    torch.testing.assert_close(light[:, 0], torch.sigmoid(expect[:, 1:]))


@pytest.mark.parametrize("backend", FIELDS)
@pytest.mark.parametrize(
    "light",
    [
        ("global", "mlp"),
        ("global", "sh"),
        ("global", "rgb"),
        ("global", "axial"),
        ("field", "sh"),
        ("smooth", "mlp"),
    ],
)
def test_sample_rays_matches_per_sample_evaluation(device, backend: str, light: tuple[str, str]) -> None:
    """The march's per-ray evaluation (a global light once per ray) gives the values and gradients
    of evaluating every sample with its ray's direction (MediumField's generic path)."""
    space, mode = light
    field = _make(backend, device, light_space=space, light=mode)
    _perturb_heads(field)
    x, d = _points(device, n=6 * 5)
    pts, dirs = x.reshape(6, 5, 3), d[::5]  # [R, K, 3], [R, 3]: 6 rays of 5 samples

    def run(fn) -> tuple[torch.Tensor, ...]:
        field.zero_grad()
        s = fn(pts, dirs)
        (s.beta.sum() + (s.light * torch.linspace(0.5, 1.5, 3, device=device)).sum()).backward()
        grads = [p.grad.clone() for p in field.parameters() if p.grad is not None]
        return (s.beta.detach(), s.light.detach(), *grads)

    fast = run(field.sample_rays)
    generic = run(lambda p, v: MediumField.sample_rays(field, p, v))
    assert fast[0].shape == (6, 5) and fast[1].shape == (6, 5, 3)
    assert len(fast) == len(generic) > 2
    for a, b in zip(fast, generic, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    if space == "global":  # the light is shared along a ray, and differs between rays (mlp, sh)
        torch.testing.assert_close(fast[1], fast[1][:, :1].expand(-1, 5, -1))
        if mode != "rgb":
            assert (fast[1][0, 0] - fast[1][1, 0]).abs().max() > 1e-4


def test_axial_light_without_an_axis_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="light-axis .* has no direction"):
        MediumConfig(backend="triplane", light="axial", light_axis=(0.0, 0.0, 0.0)).check_values()


@pytest.mark.parametrize("backend", ["triplane", "voxel"])
def test_grid_start_noise_follows_init_feature_std(backend: str) -> None:
    torch.manual_seed(0)
    default = MediumConfig(backend=backend).setup(BOUNDS)
    assert float(default.features.detach().std()) == pytest.approx(0.1, rel=0.1)
    torch.manual_seed(0)
    quiet = MediumConfig(backend=backend, init_feature_std=0.0).setup(BOUNDS)
    assert not quiet.features.any()
    # a zero start still learns: the gradient reaches every grid cell a point reads
    _perturb_heads(quiet)
    x, d = _points(torch.device("cpu"))
    quiet(x, d).beta.sum().backward()
    assert float(quiet.features.grad.abs().sum()) > 0.0


def test_feature_lr_applies_to_grid_features_only() -> None:
    for backend in ("triplane", "voxel"):
        rates = {
            k: lr
            for k, (_, lr) in _make(backend, torch.device("cpu"), feature_lr=0.003).param_groups().items()
        }
        assert rates["medium.features"] == 0.003
        assert rates["medium.heads.log_kappa"] == 0.01
        assert all(
            lr == 0.01 for k, lr in rates.items() if k not in ("medium.features", "medium.heads.log_kappa")
        )
        default = {k: lr for k, (_, lr) in _make(backend, torch.device("cpu")).param_groups().items()}
        assert default["medium.features"] == 0.01  # None: the field's lr
    const = {
        k: lr
        for k, (_, lr) in _make("constant", torch.device("cpu"), feature_lr=0.003).param_groups().items()
    }
    assert const["medium.features"] == 0.01  # one global vector, not a grid


def test_feature_eps_applies_to_grid_features_only() -> None:
    for backend in ("triplane", "voxel"):
        field = _make(backend, torch.device("cpu"), feature_eps=1e-6)
        assert field.adam_eps() == {"medium.features": 1e-6}
        assert "medium.features" in field.param_groups()  # the name the optimizer knows
        assert _make(backend, torch.device("cpu")).adam_eps() == {}  # None: the optimizer's own
    for backend in ("constant", "mlp"):
        assert _make(backend, torch.device("cpu"), feature_eps=1e-6).adam_eps() == {}
