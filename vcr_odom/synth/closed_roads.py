"""Closed streets for routes that come back: a rounded irregular loop, and a figure eight that crosses
itself once.

Why: loop closure needs drives that return to places they have seen, and a closed street is the
simplest world where that happens with exact ground truth. Each lap is a pure function of its
generator and its perimeter (the perimeter is sized to the drive by :mod:`~vcr_odom.synth.routes`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from vcr_odom.synth.mesh import FloatArray
from vcr_odom.synth.paths import resample
from vcr_odom.synth.road import ROAD_STEP, Road

DENSE = 4000
"""Points the shapes are drawn with before they are resampled every ROAD_STEP metres."""


@dataclass(frozen=True)
class SelfCrossing:
    """Where a lap crosses itself: the two stations and the angle between the directions (deg)."""

    first: float
    second: float
    angle_deg: float


@dataclass(frozen=True)
class Lap:
    """One lap of a closed street (``road.xy[-1] == road.xy[0]``), where it crosses itself, the
    lap station where the drive's first frame should be, and for a loop the corners ``(K, 2)``
    (counter-clockwise, round the origin) of the polygon its road rounds off."""

    road: Road
    crossings: tuple[SelfCrossing, ...]
    start: float
    corners: FloatArray | None = None

    @property
    def perimeter(self) -> float:
        return self.road.length


def _scaled_lap(xy: FloatArray, perimeter: float) -> tuple[Road, float]:
    """A dense closed polyline (first point not repeated) scaled to ``perimeter`` and resampled,
    and the scale it was drawn at."""
    ring = np.vstack([xy, xy[:1]])
    length = float(np.linalg.norm(np.diff(ring, axis=0), axis=1).sum())
    steps = max(8, round(perimeter / ROAD_STEP))
    scale = steps * ROAD_STEP / length
    road, _ = resample(ring * scale, closed=True)
    return road, scale


def _periodic_gaussian(xy: FloatArray, sigma_points: float) -> FloatArray:
    """Smooth a closed polyline of equally spaced points (rounds a polygon's corners)."""
    half = min(int(4 * sigma_points), len(xy) - 1)
    kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma_points) ** 2)
    kernel /= kernel.sum()
    padded = np.vstack([xy[len(xy) - half :], xy, xy[:half]])
    return np.column_stack([np.convolve(padded[:, k], kernel, mode="valid") for k in (0, 1)])


def _equal_spacing(ring: FloatArray, count: int) -> FloatArray:
    """``count`` points equally spaced by arc length along a closed polyline (first point repeated last)."""
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ring, axis=0), axis=1))])
    at = np.linspace(0.0, along[-1], count, endpoint=False)
    return np.column_stack([np.interp(at, along, ring[:, 0]), np.interp(at, along, ring[:, 1])])


def loop_lap(rng: np.random.Generator, perimeter: float) -> Lap:
    """A rounded, irregular loop: 4-6 corners round a circle (jittered angles, radii +-25 %) with
    corners rounded over 4-7 % of the perimeter, driven either way round."""
    corners = int(rng.integers(4, 7))
    angle = (np.arange(corners) + rng.uniform(-0.25, 0.25, corners)) * 2.0 * math.pi / corners
    angle += rng.uniform(0.0, 2.0 * math.pi)
    radius = rng.uniform(0.75, 1.25, corners)
    polygon = np.column_stack([radius * np.cos(angle), radius * np.sin(angle)])
    dense = _equal_spacing(np.vstack([polygon, polygon[:1]]), DENSE)
    rounded = _periodic_gaussian(dense, rng.uniform(0.04, 0.07) * DENSE)
    if rng.random() < 0.5:
        rounded = rounded[::-1]
    shift = int(rng.integers(0, DENSE))  # where station 0 (the zones' seam) lies
    road, scale = _scaled_lap(np.roll(rounded, -shift, axis=0), perimeter)
    return Lap(road, (), float(rng.uniform(0.0, road.length)), polygon * scale)


def figure8_lap(rng: np.random.Generator, perimeter: float) -> Lap:
    """A figure eight (a lemniscate of Gerono with lobes of unequal size and a slight wobble) that
    crosses itself once at 90-110 deg; station 0 lies at the tip of a lobe, far from the crossing,
    and the drive starts a tenth of a lap before the crossing."""
    aspect = rng.uniform(0.7, 1.0)  # lobe height / length: the crossing angle is 180 - 2 atan(aspect)
    skew = rng.uniform(-0.2, 0.2)
    wobble, phase = rng.uniform(0.0, 0.04), rng.uniform(0.0, 2.0 * math.pi)
    t = math.pi / 2.0 + np.linspace(0.0, 2.0 * math.pi, DENSE, endpoint=False)
    x = np.sin(t) * (1.0 + skew * np.sin(t))
    y = aspect * np.sin(t) * np.cos(t) * (1.0 + wobble * np.sin(3.0 * t + phase))
    turn = rng.uniform(0.0, 2.0 * math.pi)
    xy = np.column_stack([x, y]) @ np.array(
        [[math.cos(turn), math.sin(turn)], [-math.sin(turn), math.cos(turn)]]
    )
    if rng.random() < 0.5:
        xy = np.vstack([xy[:1], xy[:0:-1]])  # the other way round, still from the tip
    road, _ = _scaled_lap(xy, perimeter)
    crossings = self_crossings(road)
    start = (crossings[0].first - 0.1 * road.length) % road.length if crossings else 0.0
    return Lap(road, crossings, float(start))


def self_crossings(road: Road, min_apart: float = 0.2) -> tuple[SelfCrossing, ...]:
    """Where a lap passes within a step of itself at stations at least ``min_apart`` of the lap
    apart (one entry per crossing, at the closest pair of samples)."""
    n = len(road.xy) - 1
    tree = cKDTree(road.xy[:n])
    found: list[tuple[float, int, int]] = []
    for i, j in sorted(tree.query_pairs(2.0 * ROAD_STEP)):
        gap = min(j - i, n - (j - i))
        if gap < min_apart * n:
            continue
        distance = float(np.linalg.norm(road.xy[i] - road.xy[j]))
        close = [k for k, (_, a, b) in enumerate(found) if abs(a - i) + abs(b - j) < 0.1 * n]
        if close:
            if distance < found[close[0]][0]:
                found[close[0]] = (distance, i, j)
        else:
            found.append((distance, i, j))
    result = []
    for _, i, j in sorted(found, key=lambda item: item[1]):
        change = abs(math.remainder(road.heading[j] - road.heading[i], 2.0 * math.pi))
        result.append(SelfCrossing(i * ROAD_STEP, j * ROAD_STEP, math.degrees(change)))
    return tuple(result)
