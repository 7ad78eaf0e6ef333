"""small_gicp's voxelized GICP against a Gaussian voxel map: a registration engine for the kiss-icp polish.

kiss-icp's own registration pairs each point with its nearest map point among the 27 voxels around it,
point to point; from a start a metre off (keyframes, the second starts) it takes a hundred iterations
and more. VGICP pairs each point's local shape with a voxel's (a mean and a covariance per voxel, kept
incrementally as frames are inserted), which converges in a few iterations. It measures most drives
better and long raw solid-state walks worse (docs/benchmarks.md, "A Gaussian voxel map for the polish").
"""

from __future__ import annotations

import os

import numpy as np
import small_gicp

from vcr_odom.geometry import Transform

COVARIANCE_NEIGHBOURS = 10
"""Points each point's covariance is estimated from: small_gicp's own default for its preprocessing."""

LRU_HORIZON_CAP = 1_000_000
"""A sensor that has not moved forgets nothing (it adds no new voxels either); a bound for the int."""

MAX_ITERATIONS = 64
"""VGICP stops earlier on small_gicp's own convergence test (0.1 deg, 1 mm); this only bounds a start
that never settles."""


class GaussianMap:
    """The frames inserted so far as small_gicp's Gaussian voxel map (``voxel_size``: its grid, the
    polish's map voxel). ``threads``: 0 for every core.

    kiss-icp's map keeps what lies within ``max_range_m`` of the sensor; small_gicp's forgets a voxel
    no frame touched for a number of insertions. That number is set to the frames it takes, at the
    run's mean spacing so far, to travel ``max_range_m``: a car at 1 m a frame keeps small_gicp's
    default 100 frames, a walk at 10 Hz the minutes it takes to come back round a courtyard."""

    def __init__(self, voxel_size: float, max_range_m: float, threads: int = 0) -> None:
        self.voxels = small_gicp.GaussianVoxelMap(float(voxel_size))
        self.max_range_m = float(max_range_m)
        self.threads = int(threads) or os.cpu_count() or 1
        self.insertions = 0
        self.path_m = 0.0
        self._last_position: np.ndarray | None = None

    @property
    def horizon(self) -> int:
        """Insertions a voxel stays without a frame touching it (small_gicp's LRU horizon)."""
        if self.path_m <= 0.0:
            return LRU_HORIZON_CAP
        return int(min(max(self.max_range_m * self.insertions / self.path_m, 1.0), LRU_HORIZON_CAP))

    def insert(self, points: np.ndarray, pose: Transform) -> None:
        """Add a frame's points, given in its own frame, at ``pose``."""
        pose = np.asarray(pose, dtype=np.float64)
        if self._last_position is not None:
            self.path_m += float(np.linalg.norm(pose[:3, 3] - self._last_position))
        self._last_position = pose[:3, 3].copy()
        if len(points) >= COVARIANCE_NEIGHBOURS:
            self.insertions += 1
            self.voxels.set_lru(self.horizon)
            self.voxels.insert(self._cloud(points), pose)

    def align(self, source: np.ndarray, start: Transform) -> Transform:
        """The pose that places ``source`` on the map, registered from ``start``; ``start`` itself where
        the map is empty or ``source`` has too few points for a covariance (nothing to measure)."""
        if len(self.voxels) == 0 or len(source) < COVARIANCE_NEIGHBOURS:
            return np.asarray(start, dtype=np.float64)
        result = small_gicp.align(
            self.voxels,
            self._cloud(source),
            np.asarray(start, dtype=np.float64),
            num_threads=self.threads,
            max_iterations=MAX_ITERATIONS,
        )
        return np.asarray(result.T_target_source, dtype=np.float64)

    def _cloud(self, points: np.ndarray) -> small_gicp.PointCloud:
        cloud = small_gicp.PointCloud(np.ascontiguousarray(points, dtype=np.float64))
        small_gicp.estimate_covariances(cloud, num_neighbors=COVARIANCE_NEIGHBOURS, num_threads=self.threads)
        return cloud
