"""What a LiDAR(-inertial) SLAM system saves of a drive: keyframes (``--keyframes``) and voxel-thinned
clouds (``--thin``), so odometry can be tested on the sparse, decimated data such systems export.

Keyframes are chosen on the generated frame stream, whose poses are exact: a frame is kept when the
sensor has moved at least ``distance`` metres or turned at least ``angle`` degrees since the last kept
one (the rule of FAST-LIO/LIO-SAM style keyframe savers; 1 m and 10 deg are common settings).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from vcr_odom.geometry import rotation_angle

KEYFRAME_ANGLE = 10.0
"""Default turn (deg) that makes a keyframe whatever the distance moved."""


def select_keyframes(poses: NDArray[np.float64], distance: float, angle: float) -> NDArray[np.int64]:
    """Indices of the keyframes of ``poses`` ``(N, 4, 4)``: frame 0, then each frame at least
    ``distance`` m or ``angle`` deg from the last keyframe (greedy, in order)."""
    kept = [0]
    limit = math.radians(angle)
    for index in range(1, len(poses)):
        last = poses[kept[-1]]
        moved = float(np.linalg.norm(poses[index, :3, 3] - last[:3, 3]))
        turned = rotation_angle(last[:3, :3].T @ poses[index, :3, :3])
        if moved >= distance or turned >= limit:
            kept.append(index)
    return np.array(kept, dtype=np.int64)


def thin_voxels(points: NDArray[np.float32], voxel: float) -> NDArray[np.float32]:
    """One point per occupied ``voxel``-metre cube: the measured point nearest its cube's centroid,
    with its own reflectance (averaging would invent points between surfaces), in scan order."""
    if len(points) == 0:
        return points
    cells = np.floor(points[:, :3].astype(np.float64) / voxel).astype(np.int64)
    cells -= cells.min(axis=0)
    extent = cells.max(axis=0) + 1
    key = (cells[:, 0] * extent[1] + cells[:, 1]) * extent[2] + cells[:, 2]  # one int per cube
    _, cell, counts = np.unique(key, return_inverse=True, return_counts=True)
    centroids = (
        np.stack([np.bincount(cell, weights=points[:, k].astype(np.float64)) for k in range(3)], axis=1)
        / counts[:, None]
    )
    spread = np.linalg.norm(points[:, :3] - centroids[cell], axis=1)
    order = np.lexsort((spread, cell))  # by cube, then nearest; stable, so ties keep scan order
    first = order[np.concatenate([[True], cell[order][1:] != cell[order][:-1]])]
    return points[np.sort(first)]
