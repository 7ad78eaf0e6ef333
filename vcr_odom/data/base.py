"""The one interface every LiDAR source implements, so odometry never cares where frames come from."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

Points = NDArray[np.float32]
"""A frame: float32 ``(N, 4)`` array of x, y, z (metres, LiDAR frame) and reflectance."""


@runtime_checkable
class LidarSequence(Protocol):
    """An ordered set of scans with optional ground truth.

    ``gt_poses`` is ``(len, 4, 4)`` float64 in the LiDAR frame with frame 0 = identity, or None.
    ``tr_velo_to_cam`` is KITTI's ``Tr`` (LiDAR -> left camera) when a calibration is known, else None.
    ``timestamps`` is seconds per frame (10 Hz assumed where the source has none).
    ``timestamps_assumed`` is True exactly when they were assumed: no times were given and a rate was
    guessed, so speeds derived from frame gaps are guesses too (odometry flags rather than trusts them).
    ``label`` names the data itself, for result folders (``name`` may be the same for two data roots).
    """

    name: str
    label: str

    def __len__(self) -> int: ...

    def frame(self, index: int) -> Points: ...

    @property
    def gt_poses(self) -> NDArray[np.float64] | None: ...

    @property
    def timestamps(self) -> NDArray[np.float64]: ...

    @property
    def timestamps_assumed(self) -> bool: ...

    @property
    def tr_velo_to_cam(self) -> NDArray[np.float64] | None: ...
