"""kiss-icp's own odometry pipeline (adaptive threshold, local voxel map, constant velocity), unmodified.

It keeps state across frames, so it is a :class:`SequentialOdometry`, not a pairwise registrar.
"""

from __future__ import annotations

import os
import warnings

import numpy as np
from kiss_icp.config import KISSConfig, load_config
from kiss_icp.kiss_icp import KissICP

from vcr_odom.data.base import Points
from vcr_odom.errors import ConfigError, DataWarning
from vcr_odom.geometry import Transform
from vcr_odom.registration.base import MIN_REGISTRATION_POINTS, TOO_FEW_POINTS


def threads_from_environment() -> int:
    """``$VCR_ODOM_THREADS`` (0 where unset: every core); a value that is not a count is named."""
    text = os.environ.get("VCR_ODOM_THREADS", "").strip()
    if not text:
        return 0
    if not text.isdigit():
        raise ConfigError(
            f"$VCR_ODOM_THREADS must be a whole number of threads (0: every core); got {text!r}"
        )
    return int(text)


def kiss_config(
    max_range: float = 100.0,
    min_range: float = 0.0,
    voxel_size: float | None = None,
    deskew: bool = False,
    max_num_threads: int = 0,
    convergence_criterion: float | None = None,
) -> KISSConfig:
    """kiss-icp's default configuration (``load_config(None)``) with our data settings.

    ``deskew=False``: KITTI ``.bin`` scans carry no per-point times (kiss-icp's own KITTI reader
    passes none either). ``max_num_threads=0`` takes ``$VCR_ODOM_THREADS`` where set (a benchmark's
    pool process: its share of the cores), else every core. ``voxel_size=None`` follows kiss-icp's rule ``max_range / 100``.
    ``convergence_criterion=None`` keeps kiss-icp's own (1e-4); the polish stops earlier.
    """
    if not 0.0 <= min_range < max_range:
        raise ConfigError(f"need 0 <= min_range < max_range; got {min_range}, {max_range}")
    config = load_config(None)
    config.data.max_range = float(max_range)
    config.data.min_range = float(min_range)
    config.data.deskew = bool(deskew)
    config.mapping.voxel_size = float(max_range / 100.0 if voxel_size is None else voxel_size)
    config.registration.max_num_threads = int(max_num_threads) or threads_from_environment()
    if convergence_criterion is not None:
        if not convergence_criterion > 0:
            raise ConfigError(f"convergence_criterion must be > 0; got {convergence_criterion}")
        config.registration.convergence_criterion = float(convergence_criterion)
    return config


def kiss_input(points: Points) -> np.ndarray:
    """kiss-icp's input: the finite xyz of ``points`` as contiguous float64. Loaders already drop
    non-finite points, so the per-row filter runs only when one whole-array check finds some."""
    xyz = np.asarray(points)[:, :3]
    if not np.isfinite(xyz).all():
        xyz = xyz[np.isfinite(xyz).all(axis=1)]
    return np.ascontiguousarray(xyz, dtype=np.float64)


class _KissICP(KissICP):
    """kiss-icp's pipeline, except that a frame of fewer than :data:`MIN_REGISTRATION_POINTS`
    registration points is placed by the motion model, as kiss-icp places an empty frame, instead of
    by an undetermined solve that differs run to run; ``too_few`` says the last frame was one."""

    too_few: bool = False

    def voxelize(self, iframe: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        source, frame_downsample = super().voxelize(iframe)
        self.too_few = 0 < len(source) < MIN_REGISTRATION_POINTS
        return (source[:0] if self.too_few else source), frame_downsample


class KissIcpOdometry:
    """``kiss_icp.kiss_icp.KissICP`` fed frame by frame; ``step`` returns the pose in the frame-0 LiDAR frame.

    ``kitti_correction=True`` applies kiss-icp's KITTI intrinsic fix (its KITTI reader does so) to
    every frame; off by default so all methods see the same points.
    """

    name = "kiss-icp"

    def __init__(
        self,
        max_range: float = 100.0,
        min_range: float = 0.0,
        voxel_size: float | None = None,
        deskew: bool = False,
        kitti_correction: bool = False,
        max_num_threads: int = 0,
        convergence_criterion: float | None = None,
    ) -> None:
        self.config = kiss_config(
            max_range, min_range, voxel_size, deskew, max_num_threads, convergence_criterion
        )
        self.kitti_correction = kitti_correction
        self._odometry = _KissICP(self.config)
        self.last_info: dict[str, object] = {}

    def reset(self) -> None:
        """Forget the map and the motion model: the next frame is frame 0 (identity)."""
        self._odometry = _KissICP(self.config)
        self.last_info = {}

    def step(self, points: Points, timestamp: float = 0.0) -> Transform:
        """Register one raw frame; ``timestamp`` is unused (no per-point times without deskew)."""
        del timestamp
        frame = kiss_input(points)
        if len(frame) == 0:
            warnings.warn(
                "kiss-icp: empty frame, pose extrapolated by the motion model", DataWarning, stacklevel=2
            )
        elif self.kitti_correction:
            from kiss_icp.pybind import kiss_icp_pybind

            vector = kiss_icp_pybind._Vector3dVector(frame)
            frame = np.asarray(kiss_icp_pybind._correct_kitti_scan(vector))
        self._odometry.register_frame(frame, np.array([]))
        self.last_info = {"flagged": True, "reason": TOO_FEW_POINTS} if self._odometry.too_few else {}
        return np.asarray(self._odometry.last_pose, dtype=np.float64).copy()
