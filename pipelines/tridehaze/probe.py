"""The haze probe behind ``--pipeline.medium.backend auto``: does this capture need a medium, and
if so, is one extinction for the whole scene enough or does the haze vary in space?

It reads only the training views and the seed points, before training, and answers ``none`` only
on positive evidence of a clear capture: two independent measurements must both say "clear", with
a bootstrap over the views agreeing. Anything else (haze found, an estimate that is physically
impossible, too little data, a verdict that flips when the views are resampled) keeps a medium.
Missing haze costs far more than modelling it needlessly would be worth risking on a guess
(docs/tradeoff.md measures both).

The two measurements:

1. **Pair fit**. A seed point seen in two views has, under I = J T + A (1 - T), the same clean
   colour J in both, so

       ln |I_a - A| - ln |I_b - A| = -(tau_a - tau_b)

   with A the median of the views' dark-channel airlights and tau the optical depth to the point:
   the surface colour cancels. One beta fitted over all pairs (tau = beta * distance) gives the optical depth
   at the median point distance. Its bootstrap interval over views is what is trusted: an interval
   reaching below ``-IMPOSSIBLE_OPTICAL_DEPTH`` (negative extinction, T > 1) means the model's
   assumptions fail on this capture (a medium light that varies within a view, a sun glow, changing
   exposure) and the fit says nothing.
2. **Haze floor** (single-image, He et al.'s statistic): the median over pixels of the dark channel
   relative to the airlight. Haze lifts every pixel's dark channel by A (1 - T); clear captures
   keep most patches near zero.

Per pair of views the probe also measures the median residual of the fit against its spread
(``effect`` = |median| / MAD, ``F`` = n * effect^2): pairs crossing different amounts of haze
disagree with one extinction (``varying``). Thresholds were set on the calibration part of
``td-bench probe``'s scene set and checked on its held-back part (docs/tradeoff.md).
"""

from __future__ import annotations

import itertools
import math
import time
import warnings
from dataclasses import asdict, dataclass

import numpy as np
import torch

from components.losses.dcp import DCPResult, estimate_dcp
from components.losses.depth_priors import in_image, project_points
from pipelines.engine.datamanager import DataManager

CLEAR_OPTICAL_DEPTH = 0.1
"""The pair fit calls a capture clear when the upper end of its bootstrap interval of the optical
depth at the median point distance stays below this (T > 0.9 at a typical distance)."""
IMPOSSIBLE_OPTICAL_DEPTH = 0.1
"""An optical depth below minus this, with its whole bootstrap interval below zero, is a negative
extinction (T > 1.1 at a typical distance): impossible, not noise."""
CLEAR_HAZE_FLOOR = 0.2
"""The haze floor calls a capture clear below this median dark channel / airlight. On the
calibration scenes clear captures span 0.15-0.90 (bright or grey surfaces lift the dark channel
without haze) and hazy ones 0.26 and up, so only the low end is trusted as "clear"."""
MIN_DISTANCE_SPREAD = 1.3
"""Extinction shows only where the views see points at different distances: below this ratio of
the 75th to the 25th percentile of the point distances (an object-centred orbit) the pair fit
measures exposure and shading rather than haze, and it abstains."""
MIN_CONFIDENCE = 0.9
"""A ``none`` verdict that fewer than this share of the bootstrap resamples repeat is unsure."""
BOOTSTRAP = 200
"""Resamples of the views for the confidence and the intervals."""
INTERVAL = (0.05, 0.95)
"""Quantiles of the bootstrap distribution reported as the interval."""
BACKEND_FOR = {"none": "none", "homogeneous": "triplane", "varying": "triplane", "unsure": "triplane"}
"""Medium backend per haze class, from the measured comparison (docs/tradeoff.md): the constant
medium loses 5-6 dB to the tri-plane even on uniform haze in this engine, so every haze gets the
tri-plane, and an unsure verdict keeps it too."""
VARYING_F = 15.0
"""Median per-pair F above which pairs of views disagree with a homogeneous medium..."""
VARYING_EFFECT = 0.3
"""...with a median effect size (|median residual| / MAD) above this."""
MAX_VIEWS = 32
"""Views used (evenly spread over the training views); pairs grow as views^2."""
MAX_POINTS = 20_000
"""Seed points used (a fixed random subset beyond this)."""
MIN_SHARED = 15
"""Points two views must share for the pair to count."""
MIN_PAIRS = 3
"""Fewer usable view pairs than this: nothing can be measured (``unsure``)."""
MIN_SIGNAL = 0.05
"""|I - A| below this (a surface the colour of the haze) carries no transmittance information."""
GRID_CELLS = 16
"""Cells along the longer image side of the point z-buffer that drops occluded seed points."""


