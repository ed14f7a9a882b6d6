"""Procedural scene layouts (street, courtyard, room, field), randomised by a seed.

Each layout places primitives with procedural materials, sets the sun and sky, names a
reference viewing distance (which scales the haze presets) and offers a walk and an orbit path.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from components.synth.geometry import Box, Cylinder, Material, Plane, SceneGeometry, Sphere
from components.synth.medium import MediumContext
from components.synth.trajectories import OrbitPath, WalkPath

LAYOUTS: tuple[str, ...] = ("street", "courtyard", "room", "field")


@dataclass(frozen=True)
class Sky:
    """Clean sky radiance: vertical gradient plus a sun disc and glow."""

    horizon: tuple[float, float, float] = (0.78, 0.84, 0.92)
    zenith: tuple[float, float, float] = (0.32, 0.52, 0.85)
    sun_color: tuple[float, float, float] = (1.0, 0.95, 0.85)


@dataclass
class Layout:
    name: str
    geometry: SceneGeometry
    sun: tuple[float, float, float]
    """Unit vector towards the sun (indoors: towards the window / main light)."""
    ref_distance: float
    """Typical viewing distance (m); scales the haze presets."""
    far: float
    """Far bound (m): sky rays are marched this far, and farther hits count as sky."""
    fog_height: float
    bounds_lo: tuple[float, float, float]
    bounds_hi: tuple[float, float, float]
    walk: WalkPath
    orbit: OrbitPath
    default_trajectory: str
    sky: Sky | None = field(default_factory=Sky)
    """None indoors (every ray hits a wall)."""
    shadows: bool = True
    ambient: float = 0.45
    diffuse: float = 0.75

    def medium_context(self) -> MediumContext:
        return MediumContext(self.ref_distance, self.bounds_lo, self.bounds_hi, self.fog_height, self.sun)


def _unit(*v: float) -> tuple[float, float, float]:
    a = np.asarray(v, np.float64)
    a /= np.linalg.norm(a)
    return (float(a[0]), float(a[1]), float(a[2]))


def _sun(azimuth_deg: float, elevation_deg: float) -> tuple[float, float, float]:
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return _unit(math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))


class _Builder:
    """Collects materials and primitives; ``mat`` returns a material index."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.geo = SceneGeometry(materials=[])

    def mat(self, texture: str, a, b, scale: float = 1.0) -> int:
        self.geo.materials.append(
            Material(
                texture, tuple(map(float, a)), tuple(map(float, b)), float(scale), len(self.geo.materials)
            )
        )
        return len(self.geo.materials) - 1

    def jitter(self, color, amount: float = 0.06) -> tuple[float, ...]:
        return tuple(float(np.clip(c + self.rng.uniform(-amount, amount), 0, 1)) for c in color)

    def ground(self, m: int, z: float = 0.0) -> None:
        self.geo.planes.append(Plane((0.0, 0.0, 1.0), z, m))

    def box(self, lo, hi, m: int) -> None:
        self.geo.boxes.append(Box(tuple(map(float, lo)), tuple(map(float, hi)), m))

    def sphere(self, c, r: float, m: int) -> None:
        self.geo.spheres.append(Sphere(tuple(map(float, c)), float(r), m))

    def cylinder(self, x: float, y: float, r: float, z0: float, z1: float, m: int) -> None:
        self.geo.cylinders.append(Cylinder((float(x), float(y)), float(r), float(z0), float(z1), m))

    def tree(self, x: float, y: float, scale: float, trunk: int, crown: int) -> None:
        self.cylinder(x, y, 0.12 * scale, 0.0, 2.2 * scale, trunk)
        self.sphere((x, y, 2.2 * scale + 0.9 * scale), 1.2 * scale, crown)


FACADES = [
    ("bricks", (0.55, 0.25, 0.18), (0.85, 0.80, 0.72), 0.9),
    ("bricks", (0.70, 0.55, 0.40), (0.90, 0.88, 0.82), 0.8),
    ("tiles", (0.80, 0.76, 0.66), (0.20, 0.22, 0.28), 2.2),
    ("noise", (0.85, 0.80, 0.68), (0.60, 0.55, 0.45), 1.5),
    ("stripes", (0.92, 0.90, 0.85), (0.55, 0.60, 0.68), 1.2),
]


