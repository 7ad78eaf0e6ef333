"""What every file-backed scan loader shares: the ``.bin`` reader, point clean-up, timestamps, ``Tr``,
and the lazy sequence base that :mod:`~vcr_odom.data.kitti` and :mod:`~vcr_odom.data.folder` extend.

pykitti decodes the ``.bin`` scans (:func:`pykitti.utils.load_velo_scan`).
"""

from __future__ import annotations

import operator
import os
import re
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import Points
from vcr_odom.errors import DataError, DataWarning
from vcr_odom.geometry import camera_to_lidar_poses, lidar_to_camera_poses, normalise_to_first, project_to_se3
from vcr_odom.io import read_kitti_calib, read_times

DEFAULT_RATE_HZ = 10.0
"""KITTI's Velodyne spins at about 10 Hz: the assumed rate where a source has no timestamps."""

BIN_POINT_BYTES = 16  # float32 x, y, z, reflectance


def natural_sort_key(path: str | os.PathLike[str]) -> tuple[tuple[int, int | str], ...]:
    """Sort ``2.bin`` before ``10.bin``: digit runs compare as numbers, the rest as text."""
    parts = re.split(r"(\d+)", Path(path).name)
    return tuple((0, int(part)) if part.isdigit() else (1, part) for part in parts if part)


def check_bin_size(path: Path) -> None:
    """A KITTI scan is whole float32x4 records; any other size means a truncated or foreign file."""
    try:
        size = path.stat().st_size
    except OSError as error:
        raise DataError(f"cannot read scan file {path}: {error}") from error
    if size % BIN_POINT_BYTES:
        raise DataError(
            f"{path}: size {size} bytes is not a multiple of {BIN_POINT_BYTES} "
            "(KITTI .bin scans are float32 x, y, z, reflectance records); the file is truncated or not a scan"
        )


def clean_points(points: NDArray[np.floating], source: str | os.PathLike[str]) -> Points:
    """Drop points with NaN/inf in any column (counted in a warning) and warn on an empty frame.

    Downstream stages assume finite float32 ``(N, 4)`` data; doing this once here keeps them simple.
    """
    points = np.asarray(points, dtype=np.float32).reshape(-1, 4)
    finite = np.isfinite(points).all(axis=1)
    dropped = int(len(points) - finite.sum())
    if dropped:
        warnings.warn(
            f"{source}: dropped {dropped} of {len(points)} points with NaN or inf values",
            DataWarning,
            stacklevel=3,
        )
        points = points[finite]
    if len(points) == 0:
        warnings.warn(f"{source}: empty frame (no valid points)", DataWarning, stacklevel=3)
    return np.ascontiguousarray(points, dtype=np.float32)


def read_bin_scan(path: str | os.PathLike[str]) -> Points:
    """Read one KITTI ``.bin`` scan as float32 ``(N, 4)``; bad sizes raise DataError naming the file."""
    from pykitti.utils import load_velo_scan  # imported here: pykitti pulls in PIL, only needed to read

    path = Path(path)
    check_bin_size(path)
    return clean_points(load_velo_scan(str(path)), path)


def assumed_timestamps(count: int, where: str | os.PathLike[str]) -> NDArray[np.float64]:
    """10 Hz timestamps from 0, with one DataWarning naming the source so the user knows they are guessed."""
    warnings.warn(
        f"{where}: no timestamps (times.txt), assuming {DEFAULT_RATE_HZ:g} Hz",
        DataWarning,
        stacklevel=3,
    )
    return np.arange(count, dtype=np.float64) / DEFAULT_RATE_HZ


def load_times(path: Path, count: int) -> NDArray[np.float64]:
    """Read ``times.txt`` and insist on one line per frame (a mismatch would misalign every stamp)."""
    if not path.is_file():
        raise DataError(f"timestamps file not found: {path}")
    times = read_times(path)
    if len(times) != count:
        raise DataError(f"{path}: {len(times)} timestamps but {count} scan files")
    if not np.all(np.isfinite(times)):
        raise DataError(f"{path}: timestamps contain NaN or inf")
    return times


