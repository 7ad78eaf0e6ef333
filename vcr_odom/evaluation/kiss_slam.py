"""KISS-SLAM over a sequence's frames in one call, for a notebook: its optimised poses, loop closures and
wall time, from the same frame loop (same frames, stride and timestamps) as every other method.

``vcr-odom compare -b kiss-slam`` runs the same thing through the comparison's result folders.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import LidarSequence
from vcr_odom.odometry.frame_loop import OdometryRun, run_odometry
from vcr_odom.registration.kiss_slam import KissSlamOdometry, LoopClosure


@dataclass
class KissSlamRun:
    """``poses``: ``(n, 4, 4)`` float64, LiDAR frame, the first frame = identity, after the pose graph
    (the online estimates where ``run.interrupted``); ``closures``: accepted loop closures, their frames
    named by the sequence's indices; ``run``: the loop's record (stage times, ``slam`` summary)."""

    poses: NDArray[np.float64]
    frame_indices: list[int]
    closures: list[LoopClosure]
    wall_seconds: float
    run: OdometryRun

    @property
    def num_closures(self) -> int:
        return len(self.closures)


def run_kiss_slam(
    sequence: LidarSequence, frame_indices: Sequence[int] | None = None, **options: Any
) -> KissSlamRun:
    """KISS-SLAM over ``frame_indices`` of ``sequence`` (default: every frame); ``options`` go to
    :class:`~vcr_odom.registration.kiss_slam.KissSlamOdometry` (``max_range``, ``voxel_size``, ...).

    Raises :class:`~vcr_odom.errors.MissingExtraError` when kiss-slam is not installed.
    """
    indices = list(range(len(sequence)) if frame_indices is None else frame_indices)
    slam = KissSlamOdometry(**options)
    run = run_odometry(sequence, slam, indices)
    return KissSlamRun(
        poses=run.poses,
        frame_indices=run.frame_indices,
        closures=slam.closures(run.frame_indices),
        wall_seconds=run.wall_seconds,
        run=run,
    )