FloatOrArray = float | np.ndarray


@dataclass
class HazeProbe:
    """The probe's measurements and verdict (all logged)."""

    haze: str
    """``none``, ``homogeneous``, ``varying`` or ``unsure`` (keep a medium: see ``reason``)."""
    reason: str
    confidence: float = math.nan
    """Share of the bootstrap resamples of the views whose verdict gives the same backend; 0 where the
    probe abstained (no seed points, too few pairs, points all at one distance): a medium is kept
    because nothing could be measured, not because haze was found."""
    beta: float = math.nan
    """Extinction fitted over all view pairs (1 / scene unit)."""
    median_distance: float = math.nan
    """Median camera-to-point distance over the visible seed points (scene units)."""
    optical_depth: float = math.nan
    """beta * median_distance."""
    optical_depth_low: float = math.nan
    optical_depth_high: float = math.nan
    """Bootstrap interval (INTERVAL quantiles) of the optical depth."""
    haze_floor: float = math.nan
    """Median over the views of the median dark channel / airlight."""
    distance_spread: float = math.nan
    """75th / 25th percentile of the seed points' distances from the views that see them."""
    variation_f: float = math.nan
    """Median over view pairs of F = n * (median residual / MAD)^2."""
    variation_effect: float = math.nan
    """Median over view pairs of |median residual| / MAD."""
    pairs: int = 0
    views: int = 0
    seconds: float = 0.0
    """Time the probe took."""

    @property
    def backend(self) -> str:
        """The medium backend ``auto`` resolves to."""
        return BACKEND_FOR[self.haze]

    def message(self) -> str:
        head = (
            f"haze probe ({self.seconds:.2f} s): {self.haze} haze -> medium backend {self.backend}, "
            f"confidence {self.confidence:.2f}"
        )
        if math.isnan(self.beta):
            return f"{head} ({self.reason})"
        return (
            f"{head} ({self.reason}; optical depth {self.optical_depth:.3f} "
            f"[{self.optical_depth_low:.3f}, {self.optical_depth_high:.3f}] at the median distance "
            f"{self.median_distance:.3g} (spread {self.distance_spread:.2f}), haze floor {self.haze_floor:.3f}, "
            f"pair variation F {self.variation_f:.1f} / effect {self.variation_effect:.2f}, {self.pairs} view pairs)"
        )

    def to_dict(self) -> dict:
        """JSON-ready (an unmeasured number is None, not NaN)."""
        out = {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in asdict(self).items()}
        return {**out, "backend": self.backend}


@dataclass
class _Observations:
    """What the views say about the seed points, gathered once for the fit and its bootstrap."""

    signed: np.ndarray  # [V, N] signed distance of each point's colour from the airlight
    dist: np.ndarray  # [V, N] camera distance, NaN where the view does not see the point
    floor: np.ndarray  # [V] median dark channel / airlight of each view

    @property
    def distance_spread(self) -> float:
        """75th / 25th percentile of the distances of every (view, visible point)."""
        lo, hi = np.nanquantile(self.dist, (0.25, 0.75))
        return float(hi / max(lo, 1e-12))


