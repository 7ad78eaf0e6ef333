"""Scans in which motion cannot be measured: almost every point on one plane (a sensor facing the road
or a wall). Any scan matcher then slides along that plane where the scans give it nothing to hold,
and its fit stays as good as ever, so nothing else in the run notices. Such frames are named in the
run's output (``single_plane_frames`` in metrics.json) rather than passed off as measured.

Measured on synthetic drives: a narrow-field (Livox Avia-like) sensor at a turnaround that sees only
road gives 0.13-0.15 m of thickness (its odometry slid 0.3-0.6 m a frame there); scans that register
well give 0.39 m (Avia keyframes) to 4 m, KITTI scans 0.8 m (docs/benchmarks.md)."""

from __future__ import annotations

import numpy as np

from vcr_odom.data.base import Points

SINGLE_PLANE_M = 0.25
"""Thickness (standard deviation across the best-fitting plane) below which a scan is one plane."""
SAMPLE_POINTS = 2000
"""Points the thickness is measured on (an even stride through the scan: deterministic and ~0.1 ms)."""


def plane_thickness(points: Points) -> float:
    """The spread of ``points`` across their best-fitting plane, in metres (inf under 10 points)."""
    xyz = np.asarray(points)[:, :3]
    xyz = xyz[:: max(1, len(xyz) // SAMPLE_POINTS)]
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    if len(xyz) < 10:
        return float("inf")
    smallest = np.linalg.eigvalsh(np.cov(xyz.T.astype(np.float64)))[0]
    return float(np.sqrt(max(smallest, 0.0)))


def single_plane(points: Points) -> float | None:
    """The scan's thickness where it is one plane (under :data:`SINGLE_PLANE_M`), else None."""
    thickness = plane_thickness(points)
    return thickness if thickness < SINGLE_PLANE_M else None
