"""The ground and the road on it: a hilly terrain heightfield and the smooth centre line the car drives.

Both are pure functions of their random generator, and the road is drawn segment after segment, so a
longer road starts exactly like a shorter one (a short sequence is a prefix of a longer one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from vcr_odom.synth.mesh import FloatArray

ROAD_STEP = 0.5
"""Spacing (m) of the road's centre-line samples: fine enough that nearest-sample offsets are exact to mm."""
ROAD_CHUNK = 1000.0
"""The road is generated in whole kilometres, so a short sequence is a prefix of a longer one."""
PREROLL = 150.0
"""Road before the first frame, so the sensor sees a street behind it too."""

Waves = tuple[FloatArray, FloatArray, FloatArray]
"""Plane waves: wave vectors ``(K, 2)``, amplitudes ``(K,)`` and phases ``(K,)``."""


@dataclass(frozen=True)
class Terrain:
    """Smooth hills (a tilt plus long plane waves), centimetre ripples, and rougher ground off the road.

    Roads follow :meth:`base_height` plus :meth:`ripples` (an uneven surface that makes the car pitch
    and roll a little, as on real roads); yards, fields and verges add :meth:`bumps`.
    """

    tilt: FloatArray
    wave_vectors: FloatArray
    wave_amplitudes: FloatArray
    wave_phases: FloatArray
    bump_vectors: FloatArray
    bump_amplitudes: FloatArray
    bump_phases: FloatArray
    ripple_vectors: FloatArray
    ripple_amplitudes: FloatArray
    ripple_phases: FloatArray

    @staticmethod
    def random(rng: np.random.Generator) -> Terrain:
        """Grades up to about 6 %: a 0-2 % tilt plus four waves of 120-600 m wavelength."""
        tilt_angle = rng.uniform(0.0, 2.0 * math.pi)
        tilt = rng.uniform(0.0, 0.02) * np.array([math.cos(tilt_angle), math.sin(tilt_angle)])

        def waves(count: int, wavelengths: tuple[float, float], grade: tuple[float, float]) -> Waves:
            angle = rng.uniform(0.0, 2.0 * math.pi, count)
            wavelength = rng.uniform(*wavelengths, count)
            k = (2.0 * math.pi / wavelength)[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1)
            amplitude = rng.uniform(*grade, count) * wavelength / (2.0 * math.pi)
            return k, amplitude, rng.uniform(0.0, 2.0 * math.pi, count)

        wk, wa, wp = waves(4, (120.0, 600.0), (0.004, 0.012))
        bk, ba, bp = waves(4, (12.0, 45.0), (0.03, 0.08))
        rk, ra, rp = waves(3, (5.0, 16.0), (0.003, 0.007))
        return Terrain(tilt, wk, wa, wp, bk, ba, bp, rk, ra, rp)

    def base_height(self, xy: ArrayLike) -> FloatArray:
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        return xy @ self.tilt + np.sin(xy @ self.wave_vectors.T + self.wave_phases) @ self.wave_amplitudes

    def bumps(self, xy: ArrayLike) -> FloatArray:
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        return np.sin(xy @ self.bump_vectors.T + self.bump_phases) @ self.bump_amplitudes

    def ripples(self, xy: ArrayLike) -> FloatArray:
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        return np.sin(xy @ self.ripple_vectors.T + self.ripple_phases) @ self.ripple_amplitudes


@dataclass(frozen=True)
class Road:
    """The driven centre line, sampled every :data:`ROAD_STEP` metres from station 0."""

    xy: FloatArray
    heading: FloatArray
    curvature: FloatArray

    @property
    def length(self) -> float:
        return (len(self.xy) - 1) * ROAD_STEP

    def sample(self, stations: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position ``(N, 2)``, heading and curvature at arbitrary stations (linear interpolation)."""
        s = np.clip(np.atleast_1d(np.asarray(stations, dtype=np.float64)), 0.0, self.length) / ROAD_STEP
        i = np.minimum(s.astype(np.int64), len(self.xy) - 2)
        f = s - i
        xy = self.xy[i] * (1.0 - f)[:, None] + self.xy[i + 1] * f[:, None]
        heading = self.heading[i] * (1.0 - f) + self.heading[i + 1] * f
        curvature = self.curvature[i] * (1.0 - f) + self.curvature[i + 1] * f
        return xy, heading, curvature

    def offset(self, stations: ArrayLike, lateral: ArrayLike) -> FloatArray:
        """Points ``lateral`` metres left (negative: right) of the centre line at ``stations``."""
        xy, heading, _ = self.sample(stations)
        normal = np.stack([-np.sin(heading), np.cos(heading)], 1)
        return xy + normal * np.asarray(lateral, dtype=np.float64).reshape(-1, 1)


def smooth(values: FloatArray, sigma_samples: float) -> FloatArray:
    """Gaussian smoothing with edge padding: turns piecewise curvature into clothoid-like transitions."""
    half = int(3 * sigma_samples)
    kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma_samples) ** 2)
    kernel /= kernel.sum()
    padded = np.pad(values, half, mode="edge")
    return np.convolve(padded, kernel, mode="valid")


@dataclass(frozen=True)
class RoadShape:
    """How a road bends (metres, degrees): straights, then either a sharp (intersection-like) turn
    with probability ``sharp_prob`` or a gentle bend. The defaults are the suburban street."""

    straight: tuple[float, float] = (40.0, 220.0)
    sharp_prob: float = 0.45
    sharp_angle: tuple[float, float] = (60.0, 100.0)
    sharp_radius: tuple[float, float] = (16.0, 35.0)
    gentle_angle: tuple[float, float] = (10.0, 45.0)
    gentle_radius: tuple[float, float] = (60.0, 300.0)


def make_road(rng: np.random.Generator, length: float, shape: RoadShape = RoadShape()) -> Road:
    """Straights with slight drift, gentle bends and sharp (intersection-like) turns, smoothly joined.

    Segments are drawn one after another, so a longer road starts exactly like a shorter one.
    """
    n = math.ceil(length / ROAD_STEP) + 1
    pieces: list[FloatArray] = [np.zeros(int(PREROLL / ROAD_STEP) + 60)]
    total = len(pieces[0])
    while total < n + 100:
        straight = rng.uniform(*shape.straight)
        pieces.append(np.full(int(straight / ROAD_STEP), rng.normal(0.0, 1.0 / 1500.0)))
        if rng.random() < shape.sharp_prob:
            angle, radius = math.radians(rng.uniform(*shape.sharp_angle)), rng.uniform(*shape.sharp_radius)
        else:
            angle, radius = math.radians(rng.uniform(*shape.gentle_angle)), rng.uniform(*shape.gentle_radius)
        sign = 1.0 if rng.random() < 0.5 else -1.0
        pieces.append(np.full(max(1, int(radius * angle / ROAD_STEP)), sign / radius))
        total = sum(len(p) for p in pieces)
    curvature = smooth(np.concatenate(pieces), sigma_samples=6.0 / ROAD_STEP)[:n]
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (curvature[1:] + curvature[:-1]) * ROAD_STEP)])
    mid = heading[:-1] + 0.5 * np.diff(heading)
    steps = np.stack([np.cos(mid), np.sin(mid)], 1) * ROAD_STEP
    xy = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    return Road(xy, heading, curvature)
