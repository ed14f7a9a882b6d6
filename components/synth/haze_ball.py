"""A ball that confines synthetic haze to the part of a real capture its seed points cover.

A real photo set hazed with a depth run's maps puts haze in front of a background the photos
never located (statue: a wall at 5-22 units behind SfM points at 1.2-1.5), so the haze there
depends on a depth no method can check. Clamping each view's depth (``--max-depth-factor``) keeps the haze
recoverable, but then every view marches to its own clamp: the haze is no longer one 3D field,
and a 3D method that locates the background where the photos' parallax puts it cannot agree with
it. A haze field that is zero outside a ball around the seed points is one 3D medium, seen the
same from every view, whatever the background's depth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BALL_QUANTILE = 0.9
"""The ball's radius is a multiple of this quantile of the seed points' distance from their median."""


@dataclass(frozen=True)
class HazeBall:
    centre: np.ndarray  # [3] dataset units
    radius: float

    @staticmethod
    def around(points: np.ndarray, factor: float) -> HazeBall:
        """The ball centred on the median of ``points`` [M, 3], of radius ``factor`` times their
        ``BALL_QUANTILE`` distance from it (a median and a quantile: SfM outliers move neither)."""
        centre = np.median(points, axis=0)
        reach = float(np.quantile(np.linalg.norm(points - centre, axis=1), BALL_QUANTILE))
        return HazeBall(centre, factor * reach)

    def contains(self, x: np.ndarray) -> np.ndarray:
        """Whether each point [..., 3] lies inside the ball [...]."""
        return np.linalg.norm(x - self.centre, axis=-1) < self.radius

    def chord(self, o: np.ndarray, d: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the rays from ``o`` [3] along unit ``d`` [..., 3] enter the ball within their first
        ``dist`` [...] and how far they run inside it: (entry distance [...], length [...]); a ray
        that misses the ball, or ends before it, has length 0."""
        oc = o - self.centre  # [3]
        b = d @ oc  # [...]
        disc = b * b - (oc @ oc - self.radius**2)  # [...] quarter discriminant of |o + s d - c|^2 = r^2
        root = np.sqrt(np.maximum(disc, 0.0))
        enter = np.clip(-b - root, 0.0, dist)
        leave = np.clip(-b + root, 0.0, dist)
        return enter, np.where(disc > 0.0, leave - enter, 0.0)
