"""The ground's normal in a node's scan: which way is up, measured where the odometry cannot see it.

Why the map needs it: a scan matcher's tilt (roll, pitch) drifts like its heading, and a tilted
stretch of trajectory still closes its loops: a lobe of a figure eight driven in a plane tilted by
10 degrees meets itself at its ends, so loops leave its middle metres too high or too low. On a
16-beam car drive that was nearly all of the map's error (docs/benchmarks.md, "Maps that close their loops").
The ground is seen in every scan of a ground vehicle or a walk, so each node's measured up direction
holds the graph's tilt, loosely (:data:`~vcr_odom.loops.up_priors.ATTITUDE_SIGMA_DEG`): roads slope.

Measured on the lowest points near the sensor: far ground is sparse (a 16-beam sensor's rings meet
the road 6-20 m away), and taking the lowest band first leaves RANSAC a set that is mostly ground,
where a scan-wide fit through a few rings tilts by 10-20 degrees.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from vcr_odom.data.base import Points
from vcr_odom.preprocess import is_ground, least_squares_plane

NEAR_M = (0.5, 20.0)
"""Horizontal range of the points used: the ground is densest near the sensor."""
BAND_M = 0.6
"""Height above the lowest points (their 5th percentile) kept as ground candidates."""
DISTANCE_M = 0.08
MAX_TILT_DEG = 30.0
"""A plane tilted further from the scan's own z axis is a ramp, a wall or a wrong fit."""
SENSOR_ABOVE_M = 0.2
"""The sensor is at least this far above the plane (a plane through it is a wrong fit)."""
MIN_POINTS = 30
INPUT_POINTS = 20_000
"""A dense scan is taken every k-th point down to about this many first (the cost is in the scan's size)."""
SAMPLE_POINTS = 2000
ITERATIONS = 100


def ground_normal(points: Points) -> NDArray[np.float64] | None:
    """The ground plane's upward unit normal in the scan's frame, or None where no plausible ground
    is seen (too few low points, a plane too steep or above the sensor)."""
    xyz = np.asarray(points)[:, :3]
    xyz = xyz[:: max(1, len(xyz) // INPUT_POINTS)].astype(np.float64)
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    horizontal = np.linalg.norm(xyz[:, :2], axis=1)
    xyz = xyz[(horizontal > NEAR_M[0]) & (horizontal < NEAR_M[1])]
    if len(xyz) < MIN_POINTS:
        return None
    low = xyz[xyz[:, 2] < np.percentile(xyz[:, 2], 5) + BAND_M]
    low = low[:: max(1, len(low) // SAMPLE_POINTS)]
    if len(low) < MIN_POINTS:
        return None
    o3d.utility.random.seed(0)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(low))
    _, inliers = cloud.segment_plane(DISTANCE_M, 3, ITERATIONS, probability=1.0)
    if len(inliers) < MIN_POINTS:
        return None
    plane = least_squares_plane(low[inliers])  # RANSAC's own model rests on three points
    if not is_ground(plane, MAX_TILT_DEG) or plane[3] < SENSOR_ABOVE_M:
        return None
    return plane[:3]