def street(rng: np.random.Generator) -> Layout:
    """A street running along +y between two rows of buildings, open to the sky at the far end."""
    b = _Builder(rng)
    asphalt = b.mat("noise", (0.18, 0.18, 0.19), (0.40, 0.40, 0.40), 2.0)
    b.ground(asphalt)
    pavement = b.mat("tiles", (0.62, 0.60, 0.56), (0.35, 0.34, 0.32), 0.6)
    paint = b.mat("plain", (0.95, 0.95, 0.92), (0.80, 0.80, 0.78))
    for side in (-1, 1):
        x0, x1 = sorted((side * 4.0, side * 7.0))
        b.box((x0, -10, 0), (x1, 90, 0.15), pavement)
    for y in np.arange(-8.0, 88.0, 6.0):
        b.box((-0.1, y, 0), (0.1, y + 3.0, 0.02), paint)
    facades = [b.mat(t, b.jitter(a), b.jitter(c), s) for t, a, c, s in FACADES]
    for side in (-1, 1):
        y = -10.0
        while y < 90.0:
            w = rng.uniform(6, 14)
            h = rng.uniform(6, 22)
            depth = rng.uniform(8, 14)
            x0, x1 = sorted((side * 7.0, side * (7.0 + depth)))
            b.box((x0, y, 0), (x1, y + w - 0.3, h), facades[int(rng.integers(len(facades)))])
            y += w
    metal = b.mat("stripes", (0.15, 0.16, 0.18), (0.35, 0.36, 0.40), 0.05)
    lamp = b.mat("plain", (0.98, 0.95, 0.80), (0.85, 0.82, 0.70))
    for k, y in enumerate(np.arange(3.0, 80.0, 11.0)):
        x = 4.6 * (1 if k % 2 else -1)
        b.cylinder(x, y, 0.08, 0.0, 4.5, metal)
        b.sphere((x, y, 4.6), 0.22, lamp)
    bark = b.mat("stripes", (0.30, 0.20, 0.12), (0.45, 0.32, 0.20), 0.08)
    leaves = b.mat("noise", (0.10, 0.35, 0.08), (0.45, 0.65, 0.20), 0.5)
    for y in (8.0, 21.0, 37.0, 55.0):
        b.tree(-5.5 if y % 2 else 5.5, y + rng.uniform(-1, 1), rng.uniform(0.9, 1.3), bark, leaves)
    car = b.mat("checker", b.jitter((0.60, 0.10, 0.10)), (0.75, 0.20, 0.18), 0.5)
    glass = b.mat("noise", (0.10, 0.12, 0.16), (0.30, 0.35, 0.42), 0.4)
    for y, x in ((13.0, -2.9), (30.0, 2.9)):
        b.box((x - 0.9, y, 0.2), (x + 0.9, y + 4.2, 1.1), car)
        b.box((x - 0.8, y + 1.0, 1.1), (x + 0.8, y + 3.0, 1.6), glass)
    stone = b.mat("noise", (0.55, 0.52, 0.48), (0.75, 0.72, 0.66), 0.3)
    for y in np.arange(5.0, 50.0, 4.5):
        b.cylinder(3.8, y, 0.1, 0.0, 0.9, stone)
    for _ in range(6):
        x = rng.choice([-1, 1]) * rng.uniform(4.5, 6.5)
        y = rng.uniform(2, 50)
        s = rng.uniform(0.5, 1.0)
        b.box((x - s / 2, y - s / 2, 0.15), (x + s / 2, y + s / 2, 0.15 + s), facades[1])
    b.sphere((-2.0, 17.0, 0.45), 0.45, stone)
    return Layout(
        name="street",
        geometry=b.geo,
        sun=_sun(70.0, 16.0),
        ref_distance=15.0,
        far=150.0,
        fog_height=4.0,
        bounds_lo=(-8.0, -5.0, 0.0),
        bounds_hi=(8.0, 70.0, 15.0),
        walk=WalkPath(start=(0.8, 0.0, 1.6), end=(0.8, 24.0, 1.6)),
        orbit=OrbitPath(target=(0.0, 16.0, 1.0), radius=3.2, height=1.8, arc_deg=180.0),
        default_trajectory="walk",
    )