@dataclass
class _Pairs:
    """Per usable pair of views (a, b): the sufficient sums of the extinction fit and the samples."""

    a: np.ndarray  # [P] first view
    b: np.ndarray  # [P] second view
    sxy: np.ndarray  # [P] sum of distance difference x log-contrast difference
    sxx: np.ndarray  # [P] sum of squared distance differences
    xs: list[np.ndarray]
    ys: list[np.ndarray]


def _visible(points: torch.Tensor, cam, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices of the seed points in view and in front (a coarse z-buffer of the points themselves),
    their pixel coordinates [M, 2] and distances [M]."""
    pc, uv = project_points(points, cam.viewmats()[0].float(), cam.Ks()[0].float())
    ok = in_image(pc, uv, width, height, near=1e-6)  # [M]
    pc, uv = pc.numpy(), uv.numpy()
    idx = np.nonzero(ok.numpy())[0]
    px = uv[idx].astype(np.int64)  # [M, 2]
    z = pc[idx, 2]
    cell = max(max(width, height) // GRID_CELLS, 1)
    key = (px[:, 1] // cell) * (width // cell + 1) + px[:, 0] // cell
    front = np.full(int(key.max()) + 1 if len(key) else 1, np.inf)
    np.minimum.at(front, key, z)
    keep = z <= 1.1 * front[key]
    idx, px = idx[keep], px[keep]
    return idx, px, np.linalg.norm(pc[idx], axis=-1)


def probe_haze(
    dm: DataManager,
    views: list[int],
    points: torch.Tensor | None,
    seed: int = 0,
    dcp: dict[int, DCPResult] | None = None,
) -> HazeProbe:
    """Measure the training views (see the module docstring) and choose a medium backend.
    ``dcp``: dark-channel results already computed per view (estimated here where missing)."""
    start = time.perf_counter()
    probe = _probe(dm, views, points, seed, dcp or {})
    probe.seconds = time.perf_counter() - start
    return probe


def _observe(
    dm: DataManager, views: list[int], pts: torch.Tensor, dcps: dict[int, DCPResult]
) -> _Observations:
    v, n = len(views), len(pts)
    colour = np.full((v, n, 3), np.nan, np.float32)  # [V, N, 3] pixel colour of each visible point
    dist = np.full((v, n), np.nan, np.float32)  # [V, N]
    airlight = np.zeros((v, 3), np.float32)  # [V, 3]
    floor = np.zeros(v, np.float32)  # [V]
    for a, i in enumerate(views):
        img = dm.image(i).cpu().numpy()  # [H, W, 3]
        dcp = dcps[i] if i in dcps else estimate_dcp(img)
        airlight[a] = dcp.airlight
        floor[a] = float(np.median(dcp.dark)) / max(float(dcp.airlight.mean()), 1e-3)
        cam = dm.camera(i).to("cpu")
        idx, px, d = _visible(pts, cam, int(cam.width[0]), int(cam.height[0]))
        colour[a, idx] = img[px[:, 1], px[:, 0]]
        dist[a, idx] = d
    diff = colour - np.median(airlight, axis=0)  # [V, N, 3]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # points no view sees: all-NaN rows
        strength = np.nan_to_num(np.nanmean(np.abs(diff), axis=0))  # [N, 3]
    channel = strength.argmax(-1)  # [N] the channel farthest from the airlight, per point
    signed = np.take_along_axis(diff, np.broadcast_to(channel[None, :, None], (v, n, 1)), 2)[..., 0]  # [V, N]
    return _Observations(signed, dist, floor)


def _pairs(obs: _Observations) -> _Pairs:
    signed, dist = obs.signed, obs.dist
    log_mag = np.log(np.maximum(np.abs(signed), 1e-6))  # [V, N]
    a_s, b_s, sxy, sxx, xs, ys = [], [], [], [], [], []
    for a, b in itertools.combinations(range(len(dist)), 2):
        m = np.isfinite(dist[a]) & np.isfinite(dist[b])
        m &= (np.abs(signed[a]) > MIN_SIGNAL) & (np.abs(signed[b]) > MIN_SIGNAL)
        m &= np.sign(signed[a]) == np.sign(signed[b])
        if int(m.sum()) >= MIN_SHARED:
            y = (log_mag[a, m] - log_mag[b, m]).astype(np.float64)  # = tau_b - tau_a
            x = (dist[b, m] - dist[a, m]).astype(np.float64)
            a_s.append(a), b_s.append(b), xs.append(x), ys.append(y)
            sxy.append(float((x * y).sum())), sxx.append(float((x * x).sum()))
    return _Pairs(np.array(a_s, int), np.array(b_s, int), np.array(sxy), np.array(sxx), xs, ys)


def _says_clear(
    optical_depth_high: FloatOrArray, optical_depth: FloatOrArray, floor: FloatOrArray
) -> bool | np.ndarray:
    """Both measurements say "clear" and the fit is physically possible (floats, or arrays of
    bootstrap resamples, where each resample's own estimate serves as its upper end)."""
    return (
        (optical_depth_high < CLEAR_OPTICAL_DEPTH)
        & (optical_depth > -IMPOSSIBLE_OPTICAL_DEPTH)
        & (floor < CLEAR_HAZE_FLOOR)
    )


def _impossible(out: HazeProbe) -> bool:
    """A negative extinction that noise does not explain."""
    return out.optical_depth < -IMPOSSIBLE_OPTICAL_DEPTH and out.optical_depth_high < 0.0


def _bootstrap(
    obs: _Observations, pairs: _Pairs, median_distance: float, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Optical depth [B] and haze floor [B] over ``BOOTSTRAP`` resamples of the views (a pair counts
    as often as both its views were drawn)."""
    rng = np.random.default_rng(seed)
    v = len(obs.floor)
    taus, floors = [], []
    for _ in range(BOOTSTRAP):
        count = np.bincount(rng.integers(0, v, v), minlength=v)  # [V]
        w = (count[pairs.a] * count[pairs.b]).astype(np.float64)  # [P]
        den = float((w * pairs.sxx).sum())
        taus.append(float((w * pairs.sxy).sum()) / den * median_distance if den > 0 else math.nan)
        floors.append(float(np.median(np.repeat(obs.floor, count))))
    return np.array(taus), np.array(floors)


def _variation(pairs: _Pairs, beta: float) -> tuple[float, float]:
    """Median over pairs of F and of the effect size of the residuals around one extinction."""
    f_stats, effects = [], []
    for xp, yp in zip(pairs.xs, pairs.ys, strict=True):
        r = yp - beta * xp
        med = float(np.median(r))
        mad = 1.4826 * float(np.median(np.abs(r - med))) + 1e-6
        effects.append(abs(med) / mad)
        f_stats.append(len(r) * (med / mad) ** 2)
    return float(np.median(f_stats)), float(np.median(effects))


def _probe(
    dm: DataManager, views: list[int], points: torch.Tensor | None, seed: int, dcps: dict[int, DCPResult]
) -> HazeProbe:
    if points is None or len(points) < MIN_SHARED:
        return HazeProbe("unsure", "no seed points to measure the haze with", confidence=0.0)
    pts = points.detach().float().cpu()
    if len(pts) > MAX_POINTS:
        gen = torch.Generator().manual_seed(seed)
        pts = pts[torch.randperm(len(pts), generator=gen)[:MAX_POINTS]]
    if len(views) > MAX_VIEWS:
        views = [views[round(k * (len(views) - 1) / (MAX_VIEWS - 1))] for k in range(MAX_VIEWS)]
    obs = _observe(dm, views, pts, dcps)
    pairs = _pairs(obs)
    if len(pairs.a) < MIN_PAIRS:
        return HazeProbe(
            "unsure", f"only {len(pairs.a)} view pairs share enough seed points", confidence=0.0,
            pairs=len(pairs.a), views=len(views),
        )  # fmt: skip
    beta = float(pairs.sxy.sum() / max(float(pairs.sxx.sum()), 1e-12))
    median_distance = float(np.nanmedian(obs.dist))
    taus, floors = _bootstrap(obs, pairs, median_distance, seed)
    taus = np.where(np.isfinite(taus), taus, 0.0)
    lo, hi = (float(q) for q in np.quantile(taus, INTERVAL))
    f, effect = _variation(pairs, beta)
    out = HazeProbe(
        "homogeneous", "", beta=beta, median_distance=median_distance, optical_depth=beta * median_distance,
        optical_depth_low=lo, optical_depth_high=hi, haze_floor=float(np.median(obs.floor)),
        distance_spread=obs.distance_spread, variation_f=f, variation_effect=effect, pairs=len(pairs.a), views=len(views),
    )  # fmt: skip
    _classify(out, clear_share=float(_says_clear(taus, taus, floors).mean()))
    return out


def _classify(out: HazeProbe, clear_share: float) -> None:
    """Set ``haze``, ``reason`` and ``confidence`` of a measured probe."""
    if out.distance_spread < MIN_DISTANCE_SPREAD:
        out.haze, out.confidence = "unsure", 0.0
        out.reason = (
            f"the views see the seed points at too similar distances to measure extinction (spread "
            f"{out.distance_spread:.2f} < {MIN_DISTANCE_SPREAD:g}): keeping a medium"
        )
        return
    if _says_clear(out.optical_depth_high, out.optical_depth, out.haze_floor):
        if clear_share >= MIN_CONFIDENCE:
            out.haze, out.confidence = "none", clear_share
            out.reason = (
                f"clear capture: optical depth below {CLEAR_OPTICAL_DEPTH:g} (T > "
                f"{math.exp(-CLEAR_OPTICAL_DEPTH):.2f}) at a typical distance and haze floor below "
                f"{CLEAR_HAZE_FLOOR:g}"
            )
        else:
            out.haze, out.confidence = "unsure", 1.0 - clear_share
            out.reason = (
                f"looks clear but only {clear_share:.0%} of resampled views agree (< {MIN_CONFIDENCE:.0%}): "
                "keeping a medium"
            )
        return
    out.confidence = 1.0 - clear_share
    if _impossible(out):
        out.haze = "unsure"
        out.reason = (
            f"impossible estimate: optical depth {out.optical_depth:.3f} < -{IMPOSSIBLE_OPTICAL_DEPTH:g} "
            f"(negative extinction, T {math.exp(-out.optical_depth):.2f} > 1): the capture breaks the fit's "
            "assumptions, keeping a medium"
        )
    elif out.optical_depth_high < CLEAR_OPTICAL_DEPTH:
        out.haze = "unsure"
        out.reason = (
            f"the pair fit finds little haze but the dark channel's haze floor {out.haze_floor:.3f} >= "
            f"{CLEAR_HAZE_FLOOR:g} disagrees: keeping a medium"
        )
    elif out.variation_f > VARYING_F and out.variation_effect > VARYING_EFFECT:
        out.haze = "varying"
        out.reason = (
            f"view pairs disagree with one extinction "
            f"(F {out.variation_f:.1f} > {VARYING_F:g}, effect {out.variation_effect:.2f} > {VARYING_EFFECT:g})"
        )
    else:
        held = []  # only the conditions that hold (either suffices)
        if out.variation_f <= VARYING_F:
            held.append(f"F {out.variation_f:.1f} <= {VARYING_F:g}")
        if out.variation_effect <= VARYING_EFFECT:
            held.append(f"effect {out.variation_effect:.2f} <= {VARYING_EFFECT:g}")
        out.reason = f"one extinction explains every view pair ({', '.join(held)})"
