"""kiss-icp's frame registration with a second start: the one piece that reaches into kiss-icp.

Every step is kiss-icp's own library piece, in its order (preprocess, voxelize, adaptive threshold,
``align_points_to_map``, model-deviation update, map update); what is added is a second start for the
registration and the choice between the two results. These are kiss-icp internals, not its public
API, so the supported versions are bounded in pyproject.toml and :func:`check_kiss_internals` names
what is missing if a release moves them, instead of failing mid-run.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
from kiss_icp.kiss_icp import KissICP

from vcr_odom.errors import ConfigError
from vcr_odom.geometry import Transform, invert, project_to_se3, rotation_angle

KISS_INTERNALS = ("preprocessor", "voxelize", "adaptive_threshold", "registration", "local_map")


def check_kiss_internals(odometry: KissICP) -> None:
    """ConfigError naming the kiss-icp attributes this polish needs and the installed release lacks."""
    missing = [name for name in KISS_INTERNALS if not hasattr(odometry, name)]
    if not hasattr(getattr(odometry, "registration", None), "align_points_to_map"):
        missing.append("registration.align_points_to_map")
    if missing:
        import kiss_icp

        raise ConfigError(
            f"the kiss-icp polish needs kiss-icp 1.x internals ({', '.join(missing)} missing in "
            f"kiss-icp {getattr(kiss_icp, '__version__', '?')}); install kiss-icp>=1.0,<2 or use --refine icp"
        )


class GuidedKissICP(KissICP):
    """``KissICP`` whose frames may also start from a pose given by a global method.

    Fed its own prediction as the guess it reproduces kiss-icp's poses exactly (a test holds it to that).
    """

    def __init__(self, config: object) -> None:
        super().__init__(config)
        check_kiss_internals(self)
        self.last_sigma = float("nan")
        self.last_source_points = 0

    def seed(self, frame: np.ndarray, pose: Transform, last_delta: Transform) -> None:
        """Start (or restart) the local map with ``frame`` at ``pose``, without registering it against
        an empty map; ``last_delta`` is the motion into this frame (the next prediction's velocity)."""
        frame = self.preprocessor.preprocess(frame, np.array([]), np.eye(4))
        _, frame_downsample = self.voxelize(frame)
        pose = project_to_se3(pose)
        self.local_map.update(frame_downsample, pose)
        self.last_pose, self.last_delta = pose, project_to_se3(last_delta)

    def register_frame_with_guess(
        self, frame: np.ndarray, guess: Transform, keep_prediction: bool = True
    ) -> tuple[Transform, str]:
        """Register ``frame`` (N x 3, float64) and return its pose and the start that won
        (``"prediction"`` or ``"global"``).

        ``keep_prediction``: start from kiss-icp's constant-velocity prediction and, where that result
        is not within the basin of ``guess`` (the frame's pose by the global method), from ``guess``
        too; the result that fits the local map better wins. False: ``guess`` replaces the prediction.
        Why both: the prediction is the better start while the motion is steady, the global estimate
        where it is not (a first pair, a sudden stop, a large stride). Fit is open3d's
        ``evaluate_registration`` fitness within half a map voxel: kiss-icp's own 3-sigma gate grows
        to metres after a large motion, where every start fits. The adaptive threshold learns the
        deviation from the start that won, so it stays kiss-icp's own wherever the prediction wins.
        Guesses are projected onto SE(3): kiss-icp's Sophus aborts the process on a rotation that is
        orthonormal only to float32 precision.
        """
        frame = self.preprocessor.preprocess(frame, np.array([]), self.last_delta)
        source, frame_downsample = self.voxelize(frame)
        sigma = self.adaptive_threshold.get_threshold()
        prediction = self.last_pose @ self.last_delta
        guess = project_to_se3(guess)
        start = "prediction" if keep_prediction else "global"
        new_pose = self._align(source, prediction if keep_prediction else guess, sigma)
        if keep_prediction and not within_basin(new_pose, guess):  # else it would end here too
            from_guess = self._align(source, guess, sigma)
            if self._fits_better(source, from_guess, new_pose):
                new_pose, start = from_guess, "global"
        start_pose = prediction if start == "prediction" else guess
        self.adaptive_threshold.update_model_deviation(np.linalg.inv(start_pose) @ new_pose)
        self.local_map.update(frame_downsample, new_pose)
        self.last_delta = np.linalg.inv(self.last_pose) @ new_pose
        self.last_pose = new_pose
        self.last_sigma = float(sigma)
        self.last_source_points = len(source)
        return np.asarray(new_pose, dtype=np.float64), start

    def _align(self, source: np.ndarray, guess: Transform, sigma: float) -> Transform:
        """kiss-icp's registration step, as its ``register_frame`` calls it."""
        return self.registration.align_points_to_map(
            points=source,
            voxel_map=self.local_map,
            initial_guess=project_to_se3(guess),
            max_correspondance_distance=3 * sigma,
            kernel=sigma,
        )

    def _fits_better(self, source: np.ndarray, pose: Transform, than: Transform) -> bool:
        """Whether more of ``source`` lands within half a map voxel of the local map at ``pose``."""
        registration = o3d.pipelines.registration
        distance = 0.5 * self.config.mapping.voxel_size
        source_cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(source)))
        map_cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.local_map.point_cloud()))
        fitness = [
            registration.evaluate_registration(source_cloud, map_cloud, distance, candidate).fitness
            for candidate in (pose, than)
        ]
        return bool(fitness[0] > fitness[1])


BASIN_M = 0.5
BASIN_DEG = 2.0
"""Starts this close end in the same local result: running the local method from both only costs time."""


def motion_difference(a: Transform, b: Transform) -> tuple[float, float]:
    """Translation (m) and rotation (deg) between two motions."""
    delta = invert(a) @ b
    return float(np.linalg.norm(delta[:3, 3])), float(np.degrees(rotation_angle(delta)))


def within_basin(a: Transform, b: Transform) -> bool:
    change_m, change_deg = motion_difference(a, b)
    return change_m < BASIN_M and change_deg < BASIN_DEG