def courtyard(rng: np.random.Generator) -> Layout:
    """A walled square with a fountain, columns and crates in the middle."""
    b = _Builder(rng)
    b.ground(b.mat("tiles", (0.72, 0.68, 0.60), (0.45, 0.42, 0.38), 1.0))
    facades = [b.mat(t, b.jitter(a), b.jitter(c), s) for t, a, c, s in FACADES]
    half = 13.0
    for side in range(4):
        segs = np.sort(rng.uniform(-half, half, 2))
        cuts = [-half - 1, *segs, half + 1]
        for a, c in zip(cuts[:-1], cuts[1:], strict=True):
            h = rng.uniform(7, 12)
            m = facades[int(rng.integers(len(facades)))]
            if side == 0:
                b.box((a, half, 0), (c, half + 1, h), m)
            elif side == 1:
                b.box((a, -half - 1, 0), (c, -half, h), m)
            elif side == 2:
                b.box((half, a, 0), (half + 1, c, h), m)
            else:
                b.box((-half - 1, a, 0), (-half, c, h), m)
    stone = b.mat("noise", (0.62, 0.60, 0.55), (0.85, 0.82, 0.76), 0.4)
    marble = b.mat("checker", (0.90, 0.88, 0.84), (0.55, 0.55, 0.58), 0.25)
    b.cylinder(0, 0, 2.0, 0.0, 0.6, stone)
    b.cylinder(0, 0, 0.3, 0.6, 2.2, marble)
    b.sphere((0, 0, 2.6), 0.5, marble)
    column = b.mat("stripes", (0.88, 0.86, 0.80), (0.70, 0.68, 0.62), 0.15)
    for k in range(8):
        a = 2 * math.pi * (k + 0.5) / 8
        b.cylinder(9.5 * math.cos(a), 9.5 * math.sin(a), 0.35, 0.0, 4.0, column)
    wood = b.mat("stripes", (0.45, 0.30, 0.15), (0.65, 0.48, 0.28), 0.12)
    for _ in range(7):  # kept off the orbit ring (r ~ 6.5) so no crate fills a view
        a = rng.uniform(0, 2 * math.pi)
        r = rng.uniform(3.0, 4.8) if rng.random() < 0.6 else rng.uniform(8.3, 11.0)
        s = rng.uniform(0.6, 1.3)
        x, y = r * math.cos(a), r * math.sin(a)
        b.box((x - s / 2, y - s / 2, 0), (x + s / 2, y + s / 2, s), wood)
    for _ in range(4):
        a = rng.uniform(0, 2 * math.pi)
        r = rng.uniform(3.0, 4.8)
        s = rng.uniform(0.4, 0.8)
        b.sphere((r * math.cos(a), r * math.sin(a), s), s, stone)
    bark = b.mat("stripes", (0.30, 0.20, 0.12), (0.45, 0.32, 0.20), 0.08)
    leaves = b.mat("noise", (0.10, 0.35, 0.08), (0.45, 0.65, 0.20), 0.5)
    b.tree(-10.5, 10.5, 1.6, bark, leaves)
    b.tree(10.5, -10.0, 1.4, bark, leaves)
    return Layout(
        name="courtyard",
        geometry=b.geo,
        sun=_sun(rng.uniform(0, 360), 32.0),
        ref_distance=10.0,
        far=120.0,
        fog_height=2.5,
        bounds_lo=(-13.0, -13.0, 0.0),
        bounds_hi=(13.0, 13.0, 12.0),
        walk=WalkPath(start=(-8.0, -7.0, 1.6), end=(7.0, -6.0, 1.6), yaw_deg=20.0),
        orbit=OrbitPath(target=(0.0, 0.0, 1.2), radius=6.5, height=2.2),
        default_trajectory="orbit",
    )


