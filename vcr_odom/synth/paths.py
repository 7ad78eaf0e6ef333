"""The centre line the car (or the walker) follows, as distinct from the street it is built along.

Why two things: on the open street the path is the street's own centre line, but on a loop the car
drives the same street round and round, and on a return it drives it out and back in the other lane.
Both are :class:`~vcr_odom.synth.road.Road` samples :data:`~vcr_odom.synth.road.ROAD_STEP` apart; the
path also records which station of the street each of its samples passes, so that what depends on the
street's zones (lane widths) can be looked up from the path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vcr_odom.synth.mesh import FloatArray
from vcr_odom.synth.road import ROAD_STEP, Road, smooth

CURVATURE_SMOOTHING = 2.0
"""Metres over which a resampled path's numerical curvature is smoothed (it sets speed and body roll)."""


@dataclass(frozen=True)
class DrivePath:
    """Samples of the driven centre line from its station 0 (:data:`~vcr_odom.synth.road.PREROLL`
    before the first frame), and the street station under each sample."""

    line: Road
    road_station: FloatArray

    @staticmethod
    def along(road: Road) -> DrivePath:
        """The open street driven once from its start: the path is the road itself."""
        return DrivePath(road, np.arange(len(road.xy)) * ROAD_STEP)


def resample(xy: FloatArray, closed: bool = False) -> tuple[Road, FloatArray]:
    """A polyline as a :class:`Road` sampled every :data:`ROAD_STEP` metres of arc length, with
    heading and curvature taken numerically; also the polyline's arc length at each new sample (to
    carry other per-point values over with ``np.interp``).

    ``closed``: the polyline is a lap (its last point equals its first); the result is the lap with
    ``round(length / ROAD_STEP)`` equal steps, ending on its first sample, and its heading and
    curvature are periodic (the heading ends one full turn, or none, from where it started).
    """
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    if closed:
        steps = max(3, round(along[-1] / ROAD_STEP))
        at = np.linspace(0.0, along[-1], steps + 1)
    else:
        at = np.arange(math.floor(along[-1] / ROAD_STEP) + 1) * ROAD_STEP
    points = np.column_stack([np.interp(at, along, xy[:, 0]), np.interp(at, along, xy[:, 1])])
    if closed:
        ring = points[:-1]
        tangent = np.roll(ring, -1, axis=0) - np.roll(ring, 1, axis=0)
        raw = np.arctan2(tangent[:, 1], tangent[:, 0])
        step = np.angle(np.exp(1j * np.diff(np.append(raw, raw[0]))))  # the last step closes the lap
        heading = raw[0] + np.concatenate([[0.0], np.cumsum(step)])  # ends one full turn (or none) on
        rate = 0.5 * (step + np.roll(step, 1)) / ROAD_STEP
        curvature = _periodic_smooth(rate, CURVATURE_SMOOTHING / ROAD_STEP)
        curvature = np.append(curvature, curvature[0])
    else:
        tangent = np.gradient(points, axis=0)
        heading = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
        curvature = smooth(np.gradient(heading) / ROAD_STEP, CURVATURE_SMOOTHING / ROAD_STEP)
    return Road(points, heading, curvature), at


def _periodic_smooth(ring: FloatArray, sigma_samples: float) -> FloatArray:
    """Gaussian smoothing of values round a lap (one per sample, not repeating the first)."""
    half = min(int(3 * sigma_samples), len(ring) - 1)
    kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma_samples) ** 2)
    padded = np.concatenate([ring[len(ring) - half :], ring, ring[:half]])
    return np.convolve(padded, kernel / kernel.sum(), mode="valid")


def unroll(lap: Road, start: float, length: float) -> DrivePath:
    """The lap driven round and round for at least ``length`` metres, from lap station ``start``
    (rounded to a sample): headings keep turning lap after lap, road stations wrap."""
    n = len(lap.xy) - 1
    first = round(start / ROAD_STEP) % n
    k = first + np.arange(math.ceil(length / ROAD_STEP) + 1)
    index, laps = k % n, k // n
    turn = lap.heading[-1] - lap.heading[0]
    line = Road(lap.xy[index], lap.heading[index] + laps * turn, lap.curvature[index])
    return DrivePath(line, index * ROAD_STEP)
