"""The Gaussian-splatting pipeline assembled from registered components.

It composes a Gaussian model, a rasterizer and a photometric loss, plus the Tri-DehazeGS parts:
a medium field composited physically (I = J*T + S), a gradient policy, the depth and dark-channel
losses and the two-stage schedule. With the ``none`` medium it is plain 3DGS, whose clean and
hazy renders coincide; every ablation is a field of this config (docs/medium.md).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Literal

import torch
from torch import Tensor, nn
from torch.profiler import record_function

from components.data.cameras import Cameras, scene_up
from components.gaussians.densify import Densifier, DensifyConfig
from components.gaussians.model import GaussianModel, GaussianModelConfig
from components.losses.dcp import DCPResult, dark_channel_bound, dcp_transmittance_loss, default_patch
from components.losses.depth import (
    depth_spread,
    edge_aware_smoothness,
    log_depth_l1,
    trimmed_pearson_depth_loss,
)
from components.losses.medium_texture import path_extinction_roughness
from components.losses.reconstruction import ReconstructionLossConfig
from components.losses.shape import elongation_penalty
from components.medium.band_limit import coarse_to_fine_sigma
from components.medium.base import FieldBounds, MediumConfig, MediumField
from components.medium.compositing import (
    OPEN_SKY_COVERAGE,
    CompositeConfig,
    MediumCompositor,
    MediumRender,
    composite,
    composite_over_backdrop,
)
from components.rasterizers.base import RasterizeOutput, RasterizerConfig
from pipelines.engine.contract import Decision, Pipeline, PipelineConfig, StepResult
from pipelines.engine.datamanager import DataManager
from pipelines.engine.medium_recovery import reference_depth
from pipelines.engine.metrics import psnr
from pipelines.tridehaze.floater_pruning import FloaterPruning, rendered_surface, surface_views, true_surface
from pipelines.tridehaze.ground_seeds import ground_seeds
from pipelines.tridehaze.light_colour_fit import (
    LightColourFit,
    PointObservations,
    light_spread,
    mean_view_light,
    ray_light,
)
from pipelines.tridehaze.light_flattening import LightFlattening
from pipelines.tridehaze.light_isotropy import LightIsotropy
from pipelines.tridehaze.medium_transplant import load_medium, load_verdict
from pipelines.tridehaze.priors import (
    ViewPrior,
    build_view_priors,
    dcp_per_view,
    dehaze_point_colors,
    dehazed_views,
    estimate_medium,
    observed_point_colors,
    resolve_depth_prior,
    scaled_step,
    visible_points,
)
from pipelines.tridehaze.probe import probe_haze
from pipelines.tridehaze.reference_start import PARTS as REFERENCE_PARTS
from pipelines.tridehaze.reference_start import fit_to_reference
from pipelines.tridehaze.scene_transplant import load_gaussians
from pipelines.tridehaze.sky_shell import sky_shell
from pipelines.tridehaze.true_depth_march import march_to_depth, trusted_medium
from pipelines.tridehaze.warmup import warmup_depths
from tridehaze_plugin.config import NonNegative, Positive, Range, RegistryChoice, retire_options
from tridehaze_plugin.errors import ConfigError
from tridehaze_plugin.registry import REGISTRY


@dataclass
class GaussianPipelineConfig(PipelineConfig):
    """Which components make up the method, and how they are combined."""

    model: GaussianModelConfig = field(default_factory=GaussianModelConfig)
    """The clean scene: 3D Gaussians."""
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    """Adaptive density control (clone / split / prune / opacity reset)."""
    rasterizer: RasterizerConfig = field(default_factory=RasterizerConfig)
    """Differentiable rasterizer backend."""
    loss: ReconstructionLossConfig = field(default_factory=ReconstructionLossConfig)
    """Photometric loss against the input views."""
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Background colour behind the Gaussians (RGB in [0, 1])."""
    random_background: bool = False
    """Use a random background colour each step (discourages Gaussians from encoding the background)."""
    medium_ignores_backdrop: bool = False
    """With ``random_background``: hold T constant in the random backdrop's term of the composite,
    so that only the Gaussians' coverage answers for it. Otherwise the backdrop's variance rewards
    any extinction that hides it and the medium thickens wherever coverage is incomplete. Holding it
    brings T closer to the truth on real photos with synthetic haze, but restores worse there (beer
    -1.3 to -3.8 dB) and on the generated benchmark (the sunlit field's sky leaves the fade): an
    ablation switch, not a recommended setting (docs/results/medium_recovery.md, session 34)."""
    medium: MediumConfig = field(default_factory=MediumConfig)
    """The view-shared medium (``--pipeline.medium.backend none`` is plain 3DGS)."""
    composite: CompositeConfig = field(default_factory=CompositeConfig)
    """Ray marching of the medium between the camera and the rendered surface."""
    gradient_policy: Annotated[str, RegistryChoice("gradient_policy")] = "none"
    """Transmittance gradient compensation: ``none``, ``tgc`` (from the start) or ``md-tgc``
    (only once the medium is frozen)."""
    t_min: float = 0.1
    """Compensation factor is 1 / clamp(T, t_min): at most 1 / t_min."""
    densify_grad: Literal["uncompensated", "compensated"] = "uncompensated"
    """Which screen-space gradient densification sees while compensation is on: ``uncompensated``
    multiplies each Gaussian's gradient by clamp(T, t_min) at its centre (undoing the 1/T boost, so
    dense haze does not trigger extra growth); ``compensated`` uses the boosted gradient as is."""
    depth_prior: Literal["auto", "files", "dcp", "sfm", "warmup", "none"] = "auto"
    """Pseudo-depth for the depth-correlation loss: the dataset's depth files, -ln T of the dark
    channel, sparse SfM depth, a short haze-agnostic warm-up's depth, or none. ``auto``: files when
    every training view has one, else SfM when the scene has seed points, else warmup."""
    point_tracks: Literal["off", "only", "union"] = "off"
    """How the ``sfm`` pseudo-depth uses SfM tracks where the dataset records them (COLMAP models,
    td-synth scenes). ``off``: every point reprojected into every view, with a guess at occlusion
    (what datasets without tracks get). ``only``: each view's tracked points alone, no guess.
    ``union``: the tracked points without the guess, the others reprojected with it (a track's
    absence is a failed match as often as a hidden point). ``tri-dehaze`` uses ``union``: paired on
    one machine it gains 0.6 dB on the benchmark at two seeds, ties on the holdout set and hazed
    beer, gains 0.2 dB on hazed statue; ``only`` gains as much on generated scenes but loses 1-1.5
    dB on beer, whose COLMAP tracks (median 4 views) halve the prior's coverage
    (docs/results/medium_recovery.md, sessions 43-49). Off here, for datasets without tracks and
    the paper's preset."""
    warmup_steps: Annotated[int, NonNegative] = 300
    """Steps of the haze-agnostic warm-up that produces the ``warmup`` pseudo-depth."""
    lambda_depth: Annotated[float, NonNegative] = 0.0
    """Weight of the depth loss (1 - Pearson correlation + lambda_smooth * smoothness); 0 = off."""
    lambda_smooth: Annotated[float, NonNegative] = 0.1
    """Weight of edge-aware depth smoothness inside the depth loss; 0 = off."""
    depth_trim: Annotated[float, Range(0.0, 0.9)] = 0.0
    """Share of the prior's pixels left out of the depth correlation each step: those whose
    standardised depth disagrees most with the render (a trimmed loss against SfM outliers:
    mismatches and hidden points seen through gaps). 0 = every prior pixel counts. With
    ``lambda_depth`` 0.1 it gains 0.4-0.5 dB on the benchmark set, ties on the holdout set and
    is mixed on hazed real photos (docs/results/medium_recovery.md, sessions 63-64): off."""
    lambda_depth_metric: Annotated[float, NonNegative] = 0.0
    """Weight of the log-depth L1 against a pseudo-depth in the scene's own scale (the ``sfm``
    prior only; the others are relative); 0 = off. The Pearson term cannot see the depth's scale,
    and a march to too short a depth needs too little haze (docs/results/medium_recovery.md)."""
    lambda_depth_spread: Annotated[float, NonNegative] = 0.0
    """Weight of the depth spread along each ray: the variance of the blended Gaussians' depths
    over the squared mean depth, on pixels covered at least half. The medium is marched to the
    blend's mean depth, which Gaussians spread in front of a surface pull short (the shorter the
    march, the less haze, and the scene takes up the rest); this draws them onto the surface,
    like Mip-NeRF 360's distortion loss. It costs a second rasterization of three channels (kept
    out of densification's statistics); 0 = off."""
    lambda_elongation: Annotated[float, NonNegative] = 0.0
    """Weight of the needle penalty: how far each Gaussian's largest scale exceeds
    ``max_elongation`` times its middle one (in log space, averaged over the Gaussians). A needle
    seen end-on by the training views shows as a streak in a novel view; 0 = off."""
    max_elongation: Annotated[float, Range(1.0, None)] = 10.0
    """Largest-to-middle scale ratio the needle penalty allows freely (discs are never penalised)."""
    homogeneous_tv_weight: Annotated[float, NonNegative] = 0.0
    """TV weight on the medium's grid features (``medium.tv_weight``) for captures whose haze the
    probe finds homogeneous (one extinction explains every pair of training views; logged in
    logs/decisions.jsonl); other captures keep ``medium.tv_weight``. Left free, the extinction
    field takes up the surfaces' texture in front of them (a thin slab of haze is a change of
    colour to the photometric loss), which a smoothness prior suppresses. At 0.1, paired on the
    benchmark: +0.25 dB at seeds 42 and 7 (room-uniform +0.8 / +0.7); but on the holdout set's
    homogeneous room -3.1 / -0.6 dB (seeds 42 / 7; T MAE 0.043 -> 0.067 at 42: a denser medium
    under a dimmer light), so it is not ``tri-dehaze``'s default (docs/results/medium_recovery.md, session 50). Resolved before setup, like
    ``medium.backend auto``: the run's config.yml holds the chosen ``medium.tv_weight`` and 0
    here. 0: no gate (and no probe)."""
    depth_correlation: bool = True
    """Keep the Pearson correlation term of the depth loss (``--pipeline.no-depth-correlation`` drops
    it but keeps the smoothness term: the paper's "without depth correlation" ablation)."""
    lambda_dcp: Annotated[float, NonNegative] = 0.0
    """Weight of the dark-channel transmittance loss ||T - T_dcp||^2 (Stage I only); 0 = off."""
    dcp_bound: Literal["two-sided", "lower", "lower-own-light"] = "two-sided"
    """How the dark channel constrains T: ``two-sided`` pulls T to it (the paper's MSE); ``lower``
    penalises only T below it, since the prior under-estimates t on surfaces without dark pixels;
    ``lower-own-light`` the same bound recomputed each step with the medium's own light along each
    ray as the airlight (one airlight per image over-estimates t where the haze light is dimmer)."""
    dcp_omega: Annotated[float, Range(0.5, 1.0)] = 0.95
    """The dark channel's omega in the ``lower-own-light`` bound T >= 1 - omega min(I / L). He et
    al.'s 0.95 keeps a little haze for looks; on a black clean patch it lies (1 - omega)(1 - T)
    above the true T, which holds dense haze too thin wherever the bound is active. 1 is the bound
    the physics gives where T is even over the patch (J >= 0 at the patch's darkest pixel); it moved
    dense haze towards the truth but let the one-light rooms go too dense: +0.08 / +0.22 dB on the
    benchmark (courtyard-dense alone), -0.87 on the holdout set (docs/results/medium_recovery.md, session 53)."""
    dcp_omega_strong: Annotated[float, Range(0.5, 1.0)] | None = None
    """``dcp_omega`` while the raised dark-channel weight holds (``lambda_dcp_isotropic`` on a run
    judged one light); None: ``dcp_omega`` throughout. Weight 1 pins such a run's haze to the
    bound, so the margin lifts its opaque haze to T ~ 0.05 against a true ~0.01. At 1: -0.35 dB on
    the holdout set's one-light scenes (courtyard-height -0.89), so it stays None (session 53)."""
    dcp_upper_weight: Annotated[float, Range(0.0, 1.0)] = 0.0
    """With a ``lower`` bound: the share of the squared error still paid where T is above the dark
    channel (0: a pure bound; 1: the two-sided loss). Dense or homogeneous haze, where the dark
    channel is close, drifts to too little haze under a pure bound."""
    dcp_weighting: Literal["uniform", "transmittance"] = "uniform"
    """Per-pixel weight of the dark-channel term: ``uniform``, or ``transmittance``: the pixel's
    rendered T (detached). The bound speaks about the clean colour through T: where the haze is
    nearly opaque (sky, dense haze) it says little about how the haze splits into T and light,
    and its omega margin, (1 - omega)(1 - T) above the truth on a black clean patch, is largest
    against T. There the medium and the light follow the photos alone (a strong bound on the
    sky thins the whole field and brightens the light: docs/results/medium_recovery.md, session 28)."""
    lambda_dcp_isotropic: Annotated[float, NonNegative] = 0.0
    """The dark-channel weight from ``light-decision-fraction`` of the run on, where the medium's
    light has proved the same along every ray by then (the spread of its per-ray light under
    ``light-isotropy-cv``); elsewhere ``lambda-dcp`` stays. 0 = off (the verdict is still taken
    for ``composite.clean-fill auto``); it does nothing where the medium never learns (a hold as
    long as Stage I). Where no pixel sees the haze light the photos do not pin its brightness, and
    a strong bound corrects a too dim light and a too dense medium; where the light depends on the
    direction (sunlit haze) the photos do, and a strong bound only thins the field along the sky
    (docs/results/medium_recovery.md, session 30)."""
    light_isotropy_cv: Annotated[float, NonNegative] = 0.03
    """The spread (standard deviation over mean) of the medium's per-ray light S / (1 - T), over
    the pixels with at least 20 % haze, under which the light counts as the same along every ray.
    Measured: 0.007-0.014 on real photos hazed with one light, 0.02-0.06 on the generated scenes
    without a sun, 0.07-0.16 on the sunlit ones, where a strong bound costs 2-6 dB: 0.03 keeps
    a margin of 2.4x below the sunlit scenes."""
    light_weight_ramp: tuple[float, float] | None = None
    """Spreads (start, end) over which the raised dark-channel weight falls geometrically to
    ``lambda-dcp`` instead of stepping at ``light-isotropy-cv``: runs of one scene read spreads
    within about 1 % of each other and five generated scenes sit at 2.5-3.5 %, so the step moved
    one of them by 2 dB between seeds (docs/results/medium_recovery.md, session 57). The clean
    render's fill (``composite.clean-fill auto``) still follows the threshold. None: the step."""
    flatten_one_light: bool = False
    """At the freeze, where the run was judged one light (``light-isotropy-cv``), replace the
    medium's light by its mean over the training pixels for every ray: the verdict says the light
    is one, but the learnt light keeps a direction dependence that gives each view its own
    in-scattering error (pipelines/tridehaze/light_flattening.py). False: the light as learnt."""
    flatten_seen_share: Annotated[float, Range(0.0, 1.0)] = 0.2
    """``flatten-one-light`` keeps the learnt light where more than this share of the verdict
    window's pixels rendered opaque haze (T under ``light-seen-level``): those pixels show the
    light itself in their directions, so its direction dependence is observed, not left free
    (courtyard-dense under an open sky, session 58). 1.0: flatten every one-light run."""
    light_seen_share: Annotated[float, Range(0.0, 1.0)] = 1.0
    """A run judged one light keeps the weak dark-channel weight where more than this share of the
    verdict window's pixels render as opaque haze (T under ``light-seen-level``): there the photos
    show the haze light itself and pin its brightness, and the strong bound would only thin the
    medium (dense haze hiding walls; docs/results/medium_recovery.md, session 40). The fill of
    ``composite.clean-fill auto`` still follows the one-light verdict. 1.0: never."""
    light_seen_level: Literal[0.02, 0.05, 0.1, 0.15] = 0.05
    """The rendered T under which a pixel counts as seeing the haze light (``light-seen-share``)."""
    light_decision_fraction: Annotated[float, Range(0.0, 1.0)] = 0.25
    """When the light's spread is judged, as a fraction of the run; it is measured over the second
    half of the steps between the medium's hold and then (earlier, the sunlit and the other
    generated scenes' spreads overlap). Where that falls at or after the freeze (a short Stage I:
    ``tri-dehaze-fast`` freezes at a fifth), halfway between the hold's end and the freeze. The
    strong bound acts from here to the freeze and only ever thins the medium, so this also sets
    its dose (``tri-dehaze``: 0.5 with the freeze at 0.75; docs/results/medium_recovery.md,
    session 39)."""
    medium_late_lr_scale: Annotated[float, Positive] = 1.0
    """The medium's learning rates times this from the one-light verdict
    (``light-decision-fraction``) to the freeze. The medium is still short of where its photos put
    it at the freeze on the rooms and the patchy media (a medium 3x as fast throughout restores
    their surfaces better), but faster before the verdict it reads the light's spread lower and
    flips it (docs/results/medium_recovery.md, session 66). At 3: benchmark +0.21 / +0.10 dB
    (seeds 42 / 7; dense haze under the strong bound thins too far, courtyard-dense -0.6 / -0.9),
    holdout -0.11 (seed 42; room-dense -1.0): session 67. 1.0: the rates as configured."""
    medium_late_lr_groups: tuple[str, ...] = ()
    """The medium's optimizer groups ``medium-late-lr-scale`` acts on, by name (``medium.features``:
    a grid backend's features; the others as a checkpoint names them); empty: all of them. At 3x
    (session 68): the grid alone -0.20 dB, the extinction's head and kappa -0.24 (seed 42); the
    light alone (``medium.heads.light_*``) +0.02 / +0.13 (seeds 42 / 7): the rooms gain, the
    sunlit field's sky loses."""
    medium_late_lr_when: Literal["always", "one-light"] = "always"
    """Which runs ``medium-late-lr-scale`` acts on: every run, or only those the verdict judged one
    light (from the step after it). A faster light alone gained on the rooms (one light) and lost
    the sunlit field's sky; kept to one-light runs, the holdout set lost -0.08 (seed 42; room-dense
    -0.43): session 68."""
    lambda_path_extinction: Annotated[float, NonNegative] = 0.0
    """Weight of the medium-texture prior (while the medium learns; 0 = off): the squared
    difference, relative to the view's mean, of the mean extinction tau / z along adjacent pixels'
    rays that end at about the same depth. Left free, the extinction field takes up the surfaces'
    texture in front of them; unlike ``medium.tv_weight`` this does not hold a homogeneous
    medium's amount (components/losses/medium_texture.py). At 1, paired on the benchmark: -0.19 /
    -0.24 dB (seeds 42 / 7): the uniform media gain (room-uniform +2.4 / +1.5, street-homogeneous
    +0.8 / +0.5), the patchy ones and the sunlit field lose (room-patchy -0.8 / -0.7, field-sunlit
    -3.1 / -2.2), so it stays off (docs/results/medium_recovery.md, session 51)."""
    path_extinction_depth_step: Annotated[float, Positive] = 0.05
    """Adjacent pixels whose end depths differ by more than this (in log depth) are a depth edge,
    across which the medium-texture prior lets the mean extinction change."""
    lambda_light: Annotated[float, NonNegative] = 0.0
    """Weight of the light anchor (Stage I only; 0 = off): the squared error between the mean light
    the view's rays scatter and the view's dark-channel airlight. The light is otherwise free to
    drift with the haze amount (too bright under the two-sided loss, too dim under a lower bound,
    on real photos whose airlight the dark channel gets right: docs/results/medium_recovery.md)."""
    freeze_step: int | None = None
    """Step at which the medium is frozen and Stage II begins (None: ``freeze_fraction`` of the run)."""
    freeze_fraction: float = 0.2
    """Stage I length as a fraction of ``--max-steps`` when ``freeze_step`` is None (paper: 3k/15k)."""
    stage_two_holds_haze: bool = False
    """Stage II also holds the haze each pixel sees: the composite's end depth and coverage are
    detached, so the Gaussians cannot move along the rays to change T and S once the medium is
    frozen (with ``composite.depth_gradient`` they do: the default's T at the rendered depth moved
    0.028 -> 0.036-0.040 on courtyard-dense over Stage II, benchmarks/stage_two_change.py). Measured
    -0.03 / -0.03 dB (seeds 42 / 7), the drift unchanged: it is not the composite's gradient (session 53)."""
    stage_two_geometry: Literal["free", "held"] = "free"
    """``held``: Stage II fits only the Gaussians' colours; their positions, shapes and opacities
    stay as at the freeze. With the medium frozen, a Gaussian moving changes the depth each pixel is
    marched to and so its T and S: Stage II's free geometry let the haze drift (courtyard-dense's T
    MAE 0.028 -> 0.036-0.040, session 53), which detaching only the composite's depth did not stop.
    Densification, pruning and opacity resets scheduled past the freeze are skipped too. Paired by
    continuing the default's runs from the freeze (session 65): benchmark +0.40 / +0.42 dB (seeds
    42 / 7; courtyard-dense +1.66 / +1.52, the rest -0.11 to +1.11), but holdout -0.20 / -0.14 (8 of
    10 lower, reconstruction lower on 9) and hazed beer -1.7 to -2.6 on all four runs (its T at the
    rendered depth improves in Stage II): an option, off (docs/results/stage_two_geometry_held.md)."""
    medium_start: Literal[
        "dark-channel", "reference", "reference-mean", "reference-extinction", "reference-light"
    ] = "dark-channel"
    """Where the trainable medium starts: the dark channel's estimate, or ``reference`` (a diagnosis
    on td-synth data, never a method): fitted to the generator's true medium before training, to
    see whether training keeps it (pipelines/tridehaze/reference_start.py); ``reference-mean``: to
    its mean over the box, one extinction and one light (the right amount, not the layout);
    ``reference-extinction``: the true extinction with the mean light; ``reference-light``: the true
    light with the mean extinction."""
    march_to: Literal["rendered", "true-depth"] = "rendered"
    """Where the training rays' march through the medium ends: the Gaussians' rendered depth, or
    ``true-depth`` (a diagnosis on td-synth data, never a method): each training view's true depth
    (clamped to the far bound; no gradient to the Gaussians' depth from the composite), to see what
    the rendered depth's errors do to the fitted medium. Rendering and evaluation march to the
    rendered depth either way."""
    medium_from: Path | None = None
    """Start from, and hold for the whole run, the medium of this checkpoint of an earlier run on
    the same data (same method and medium backend): the scene is fitted afresh through it, the
    light is not recoloured again and the one-light verdict is the checkpoint's
    (pipelines/tridehaze/medium_transplant.py). Through the
    default's own final medium the refitted scene ties on six of eight benchmark scenes (seeds 42, 7),
    so the joint fit does not damage the Gaussians (docs/results/medium_recovery.md, session 56).
    None: the medium starts from the dark channel's estimate and learns in Stage I."""
    scene_from: Path | None = None
    """Start from, and hold for the whole run, the Gaussians of this checkpoint of an earlier run on
    the same data (a diagnosis, never a method: ``vanilla-gs`` trained on a generated scene's clean
    photos gives the scene a haze-free capture would): no densification, and only the medium learns
    (pipelines/tridehaze/scene_transplant.py). ``scene-from-holds geometry`` lets the colours learn.
    None: the Gaussians start from the seed cloud."""
    scene_from_holds: Literal["all", "geometry"] = "all"
    """What of ``scene_from``'s Gaussians is held: ``all`` (only the medium learns) or ``geometry``
    (means, rotations, scales and opacities; the colours learn through the medium)."""
    medium_learns_from: Literal["all", "true-depth"] = "all"
    """Which training pixels the medium's photometric gradient comes from: all, or ``true-depth`` (a
    diagnosis on td-synth data, never a method): only those whose rendered end depth is within
    ``medium_trust_tolerance`` of the true depth (clamped to the far bound), so rays that stop
    short or overshoot cannot tilt the medium. The composite and the Gaussians' gradient are
    unchanged; the medium's priors still see every pixel. Measured -5.6 dB (seed 42): the medium
    goes 1.3-1.85x too dense, since the wrongly deep pixels are what held its amount down
    (docs/results/medium_recovery.md, session 56)."""
    medium_trust_tolerance: Annotated[float, Range(0.0, 1.0)] = 0.05
    """Relative end-depth error under which ``medium_learns_from true-depth`` trusts a pixel."""
    prune_floaters: Literal["off", "true-depth", "rendered"] = "off"
    """Prune, every ``densify.refine-every`` steps from ``densify.refine-start`` on, the Gaussians
    whose centre lies more than ``floater-margin`` in front of the surface in more than
    ``floater-share`` of the training views that see it (they carry haze that belongs to the
    medium; pipelines/tridehaze/floater_pruning.py). ``true-depth``: the surface from td-synth's
    true depth (a diagnosis, never a method); ``rendered``: the model's own depth where its
    coverage is at least 0.5 (one extra render per training view each time)."""
    floater_margin: Annotated[float, Range(0.0, 1.0)] = 0.15
    """Relative distance in front of the surface from which a Gaussian's centre is in free space."""
    floater_share: Annotated[float, Range(0.0, 1.0)] = 0.5
    """Share of the views seeing a Gaussian on a surface pixel that must see it in free space."""
    medium_hold_fraction: float = 0.05
    """The medium keeps its initial values for this fraction of the run: early, the Gaussians are
    transparent and the rendered depth is the far bound, which would drive the extinction down."""
    medium_freeze_blur: Annotated[float, NonNegative] = 0.0
    """At the freeze, low-pass the medium's grid by a Gaussian of this std (grid cells) for Stage II
    and every render after it. The medium learns faster than the Gaussians and keeps the surfaces'
    texture it took up early in Stage I (3-100x the true roughness, session 52); blurring the
    frozen field hands that texture to the Gaussians, which Stage II refits. Grid backends only
    (triplane, voxel); 0 = off."""
    medium_coarse_to_fine: Annotated[float, NonNegative] = 0.0
    """Coarse-to-fine medium: when it starts learning, the grid's features are low-passed by a
    Gaussian of this std (in grid cells), falling linearly to none over ``medium-coarse-fraction``
    of its learning (the hold's end to the freeze). Early in Stage I the Gaussians are coarse and
    the medium, a fast learner, takes up the surfaces' texture as thin slabs of haze; smooth haze
    first leaves the texture to the Gaussians. Grid backends only (triplane, voxel); 0 = off. At 4,
    paired on the benchmark: -0.30 / +0.15 dB (seeds 42 / 7; the patchy media up at both, the
    dense and sunlit ones down, T MAE unchanged), so it stays off (docs/results/medium_recovery.md, session 52)."""
    medium_coarse_fraction: Annotated[float, Range(0.0, 1.0)] = 0.5
    """Share of the medium's learning over which the coarse-to-fine blur falls to zero."""
    init_medium: bool = True
    """Start the medium from the dark channel: airlight from the brightest dark-channel pixels,
    extinction from -ln T_dcp at the seed points' distances (else the medium config's values)."""
    airlight: tuple[float, float, float] | None = None
    """The haze light (RGB in (0, 1]) where it is known (a grey card or a sky patch seen through
    opaque haze): replaces the dark channel's airlight in the medium's start, in every view's
    dark-channel T, and as the light anchor's target. None: estimated per view from the brightest
    dark-channel pixels, which is too dim where no pixel is opaque haze (indoors), and then the
    medium is too dense (docs/results/medium_recovery.md, session 14)."""
    dehaze_seed_colors: bool = True
    """Take the estimated haze out of the seed points' colours before initialising the Gaussians."""
    sky_shell: Annotated[int, NonNegative] = 0
    """Seed this many Gaussians evenly over the sphere around the medium's box (only those some
    training view sees are kept), coloured by the views: the sky and far background then start at
    a depth every view agrees on instead of as floaters near the cameras. It also lets a
    semi-transparent surface show the shell behind it, against the random training background's
    push to opacity: off (0) by default (docs/results/medium_recovery.md, session 29). Without a
    seed cloud it does nothing: the random start already fills the box."""
    ground_seeds: Annotated[int, NonNegative] = 0
    """Seed up to this many Gaussians on the ground plane (a low quantile of the seed points'
    height along the cameras' up) where training rays below the horizon see no seed point, beyond
    the view's farthest ones: far terrain that structure from motion does not reach. For open
    ground running to the horizon: +0.2 to +0.4 dB on the generated fields and the sunlit street
    (seeds 42 and 7, mostly in the sky); in courtyards and rooms the plane runs on behind the
    walls and the seeds cast through a wall start it at a second depth, -0.8 to -2.4 dB. 0: off
    (docs/results/medium_recovery.md, session 42). Without a seed cloud it does nothing."""
    seed_colors: Literal["nearest", "observed"] = "nearest"
    """How the seed colours are dehazed: ``nearest`` dehazes the dataset's point colour at the
    nearest camera's distance; ``observed`` re-reads every training view that sees the point and
    dehazes each observation at its own distance (T^2-weighted mean), which does not depend on how
    the dataset chose its one colour (docs/results/medium_recovery.md, session 17)."""
    light_colour_fit: bool = False
    """At the freeze, give the medium's light the colour that the seed points' hazy colours say,
    read from how each point's colour changes with its haze across the training views (with the
    model's T; the medium's brightness is kept). The joint fit leaves the light's colour where it
    started, and the clean render then takes the difference as a cast. Not applied where the
    medium's per-ray light spreads over 5 % (the fit assumes one light) or the fit is uncertain;
    the decision goes to logs/decisions.jsonl (pipelines/tridehaze/light_colour_fit.py;
    docs/results/medium_recovery.md, session 37)."""
    input_dehaze: Literal["none", "dcp"] = "none"
    """Dehaze the training views before training: ``dcp`` replaces each by its single-image dark
    channel prior restoration (guided-filter refined T, clamped at 0.05): the restoration-assisted
    baseline ``dcp-gs``. Use it without a medium (the medium would model haze that is gone)."""

    def check_values(self) -> None:
        if not all(0.0 <= c <= 1.0 for c in self.background):
            raise ConfigError(f"--pipeline.background must be three values in [0, 1], got {self.background}")
        if not 0.0 < self.t_min <= 1.0:
            raise ConfigError(f"--pipeline.t-min must be in (0, 1], got {self.t_min}")
        if self.airlight is not None and not all(0.0 < a <= 1.0 for a in self.airlight):
            raise ConfigError(
                f"--pipeline.airlight must be three values in (0, 1] (linear RGB of the haze light), "
                f"got {self.airlight}"
            )
        for sub in (self.loss, self.composite, self.medium, self.densify, self.rasterizer):
            sub.check_values()
        if not 0.0 <= self.freeze_fraction <= 1.0 or not 0.0 <= self.medium_hold_fraction <= 1.0:
            raise ConfigError(
                "--pipeline.freeze-fraction and --pipeline.medium-hold-fraction must be in [0, 1]"
            )
        if self.medium_start != "dark-channel" and self.medium_from is not None:
            raise ConfigError(
                f"--pipeline.medium-start {self.medium_start} and --pipeline.medium-from both replace the "
                "medium's start: the checkpoint's medium would overwrite the reference fit",
                fix="give only one of them",
            )

    def resolve(self, datamanager: DataManager, seed: int) -> tuple[GaussianPipelineConfig, list[Decision]]:
        """The haze probe of the training views, where a choice depends on it: the medium backend
        (``--pipeline.medium.backend auto``) and the extinction's smoothness
        (``homogeneous_tv_weight``)."""
        auto = self.medium.backend == "auto"
        gated = self.homogeneous_tv_weight > 0 and self.medium.backend != "none"
        if not (auto or gated):
            return self, []
        train = datamanager.train_indices
        dcp = dcp_per_view(datamanager, train, keep=True, airlight=self.airlight)  # for setup()
        probe = probe_haze(datamanager, train, datamanager.scene.points, seed, dcp)
        medium, decisions = self.medium, []
        if auto:
            medium = replace(medium, backend=probe.backend)
            decisions.append(Decision(probe.message(), {"haze_probe": probe.to_dict()}))
        if gated:
            smooth = probe.haze == "homogeneous"
            weight = self.homogeneous_tv_weight if smooth else medium.tv_weight
            medium = replace(medium, tv_weight=weight)
            why = "one extinction explains every pair of views" if smooth else f"the probe says {probe.haze}"
            decisions.append(
                Decision(
                    f"medium TV weight {weight:g}: {why}",
                    {
                        "homogeneous_tv": {
                            "haze": probe.haze,
                            "tv_weight": weight,
                            **({} if auto else {"haze_probe": probe.to_dict()}),
                        }
                    },
                )
            )
        # resolved once: the run's config.yml names the choices, and reloading never probes again
        return replace(self, medium=medium, homogeneous_tv_weight=0.0), decisions

    def setup(
        self, datamanager: DataManager, seed: int = 0, max_steps: int = 30_000, training: bool = True
    ) -> GaussianPipeline:
        """``training=False`` (reloading a run to render it) skips the per-view priors and warm-up."""
        return GaussianPipeline(self, datamanager, seed, max_steps, training)