def room(rng: np.random.Generator) -> Layout:
    """An indoor room (no sky) with furniture; the main light comes from a window direction."""
    b = _Builder(rng)
    floor = b.mat("stripes", (0.55, 0.36, 0.20), (0.70, 0.50, 0.30), 0.18)
    b.ground(floor)
    b.geo.planes.append(Plane((0.0, 0.0, 1.0), 3.2, b.mat("plain", (0.92, 0.92, 0.90), (0.80, 0.80, 0.78))))
    walls = [
        b.mat("noise", (0.85, 0.80, 0.70), (0.70, 0.66, 0.58), 0.6),
        b.mat("bricks", (0.60, 0.30, 0.22), (0.88, 0.85, 0.80), 0.5),
        b.mat("tiles", (0.55, 0.65, 0.70), (0.85, 0.88, 0.90), 0.4),
        b.mat("checker", (0.82, 0.78, 0.70), (0.60, 0.56, 0.50), 0.7),
    ]
    b.geo.planes.append(Plane((1.0, 0.0, 0.0), 5.0, walls[0]))
    b.geo.planes.append(Plane((1.0, 0.0, 0.0), -5.0, walls[1]))
    b.geo.planes.append(Plane((0.0, 1.0, 0.0), 4.0, walls[2]))
    b.geo.planes.append(Plane((0.0, 1.0, 0.0), -4.0, walls[3]))
    wood = b.mat("stripes", (0.40, 0.25, 0.12), (0.58, 0.40, 0.22), 0.07)
    b.box((-0.8, -0.5, 0.72), (0.8, 0.5, 0.78), wood)  # table
    for x in (-0.7, 0.7):
        for y in (-0.4, 0.4):
            b.cylinder(x, y, 0.04, 0.0, 0.72, wood)
    shelf = b.mat("checker", (0.30, 0.32, 0.40), (0.60, 0.62, 0.70), 0.15)
    b.box((-4.9, -2.5, 0), (-4.4, 1.0, 2.0), shelf)
    b.box((2.0, 3.4, 0), (4.5, 3.9, 1.0), wood)
    fabric = b.mat("noise", (0.20, 0.30, 0.55), (0.45, 0.55, 0.80), 0.15)
    b.box((1.5, -3.8, 0), (4.0, -2.8, 0.5), fabric)  # sofa
    b.box((1.5, -3.95, 0.5), (4.0, -3.6, 1.0), fabric)
    ball = b.mat("checker", (0.90, 0.20, 0.15), (0.95, 0.90, 0.30), 0.1)
    b.sphere((0.3, 0.1, 0.93), 0.15, ball)
    b.sphere((-2.5, 2.2, 0.3), 0.3, ball)
    vase = b.mat("stripes", (0.25, 0.50, 0.45), (0.85, 0.85, 0.80), 0.04)
    b.cylinder(-0.4, -0.1, 0.1, 0.78, 1.1, vase)
    b.cylinder(-3.5, -3.2, 0.25, 0.0, 2.8, b.mat("noise", (0.8, 0.8, 0.78), (0.6, 0.6, 0.58), 0.3))
    for _ in range(5):
        x, y = rng.uniform(-4, 4), rng.uniform(-3.4, 3.4)
        if abs(x) < 1.3 and abs(y) < 1.0:
            continue
        s = rng.uniform(0.3, 0.6)
        b.box((x - s / 2, y - s / 2, 0), (x + s / 2, y + s / 2, s), wood)
    return Layout(
        name="room",
        geometry=b.geo,
        sun=_sun(rng.uniform(0, 360), 25.0),
        ref_distance=5.0,
        far=20.0,
        fog_height=1.0,
        bounds_lo=(-5.0, -4.0, 0.0),
        bounds_hi=(5.0, 4.0, 3.2),
        walk=WalkPath(start=(-3.5, -2.5, 1.5), end=(1.0, -2.0, 1.5), sway=0.15, yaw_deg=15.0),
        orbit=OrbitPath(target=(0.0, 0.0, 0.8), radius=2.8, height=1.6, height_jitter=0.15),
        default_trajectory="orbit",
        sky=None,
        shadows=False,
        ambient=0.55,
        diffuse=0.5,
    )