def read_tr(calib_path: Path, *, required: bool) -> NDArray[np.float64] | None:
    """``Tr`` (LiDAR -> left camera) from a KITTI ``calib.txt``: checked, then made exactly rigid.

    A missing ``Tr:`` line is an error only when ``required`` (camera-frame poses need it).
    """
    calib = read_kitti_calib(calib_path)
    if "Tr" not in calib:
        if required:
            raise DataError(f"{calib_path}: no 'Tr:' line (the velodyne -> camera transform)")
        return None
    tr = calib["Tr"].copy()
    rotation = tr[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4) or np.linalg.det(rotation) < 0:
        raise DataError(f"{calib_path}: 'Tr' rotation is not orthonormal (not a rigid transform)")
    # KITTI prints Tr to ~1e-7; the nearest exact rotation keeps the closed-form inverse exact,
    # so converted poses stay rigid and frame 0 stays the identity to machine precision.
    return project_to_se3(tr)


def check_pose_count(poses: NDArray[np.float64], count: int, poses_path: Path, scans: Path) -> None:
    """One pose per scan file, or a DataError naming both counts (a mismatch would misalign them all)."""
    if len(poses) != count:
        raise DataError(
            f"{poses_path}: {len(poses)} poses but {count} scan files in {scans}; "
            "the poses file must have one line per scan"
        )


class ScanFileSequence:
    """Lazy sequence over a sorted list of scan files: nothing is read until :meth:`frame` is called.

    Subclasses fill ``files``, ``name`` and the private pose/time/calibration attributes.
    """

    name: str
    files: list[Path]
    gt_poses_camera: NDArray[np.float64] | None
    """Ground truth in KITTI's left-camera frame (frame 0 = identity), or None when no calibration."""

    _gt_poses: NDArray[np.float64] | None
    _timestamps: NDArray[np.float64]
    _tr: NDArray[np.float64] | None

    def __len__(self) -> int:
        return len(self.files)

    def __iter__(self) -> Iterator[Points]:
        for index in range(len(self)):
            yield self.frame(index)

    def __repr__(self) -> str:
        gt = "with" if self._gt_poses is not None else "without"
        return f"<{type(self).__name__} {self.name}: {len(self)} frames, {gt} ground truth>"

    def frame(self, index: int) -> Points:
        """Frame ``index`` (negative counts from the end) as float32 ``(N, 4)``: x, y, z, reflectance."""
        return self._read(self.files[self._check_index(index)])

    def _read(self, path: Path) -> Points:
        return read_bin_scan(path)

    def _check_index(self, index: int) -> int:
        position = operator.index(index)  # TypeError for floats, as for lists
        count = len(self)
        if not -count <= position < count:
            raise IndexError(
                f"frame {position} out of range: {self.name} has {count} frames (0..{count - 1})"
            )
        return position % count

    @property
    def gt_poses(self) -> NDArray[np.float64] | None:
        """``(len, 4, 4)`` ground truth in the LiDAR frame, frame 0 = identity, or None."""
        return self._gt_poses

    @property
    def timestamps(self) -> NDArray[np.float64]:
        """Seconds per frame (10 Hz assumed, with a warning at construction, where none are known)."""
        return self._timestamps

    @property
    def tr_velo_to_cam(self) -> NDArray[np.float64] | None:
        """KITTI's 4x4 ``Tr`` (LiDAR -> left camera), or None when no calibration is known."""
        return self._tr

    def _set_poses(
        self, poses: NDArray[np.float64] | None, tr: NDArray[np.float64] | None, camera_frame: bool
    ) -> None:
        """Store ground truth in both frames, re-anchored so frame 0 = identity: every trajectory in the
        library starts there, so estimates and ground truth compare without an alignment step."""
        self._tr = tr
        self._gt_poses = None
        self.gt_poses_camera = None
        if poses is None:
            return
        if camera_frame:
            assert tr is not None
            self.gt_poses_camera = normalise_to_first(poses)
            self._gt_poses = normalise_to_first(camera_to_lidar_poses(poses, tr))
        else:
            self._gt_poses = normalise_to_first(poses)
            if tr is not None:
                self.gt_poses_camera = lidar_to_camera_poses(self._gt_poses, tr)