# options tried and removed (docs/results/medium_recovery.md), still in the config.yml of runs trained
# while they existed: loadable where they were off
retire_options(
    GaussianPipelineConfig,
    lambda_coverage=0.0,  # be6cacd
    lambda_opacity_entropy=0.0,  # 11e7734
    medium_lr_final_ratio=1.0,  # ce60462
    medium_residual_blur=0.0,  # 759f02e
    medium_warmup_fraction=0.0,  # c1b3741
    strong_bound_floor=0.0,  # 2745c37
)


@dataclass(frozen=True)
class _PriorPlan:
    """Which data-driven priors a run needs, decided once from the config and the data."""

    uses_medium: bool
    dehaze_inputs: bool
    depth_source: str
    """The pseudo-depth source in use (``none`` when the depth loss is off)."""
    needs_dcp: bool

    @staticmethod
    def decide(
        config: GaussianPipelineConfig, dm: DataManager, uses_medium: bool, training: bool
    ) -> _PriorPlan:
        source = resolve_depth_prior(config.depth_prior, dm)
        weighted = config.lambda_depth > 0 or config.lambda_depth_metric > 0
        needs_depth = training and weighted and source != "none"
        dehaze_inputs = training and config.input_dehaze == "dcp"
        dcp_weighted = config.lambda_dcp > 0 or config.lambda_dcp_isotropic > 0
        needs_dcp = training and uses_medium and (config.init_medium or dcp_weighted)
        needs_dcp = needs_dcp or dehaze_inputs or (needs_depth and source == "dcp")
        return _PriorPlan(uses_medium, dehaze_inputs, source if needs_depth else "none", needs_dcp)