def _off_ring(r: float, ring: float, half_width: float = 1.6) -> float:
    """``r`` moved outwards off the camera ring, so no object sits right in front of a camera."""
    return r + 2 * half_width if abs(r - ring) < half_width else r


def open_field(rng: np.random.Generator) -> Layout:
    """Grassland with a monument, trees, rocks and a barn at increasing distances: lots of horizon."""
    b = _Builder(rng)
    b.ground(b.mat("noise", (0.22, 0.38, 0.12), (0.50, 0.60, 0.25), 3.0))
    stone = b.mat("noise", (0.50, 0.48, 0.45), (0.78, 0.75, 0.70), 0.35)
    marble = b.mat("checker", (0.90, 0.88, 0.84), (0.45, 0.45, 0.50), 0.3)
    b.box((-0.6, -0.6, 0), (0.6, 0.6, 1.6), marble)
    b.sphere((0, 0, 2.1), 0.5, stone)
    bark = b.mat("stripes", (0.30, 0.20, 0.12), (0.45, 0.32, 0.20), 0.08)
    leaves = b.mat("noise", (0.08, 0.30, 0.06), (0.40, 0.60, 0.18), 0.5)
    for _ in range(14):
        a, r = rng.uniform(0, 2 * math.pi), rng.uniform(12, 80)
        b.tree(r * math.cos(a), r * math.sin(a), rng.uniform(1.5, 3.0), bark, leaves)
    for _ in range(10):
        a, r = rng.uniform(0, 2 * math.pi), _off_ring(rng.uniform(3, 40), 8.0)
        s = rng.uniform(0.3, 1.2)
        b.sphere((r * math.cos(a), r * math.sin(a), 0.3 * s), s, stone)
    hay = b.mat("stripes", (0.75, 0.62, 0.30), (0.90, 0.80, 0.45), 0.05)
    for _ in range(6):
        a, r = rng.uniform(0, 2 * math.pi), _off_ring(rng.uniform(5, 30), 8.0)
        b.cylinder(r * math.cos(a), r * math.sin(a), 0.7, 0.0, 1.3, hay)
    barn = b.mat("stripes", (0.60, 0.12, 0.10), (0.75, 0.25, 0.18), 0.3)
    a = rng.uniform(0, 2 * math.pi)
    cx, cy = 30 * math.cos(a), 30 * math.sin(a)
    b.box((cx - 5, cy - 4, 0), (cx + 5, cy + 4, 5), barn)
    b.box(
        (cx - 5.3, cy - 4.3, 5),
        (cx + 5.3, cy + 4.3, 5.6),
        b.mat("tiles", (0.3, 0.3, 0.32), (0.15, 0.15, 0.16), 0.5),
    )
    return Layout(
        name="field",
        geometry=b.geo,
        sun=_sun(rng.uniform(0, 360), 20.0),
        ref_distance=20.0,
        far=200.0,
        fog_height=3.0,
        bounds_lo=(-60.0, -60.0, 0.0),
        bounds_hi=(60.0, 60.0, 20.0),
        walk=WalkPath(start=(-18.0, -6.0, 1.7), end=(-2.0, -4.0, 1.7), yaw_deg=15.0),
        orbit=OrbitPath(target=(0.0, 0.0, 1.0), radius=8.0, height=2.0),
        default_trajectory="orbit",
    )


_BUILDERS: dict[str, Callable[[np.random.Generator], Layout]] = {
    "street": street,
    "courtyard": courtyard,
    "room": room,
    "field": open_field,
}


def make_layout(name: str, seed: int = 0) -> Layout:
    """Layout ``name`` with its random choices drawn from ``seed`` (same seed, same scene)."""
    if name not in _BUILDERS:
        raise ValueError(f"unknown layout {name!r}; use one of {', '.join(LAYOUTS)}")
    return _BUILDERS[name](np.random.default_rng([seed, LAYOUTS.index(name)]))
