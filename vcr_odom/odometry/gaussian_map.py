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

MAX_ITERATIONS = 64
"""VGICP stops earlier on small_gicp's own convergence test (0.1 deg, 1 mm); this only bounds a start
that never settles."""


class GaussianMap:
    """The frames inserted so far as small_gicp's Gaussian voxel map (``voxel_size``: its grid, the
    polish's map voxel); small_gicp forgets voxels no recent frame touched, as kiss-icp's map forgets
    points out of range. ``threads``: 0 for every core."""

    def __init__(self, voxel_size: float, threads: int = 0) -> None:
        self.voxels = small_gicp.GaussianVoxelMap(float(voxel_size))
        self.threads = int(threads) or os.cpu_count() or 1
        self._source: np.ndarray | None = None
        self._source_cloud: small_gicp.PointCloud | None = None

    def insert(self, points: np.ndarray, pose: Transform) -> None:
        """Add a frame's points, given in its own frame, at ``pose``."""
        if len(points) >= COVARIANCE_NEIGHBOURS:
            self.voxels.insert(self._cloud(points), np.asarray(pose, dtype=np.float64))

    def align(self, source: np.ndarray, start: Transform) -> Transform:
        """The pose that places ``source`` on the map, registered from ``start``; ``start`` itself where
        the map is empty or ``source`` has too few points for a covariance (nothing to measure)."""
        if len(self.voxels) == 0 or len(source) < COVARIANCE_NEIGHBOURS:
            return np.asarray(start, dtype=np.float64)
        result = small_gicp.align(
            self.voxels,
            self._with_covariances(source),
            np.asarray(start, dtype=np.float64),
            num_threads=self.threads,
            max_iterations=MAX_ITERATIONS,
        )
        return np.asarray(result.T_target_source, dtype=np.float64)

    def _with_covariances(self, source: np.ndarray) -> small_gicp.PointCloud:
        """``source`` as small_gicp registers it, its covariances estimated once for all the starts a
        frame is registered from (the same array: the prediction, standing still, the network's)."""
        if source is not self._source or self._source_cloud is None:
            self._source, self._source_cloud = source, self._cloud(source)
        return self._source_cloud

    def _cloud(self, points: np.ndarray) -> small_gicp.PointCloud:
        cloud = small_gicp.PointCloud(np.ascontiguousarray(points, dtype=np.float64))
        small_gicp.estimate_covariances(cloud, num_neighbors=COVARIANCE_NEIGHBOURS, num_threads=self.threads)
        return cloud