def light_decision_step(fraction: float, max_steps: int, hold: int, freeze: int) -> int:
    """The step the medium's light is judged at: ``fraction`` of the run, or halfway through the
    medium's learning (the hold's end to the freeze) where that comes at or after the freeze, so a
    short Stage I still gets its verdict (docs/results/medium_recovery.md, session 35)."""
    decide = scaled_step(None, fraction, max_steps)
    return decide if decide < freeze else (hold + freeze) // 2


def step_background(seed: int, step: int) -> Tensor:
    """The random background colour [3] of a training step: a function of (seed, step) alone, so a
    resumed run draws the same colours as an uninterrupted one."""
    gen = torch.Generator(device="cpu").manual_seed(seed * 1_000_003 + step)
    return torch.rand(3, generator=gen)


def _append_seeds(
    points: Tensor, colors: Tensor | None, extra: Tensor, extra_colors: Tensor
) -> tuple[Tensor, Tensor]:
    """The seed points [M, 3] with ``extra`` [K, 3] appended, and their colours as float in [0, 1]
    (uint8 colours rescaled; none: grey) with ``extra_colors`` [K, 3]."""
    base = torch.full_like(points, 0.5) if colors is None else torch.as_tensor(colors)
    base = base.float() / 255.0 if base.dtype == torch.uint8 else base.float()
    pts = torch.cat([points.detach().float(), extra.to(points.device)])
    return pts, torch.cat([base.to(points.device), extra_colors.to(points.device)])


class GaussianPipeline(Pipeline):
    """3D Gaussians (+ optional medium) + rasterizer + losses on one view per step."""

    def __init__(
        self,
        config: GaussianPipelineConfig,
        datamanager: DataManager,
        seed: int = 0,
        max_steps: int = 30_000,
        training: bool = True,
    ) -> None:
        super().__init__()
        self.config = config
        self.datamanager = datamanager
        scene = datamanager.scene
        torch.manual_seed(seed)  # the medium's and the model's initial values draw from it, in this order
        extent = float(scene.cameras.centers.norm(dim=-1).max()) * 1.1 if len(scene) > 1 else 1.0
        self.scene_extent = max(extent, 1e-6)
        self.max_steps = max_steps
        self.freeze_step = scaled_step(config.freeze_step, config.freeze_fraction, max_steps)
        self.hold_steps = scaled_step(None, config.medium_hold_fraction, max_steps)
        self.rasterizer = config.rasterizer.setup(device=datamanager.device)
        self.loss_fn = config.loss.setup()
        self.policy = REGISTRY.get("gradient_policy", config.gradient_policy)(config.t_min)
        self.compositor = MediumCompositor(config.composite)
        bounds = FieldBounds.from_scene(scene.cameras.centers, scene.points)
        train_c2w = scene.cameras.camtoworlds[list(datamanager.train_indices)].detach().double().cpu().numpy()
        self.scene_up = torch.from_numpy(scene_up(train_c2w)).float()  # [3] for the clean render's fill
        self.medium = self._build_medium(bounds)
        self.medium.bind_scene(scene.root, scene.transform)
        self.register_buffer("stage", torch.tensor(1, dtype=torch.int64))
        plan = _PriorPlan.decide(config, datamanager, self.medium.has_medium, training)
        dcp = (
            dcp_per_view(datamanager, datamanager.train_indices, airlight=config.airlight)
            if plan.needs_dcp
            else {}
        )
        self._targets = dehazed_views(datamanager, dcp) if plan.dehaze_inputs else {}
        colors = self._initialize_medium(dcp, plan)
        self._replace_medium_start(training, seed)
        points, colors = self._with_sky_shell(scene.points, colors, bounds)
        points, colors = self._with_ground_seeds(points, colors, scene.points)
        self.model = config.model.setup(points=points, colors=colors, scene_extent=self.scene_extent)
        self.model.to(datamanager.device)
        if config.scene_from is not None and training:
            step_n = load_gaussians(self.model, config.scene_from, scene.transform.to_dict())
            self.init_info["scene_from_step"], self.init_info["scene_from_gaussians"] = step_n
        self.medium.attach(self.model)
        self.densifier = Densifier(config.densify, self.scene_extent, max_steps)
        self.floater_pruning = FloaterPruning.from_config(config)
        self.register_buffer("densify_plateau", self.densifier.plateau)  # resumes the growth decision
        self._build_light_steps(max_steps)
        self._photometric: Tensor | None = None
        self.register_buffer(
            "background", torch.tensor(config.background, dtype=torch.float32, device=datamanager.device)
        )
        self._seed = seed
        self.depth_source = plan.depth_source
        self.priors = self._view_priors(dcp, plan, seed)
        self._last: RasterizeOutput | None = None
        self._true_depth: dict[int, Tensor] = {}  # the true-depth diagnoses: the maps read so far
        self._dens_weight: Tensor | None = None

    def _build_light_steps(self, max_steps: int) -> None:
        """What is decided about the medium's light during the run: the one-light verdict, the
        colour fit and the flattening at the freeze."""
        cfg = self.config
        self.light_isotropy = self._light_verdict(max_steps).to(self.datamanager.device)
        self.light_colour = LightColourFit(
            cfg.light_colour_fit and self.medium.has_medium and cfg.medium_from is None, self.freeze_step
        )
        self.light_flat = LightFlattening(
            cfg.flatten_one_light and self.medium.recolours_light, self.freeze_step, cfg.flatten_seen_share
        )

    def _build_medium(self, bounds: FieldBounds) -> MediumField:
        """The medium field in ``bounds``, on the data's device; refuses a coarse-to-fine schedule
        for a medium without a grid to low-pass."""
        cfg = self.config
        medium = cfg.medium.setup(bounds=bounds).to(self.datamanager.device)
        for flag, value in (
            ("coarse-to-fine", cfg.medium_coarse_to_fine),
            ("freeze-blur", cfg.medium_freeze_blur),
        ):
            if value > 0 and medium.has_medium and not medium.band_limits:
                raise ConfigError(
                    f"--pipeline.medium-{flag} low-passes a grid; the {cfg.medium.backend!r} medium has none",
                    fix=f"use --pipeline.medium.backend triplane or voxel, or leave --pipeline.medium-{flag} at 0",
                )
        unknown = sorted(set(cfg.medium_late_lr_groups) - set(medium.param_groups()))
        if unknown:
            raise ConfigError(
                f"--pipeline.medium-late-lr-groups names {unknown}, which the {cfg.medium.backend!r} "
                f"medium does not have",
                fix=f"name some of {sorted(medium.param_groups())}, or none for all of them",
            )
        return medium

    def _light_verdict(self, max_steps: int) -> LightIsotropy:
        """The one-light verdict and the dark-channel weight it sets (measured only where the medium
        learns before it and the weight or ``clean-fill auto`` reads it); with ``medium_from``, the
        checkpoint's own verdict where it took one."""
        cfg = self.config
        decide = light_decision_step(
            cfg.light_decision_fraction, max_steps, self.hold_steps, self.freeze_step
        )
        window = (max(self.hold_steps, decide - (decide - self.hold_steps) // 2), decide)
        read = cfg.lambda_dcp_isotropic > 0 or cfg.composite.clean_fill == "auto"
        verdict = LightIsotropy(
            cfg.lambda_dcp,
            cfg.lambda_dcp_isotropic,
            cfg.light_isotropy_cv,
            window,
            measures=read and decide < self.freeze_step,
            seen_light=(cfg.light_seen_level, cfg.light_seen_share),
            ramp=cfg.light_weight_ramp,
        )
        if cfg.medium_from is not None and self.medium.has_medium:
            self.init_info["medium_from_verdict"] = load_verdict(verdict, cfg.medium_from)
        return verdict

    def _initialize_medium(self, dcp: dict[int, DCPResult], plan: _PriorPlan) -> Tensor | None:
        """Start the medium from the dark channel's estimate; returns the seed colours to use
        (with the estimated haze taken out when ``dehaze_seed_colors``)."""
        cfg, dm = self.config, self.datamanager
        points, colors = dm.scene.points, dm.scene.point_colors
        self.init_info: dict[str, float | str] = {}
        if not ((plan.uses_medium and cfg.init_medium or plan.dehaze_inputs) and dcp):
            return colors
        est = estimate_medium(dm, dcp, points)
        if plan.uses_medium:
            beta = est.beta if est.beta is not None else cfg.medium.init_beta
            self.medium.initialize(beta, est.airlight)
            self.init_info.update(
                init_beta=beta, init_airlight=str([round(a, 3) for a in est.airlight.tolist()])
            )
        if cfg.dehaze_seed_colors and points is not None and colors is not None:
            colors = dehaze_point_colors(points, colors, dm.scene.cameras.centers, est)
            if cfg.seed_colors == "observed" and est.beta is not None:
                observed, seen = observed_point_colors(dm, list(dm.train_indices), points, est)
                colors = torch.where(seen[:, None], observed, colors)
        return colors

    def _replace_medium_start(self, training: bool, seed: int) -> None:
        """Overwrite the dark channel's start where asked: with the generator's true medium
        (``medium_start reference``, a diagnosis) or an earlier run's (``medium_from``)."""
        cfg, scene = self.config, self.datamanager.scene
        if not self.medium.has_medium:
            return
        if cfg.medium_start != "dark-channel" and training:
            part = REFERENCE_PARTS[cfg.medium_start]
            self.init_info.update(fit_to_reference(self.medium, scene.root, scene.transform, seed, part))
        if cfg.medium_from is not None:
            self.init_info["medium_from_step"] = load_medium(self.medium, cfg.medium_from)

    def _with_sky_shell(
        self, points: Tensor | None, colors: Tensor | None, bounds: FieldBounds
    ) -> tuple[Tensor | None, Tensor | None]:
        """The seed cloud [M, 3] and colours with ``sky_shell`` points appended (colours as float)."""
        if self.config.sky_shell == 0 or points is None or len(points) == 0:
            return points, colors
        return _append_seeds(points, colors, *sky_shell(self.datamanager, bounds, self.config.sky_shell))

    def _with_ground_seeds(
        self, points: Tensor | None, colors: Tensor | None, cloud: Tensor | None
    ) -> tuple[Tensor | None, Tensor | None]:
        """The seed points [M, 3] and colours with ``ground_seeds`` points appended (colours as
        float); the ground is found from the dataset's own cloud ``cloud``."""
        if self.config.ground_seeds == 0 or points is None or cloud is None or len(cloud) == 0:
            return points, colors
        seeds = ground_seeds(self.datamanager, cloud, self.scene_up, self.config.ground_seeds)
        return _append_seeds(points, colors, *seeds)

    def _view_priors(self, dcp: dict[int, DCPResult], plan: _PriorPlan, seed: int) -> dict[int, ViewPrior]:
        """Per-view pseudo-depth and dark-channel transmittance (a warm-up run first if it is the source)."""
        dm, scene = self.datamanager, self.datamanager.scene
        warm = None
        if plan.depth_source == "warmup":
            warm = warmup_depths(
                dm, self.config.model, self.rasterizer, scene.points, scene.point_colors,
                self.scene_extent, self.config.warmup_steps, seed,
            )  # fmt: skip
        if not (dcp or plan.depth_source != "none"):
            return {}
        tracks = scene.point_tracks if self.config.point_tracks != "off" else None
        return build_view_priors(
            dm, dm.train_indices, dcp, plan.depth_source, scene.points, warm, tracks,
            union=self.config.point_tracks == "union",
        )  # fmt: skip

    # ----------------------------------------------------------------------------- schedule
    def stage_at(self, step: int) -> int:
        """1: scene and medium fitted jointly; 2: medium frozen, compensation per the policy."""
        return 1 if step < self.freeze_step else 2

    def _band_limit(self, step: int) -> float:
        """The blur of the medium's grid at ``step`` (cells): coarse-to-fine in Stage I, the freeze
        blur in Stage II."""
        cfg = self.config
        if self.stage_at(step) == 2:
            return cfg.medium_freeze_blur
        end = self.hold_steps + round(cfg.medium_coarse_fraction * (self.freeze_step - self.hold_steps))
        return coarse_to_fine_sigma(step, self.hold_steps, end, cfg.medium_coarse_to_fine)

    def _medium_trainable(self, step: int) -> bool:
        return self.stage_at(step) == 1 and step >= self.hold_steps and self.config.medium_from is None

    # ----------------------------------------------------------------------------- training
    def training_target(self, idx: int) -> Tensor:
        """The image view ``idx`` is fitted to: its input, or its dehazed version (``input_dehaze``)."""
        if idx in self._targets:
            return self._targets[idx].float() / 255.0  # [H, W, 3]
        return self.datamanager.image(idx)

    def train_loss(self, step: int) -> StepResult:
        cfg, dm = self.config, self.datamanager
        stage = self.stage_at(step)
        self.stage.fill_(stage)
        lights = self._fit_light_colour() if self.light_colour.due(step) else None
        if self.light_flat.due(step):
            self._flatten_light(lights)
        self.medium.set_trainable(self._medium_trainable(step), self.model)
        self.model.set_geometry_trainable(not self._geometry_held(step))
        self.model.set_colour_trainable(cfg.scene_from is None or cfg.scene_from_holds == "geometry")
        if (cfg.medium_coarse_to_fine > 0 or cfg.medium_freeze_blur > 0) and self.medium.band_limits:
            self.medium.set_band_limit(self._band_limit(step))
        idx = dm.train_index(step)
        target = self.training_target(idx)  # [H, W, 3]
        bg = self.background
        if cfg.random_background:
            bg = step_background(self._seed, step).to(bg)
        cam = dm.camera(idx)
        with record_function("td.rasterize"):  # stage labels for torch.profiler
            out = self._rasterize(cam, step, bg)
        clean = out.rgb[0]  # [H, W, 3]
        depth = out.depth[0]  # [H, W, 1]
        metrics: dict[str, Tensor] = {}  # detached scalars; read by the trainer in one transfer
        with record_function("td.medium"):
            if cfg.march_to == "true-depth":
                med = self._medium_to_true_depth(idx, cam, out)
            else:
                med = self._medium(cam, out, hold=stage == 2 and cfg.stage_two_holds_haze)
            if med is not None and cfg.medium_learns_from == "true-depth":
                med, metrics["trusted_share"] = self._trusted_medium(idx, med)
        with record_function("td.composite+loss"):
            hazy = clean if med is None else self._training_composite(clean, out, med, bg, stage)
            loss, terms = self.loss_fn(hazy, target)
        self._photometric = loss.detach()
        metrics.update({k: v.detach() for k, v in terms.items()})
        prior = self.priors.get(idx)
        loss = loss + self._scene_priors(cam, depth, target, prior, metrics)
        if med is not None:
            loss = loss + self._medium_priors(
                step, stage, target, med, out.alpha[0, ..., 0].detach(), prior, metrics
            )
        self._last = out
        self._dens_weight = self._densify_weight(out, med, stage)
        metrics["psnr"] = psnr(hazy.detach(), target)
        return StepResult(loss=loss, metrics=metrics)

    def _training_view_media(self) -> Iterator[tuple[int, Cameras, Tensor, Tensor]]:
        """Each training view's index, camera, rendered T [H, W] and S [H, W, 3] on the CPU (what the
        decisions taken at the freeze read)."""
        for i in self.datamanager.train_indices:
            cam = self.datamanager.camera(i)
            med = self._medium(cam, self._rasterize(cam, None, self.background))
            yield i, cam, med.pixel_transmittance()[..., 0].cpu(), med.scattering.cpu()

    @torch.no_grad()
    def _fit_light_colour(self) -> list[Tensor] | None:
        """Recolour the medium's light by the fit over the training views (once, at the freeze);
        returns each view's per-ray light [P, 3] as the recoloured light gives it (None where the
        medium has no light to recolour)."""
        if not self.medium.recolours_light:
            self.light_colour.skip(f"the {self.config.medium.backend} medium has no light to recolour")
            return None
        dm, points = self.datamanager, self.datamanager.scene.points
        pts = None if points is None else points.detach().float().cpu()
        ids, colours, ts, lights = [], [], [], []
        for i, cam, T, S in self._training_view_media():
            lights.append(ray_light(T, S))  # [P, 3]
            if pts is not None and len(pts):
                vis = visible_points(cam, pts)
                ids.append(vis.mask.nonzero()[:, 0])
                colours.append(dm.image(i).cpu()[vis.v, vis.u].float())
                ts.append(T[vis.v, vis.u])
        obs = PointObservations(torch.cat(ids), torch.cat(colours), torch.cat(ts)) if ids else None
        gain = self.light_colour.gain(obs, mean_view_light(lights), light_spread(lights))
        if gain is None:
            return lights
        self.medium.recolour_light(gain)
        return [x * gain.to(x) for x in lights]  # S is linear in the light

    @torch.no_grad()
    def _flatten_light(self, lights: list[Tensor] | None) -> None:
        """Give the medium one light, its mean over the training pixels (once, at the freeze);
        ``lights``: each view's per-ray light where the colour fit has just rendered them."""
        if lights is None:
            lights = [ray_light(T, S) for _, _, T, S in self._training_view_media()]  # [P, 3] each
        iso = self.light_isotropy
        light = self.light_flat.decide(
            iso.judged_one_light(), iso.seen_light_share(), mean_view_light(lights), light_spread(lights)
        )
        if light is not None:
            self.medium.flatten_light(light)

    def _scene_priors(
        self, cam: Cameras, depth: Tensor, target: Tensor, prior: ViewPrior | None, metrics: dict
    ) -> Tensor:
        """The Gaussians' own loss terms (depth correlation and smoothness, metric depth, depth
        spread, needle penalty); their detached values go into ``metrics``."""
        cfg = self.config
        loss = depth.new_zeros(())
        if cfg.lambda_depth > 0 and prior is not None and prior.depth is not None:
            d = depth[..., 0]
            if cfg.depth_correlation:
                corr = trimmed_pearson_depth_loss(d, prior.depth, prior.depth_valid, cfg.depth_trim)
                loss = loss + cfg.lambda_depth * corr
                metrics["depth_corr"] = 1.0 - corr.detach()
            if cfg.lambda_smooth > 0:
                loss = loss + cfg.lambda_depth * cfg.lambda_smooth * edge_aware_smoothness(d, target)
        if (
            cfg.lambda_depth_metric > 0
            and prior is not None
            and prior.depth is not None
            and prior.depth_metric
        ):
            metric = log_depth_l1(depth[..., 0], prior.depth, prior.depth_valid)
            loss = loss + cfg.lambda_depth_metric * metric
            metrics["depth_log_l1"] = metric.detach()
        if cfg.lambda_depth_spread > 0:
            spread = self._depth_spread(cam)
            loss = loss + cfg.lambda_depth_spread * spread
            metrics["depth_spread"] = spread.detach()
        if cfg.lambda_elongation > 0:
            needle = elongation_penalty(self.model.log_scales, cfg.max_elongation)
            loss = loss + cfg.lambda_elongation * needle
            metrics["elongation"] = needle.detach()
        return loss

    def _medium_priors(
        self,
        step: int,
        stage: int,
        target: Tensor,
        med: MediumRender,
        alpha: Tensor,
        prior: ViewPrior | None,
        metrics: dict,
    ) -> Tensor:
        """The medium's own loss terms (dark-channel transmittance, light anchor, medium texture,
        field regulariser) given the view's coverage ``alpha`` [H, W]; their detached values go into
        ``metrics``."""
        cfg = self.config
        T = med.pixel_transmittance()[..., 0]  # [H, W]
        loss = T.new_zeros(())
        self.light_isotropy.observe(step, med)
        lambda_dcp = self.light_isotropy.weight(step)
        if stage == 1 and lambda_dcp > 0 and prior is not None and prior.t_dcp is not None:
            t_prior, mask = prior.t_dcp, None
            if cfg.dcp_bound == "lower-own-light":
                omega = cfg.dcp_omega
                if cfg.dcp_omega_strong is not None and self.light_isotropy.raised(step):
                    omega = cfg.dcp_omega_strong
                t_prior, mask = self._own_light_bound(target, med, omega)
            lower = cfg.dcp_bound != "two-sided"
            weight = T.detach() if cfg.dcp_weighting == "transmittance" else None
            dcp = dcp_transmittance_loss(
                T, t_prior, mask, lower_bound=lower, upper_weight=cfg.dcp_upper_weight, weight=weight
            )
            loss = loss + lambda_dcp * dcp
            metrics["dcp"] = dcp.detach()
        anchored = prior is not None and prior.airlight is not None and med.scattered_light is not None
        if stage == 1 and cfg.lambda_light > 0 and anchored:
            anchor = (med.scattered_light - prior.airlight).square().mean()
            loss = loss + cfg.lambda_light * anchor
            metrics["light_anchor"] = anchor.detach()
        trainable = self._medium_trainable(step)
        if trainable and cfg.lambda_path_extinction > 0:
            surface = alpha >= OPEN_SKY_COVERAGE  # [H, W] rays that end on the scene
            rough = path_extinction_roughness(
                T, med.end_depth[..., 0], surface, cfg.path_extinction_depth_step
            )
            loss = loss + cfg.lambda_path_extinction * rough
            metrics["path_extinction"] = rough.detach()
        reg = self.medium.regularizer() if trainable else None
        if reg is not None:
            loss = loss + reg
        metrics["mean_T"] = T.detach().mean()
        return loss

    def _depth_spread(self, cam: Cameras) -> Tensor:
        """The depth spread of the training view (the Gaussian centres' camera z), from a pass of its
        own: its gradient reaches the Gaussians but not the colour pass's screen-space gradients, so
        it does not drive densification."""
        viewmat = cam.viewmats()[0].to(self.model.means)  # [4, 4] world -> camera
        z = self.model.means @ viewmat[2, :3] + viewmat[2, 3]  # [N] camera z of each centre
        values = torch.stack([torch.ones_like(z), z, z * z], dim=-1)  # [N, 3]
        return depth_spread(self.model.render_values(self.rasterizer, cam, values)[0])

    @staticmethod
    def _own_light_bound(target: Tensor, med: MediumRender, omega: float) -> tuple[Tensor, Tensor]:
        """The dark-channel bound on T [H, W] with the medium's light along each ray as airlight
        (S / (1 - T), detached), and where it is defined: pixels with at least 5 % haze."""
        haze = 1.0 - med.pixel_transmittance().detach()  # [H, W, 1]
        light = med.ray_light(0.05).detach()  # [H, W, 3]
        H, W = haze.shape[:2]
        bound = dark_channel_bound(target, light, default_patch(H, W), omega)  # [H, W]
        return bound, haze[..., 0] >= 0.05

    def _training_composite(
        self, clean: Tensor, out: RasterizeOutput, med: MediumRender, bg: Tensor, stage: int
    ) -> Tensor:
        """The hazy training render [H, W, 3] of the clean one [H, W, 3] (premultiplied over ``bg``)."""
        if med.at_infinity:
            clean = self._surface_colour(clean, out, med, bg)
        elif self.config.random_background and self.config.medium_ignores_backdrop:
            backdrop = self._backdrop(out, bg)  # [H, W, 3]
            surface = self.policy.apply(clean - backdrop, med.transmittance, stage)
            return composite_over_backdrop(surface, backdrop, med)
        return composite(self.policy.apply(clean, med.transmittance, stage), med)

    @staticmethod
    def _surface_colour(clean: Tensor, out: RasterizeOutput, med: MediumRender, background: Tensor) -> Tensor:
        """The clean render without the background colour (premultiplied) where the medium stands in
        for it: composited to infinity (``composite.background infinite``) or shown as the sky
        (``composite.clean-sky``)."""
        if not med.at_infinity and med.sky is None:
            return clean
        return clean - GaussianPipeline._backdrop(out, background)  # [H, W, 3] premultiplied

    @staticmethod
    def _backdrop(out: RasterizeOutput, background: Tensor) -> Tensor:
        """[H, W, 3] the background colour [3] showing through the Gaussians' uncovered share."""
        return (1.0 - out.alpha[0]) * background

    def _densify_weight(self, out: RasterizeOutput, med: MediumRender | None, stage: int) -> Tensor | None:
        """clamp(T, t_min) at each Gaussian's projected centre while compensation is on."""
        if med is None or not self.policy.active(stage) or self.config.densify_grad == "compensated":
            return None
        H, W = med.transmittance.shape[:2]
        xy = out.means2d.detach()[0]  # [N, 2] pixels
        x = xy[:, 0].long().clamp(0, W - 1)
        y = xy[:, 1].long().clamp(0, H - 1)
        return med.transmittance.detach()[y, x, 0].clamp(min=self.config.t_min)[None]  # [1, N]

    def param_groups(self) -> dict[str, tuple[nn.Parameter, float]]:
        return {**self.model.param_groups(), **self.medium.param_groups()}

    def adam_eps(self) -> dict[str, float]:
        return self.medium.adam_eps()

    def lr_scales(self, step: int) -> dict[str, float]:
        """``medium-late-lr-scale`` on the chosen medium groups from the verdict to the freeze."""
        scale = self.config.medium_late_lr_scale
        if scale == 1.0:
            return {}
        iso = self.light_isotropy
        late = iso.decision_step <= step < self.freeze_step
        if self.config.medium_late_lr_when == "one-light":  # read after the verdict's own step took it
            late = late and step > iso.decision_step and iso.judged_one_light()
        groups = self.config.medium_late_lr_groups or tuple(self.medium.param_groups())
        return dict.fromkeys(groups, scale if late else 1.0)

    def after_backward(self, step: int) -> None:
        if self._last is not None:
            self.densifier.collect(self._last, self._dens_weight)
        if self._photometric is not None:
            self.densifier.observe_loss(self._photometric)

    def after_optimizer_step(self, step: int, optimizers: dict[str, torch.optim.Optimizer]) -> None:
        if self._geometry_held(step):  # no growth, pruning or opacity reset either
            self.last_refine = {}
            return
        self.last_refine = self.densifier.step(step, self.model, optimizers)
        if self.floater_pruning.due(step):
            self.last_refine["floaters"] = self._prune_floaters(optimizers)

    def milestone_steps(self) -> tuple[int, ...]:
        """The freeze: Stage II ablations and ``benchmarks/stage_two_change.py`` start from it."""
        if not self.medium.has_medium or not 0 < self.freeze_step < self.max_steps:
            return ()
        return (self.freeze_step,)

    def _geometry_held(self, step: int) -> bool:
        """Whether the Gaussians' geometry is held at ``step`` (``stage_two_geometry held``, or a
        scene taken from another run: ``scene_from``)."""
        if self.config.scene_from is not None:
            return True
        return self.stage_at(step) == 2 and self.config.stage_two_geometry == "held"

    @torch.no_grad()
    def _prune_floaters(self, optimizers: dict[str, torch.optim.Optimizer]) -> int:
        """Prune the Gaussians in front of the training views' surfaces (``prune_floaters``)."""
        far = self.compositor.far_bound(self.medium)

        def surface_of(idx: int, cam: Cameras) -> Tensor:
            size = (int(cam.height[0]), int(cam.width[0]))
            if self.config.prune_floaters == "true-depth":
                return true_surface(self._true_depth_of(idx, size), far)
            out = self._rasterize(cam, None, self.background)
            return rendered_surface(out.depth[0], out.alpha[0])

        dm = self.datamanager
        views = surface_views(list(dm.train_indices), dm.camera, surface_of)
        return self.densifier.prune(
            self.model, optimizers, self.floater_pruning.select(self.model.means, views)
        )

    # ---------------------------------------------------------------------------- rendering
    def _rasterize(self, camera: Cameras, step: int | None, background: Tensor) -> RasterizeOutput:
        # no step (rendering for eval/view): all SH bands
        return self.model.render(self.rasterizer, camera, 10**9 if step is None else step, background)

    def _medium(self, camera: Cameras, out: RasterizeOutput, hold: bool = False) -> MediumRender | None:
        """T and S for the view, or None without a medium; ``hold``: no gradient to the depth and
        coverage the rays end at."""
        if not self.medium.has_medium:
            return None
        depth, alpha = out.depth[0], out.alpha[0]  # [H, W, 1]
        if hold:
            depth, alpha = depth.detach(), alpha.detach()
        return self.medium.render_view(self.compositor, camera, depth, alpha, self.model, self.rasterizer)

    def _medium_to_true_depth(self, idx: int, camera: Cameras, out: RasterizeOutput) -> MediumRender | None:
        """T and S of training view ``idx`` marched to its true depth (``march_to true-depth``)."""
        if not self.medium.has_medium:
            return None
        z = self._true_depth_of(idx, tuple(out.depth.shape[1:3])).to(out.depth)  # [H, W, 1]
        return march_to_depth(self.medium, self.compositor, camera, z, self.model, self.rasterizer)

    def _true_depth_of(self, idx: int, size: tuple[int, int]) -> Tensor:
        """Training view ``idx``'s true z-depth [H, W, 1], clamped to the far bound (diagnoses); read
        and clamped once per view."""
        if idx not in self._true_depth:
            z = reference_depth(self.datamanager, idx, size)
            if z is None:
                raise ConfigError(
                    "--pipeline.march-to, --pipeline.medium-learns-from and --pipeline.prune-floaters "
                    "true-depth need the dataset's true depth maps",
                    where=str(self.datamanager.scene.root),
                    fix="use them on a dataset written by `td-synth scene`",
                )
            far = self.compositor.far_bound(self.medium)
            self._true_depth[idx] = z.nan_to_num(far, far, far).clamp(1e-6, far)
        return self._true_depth[idx]

    def _trusted_medium(self, idx: int, med: MediumRender) -> tuple[MediumRender, Tensor]:
        """``med`` learning only where its end depth is within ``medium_trust_tolerance`` of view
        ``idx``'s true depth (``medium_learns_from true-depth``), and the share of pixels trusted."""
        z = self._true_depth_of(idx, tuple(med.end_depth.shape[:2])).to(med.end_depth)  # [H, W, 1]
        return trusted_medium(med, z, self.config.medium_trust_tolerance)

    @torch.no_grad()
    def render(self, camera: Cameras, step: int | None = None) -> dict[str, Tensor]:
        out = self._rasterize(camera, step, self.background)
        clean = out.rgb[0]  # [H, W, 3]
        med = self._medium(camera, out)
        if med is None:
            T = torch.ones_like(out.alpha[0])
            S = torch.zeros_like(clean)
            hazy = clean
        else:
            surface = self._surface_colour(clean, out, med, self.background)
            T, S = med.pixel_transmittance(), med.scattering
            hazy = composite(surface if med.at_infinity else clean, med)
            one_light = self.light_isotropy.judged_one_light()
            clean = self.compositor.clean_view(med, surface, one_light, camera, self.scene_up)
        return {
            "clean": clean.clamp(0, 1),
            "hazy": hazy.clamp(0, 1),
            "transmittance": T,
            "scattering": S.clamp(0, 1),
            "depth": out.depth[0],
            "alpha": out.alpha[0],
        }

    def output_names(self) -> list[str]:
        return ["clean", "hazy", "transmittance", "scattering", "depth", "alpha"]

    @torch.no_grad()
    def medium_at_depth(self, camera: Cameras, depth: Tensor) -> tuple[Tensor, Tensor] | None:
        if not self.medium.has_medium:
            return None
        med = self.medium.render_view(
            self.compositor, camera, depth, torch.ones_like(depth), self.model, self.rasterizer
        )
        return med.pixel_transmittance(), med.scattering.clamp(0, 1)

    @property
    def composites_medium(self) -> bool:
        return self.medium.has_medium

    def describe(self) -> str:
        if self._targets:
            return f"training on dark-channel dehazed inputs ({len(self._targets)} views)"
        if not self.medium.has_medium:
            return ""
        parts = [f"medium {self.config.medium.backend}", f"depth prior {self.depth_source}"]
        parts += [f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in self.init_info.items()]
        parts.append(f"Stage II from step {self.freeze_step}")
        return ", ".join(parts)

    def stats(self) -> dict[str, float | int]:
        out = {"gaussians": self.model.num_gaussians, "stage": int(self.stage)}
        if self.densifier.growth_stopped_at is not None:
            out["growth_stopped_at"] = self.densifier.growth_stopped_at
        return out

    def scene_gaussians(self) -> GaussianModel:
        return self.model

    def medium_field(self) -> MediumField:
        return self.medium

    def pop_decisions(self) -> list[str | Decision]:
        out: list[str | Decision] = []
        for part in (self.densifier, self.light_isotropy, self.light_colour, self.light_flat):
            out += part.decisions
            part.decisions = []
        return out

    def _apply(self, fn, *args, **kwargs):  # noqa: ANN001, ANN202
        # moving the pipeline replaces its buffers: keep the densifier on the same plateau tensor
        out = super()._apply(fn, *args, **kwargs)
        self.densifier.plateau = self.densify_plateau
        return out

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:  # noqa: ANN001
        # checkpoints written before plateau growth existed: keep this run's "still growing" state
        state_dict.setdefault(prefix + "densify_plateau", self.densify_plateau.clone())
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
