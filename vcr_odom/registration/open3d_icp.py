"""open3d ICP (point-to-plane or point-to-point) behind the :class:`Registrar` interface.

The local baseline: accurate when started near the answer (identity or a constant-velocity guess),
wrong when the motion exceeds its correspondence distance. "ICP(10)" of the paper is 10 iterations.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from vcr_odom.data.base import Points
from vcr_odom.errors import ConfigError, DataWarning
from vcr_odom.geometry import Transform
from vcr_odom.preprocess import crop_range
from vcr_odom.registration.base import TOO_FEW_POINTS, RegistrationResult, identity_guess

ICP_VARIANTS = ("point_to_plane", "point_to_point")
_MIN_POINTS = 10  # fewer than this and a 6-DoF least-squares fit is meaningless


def prepare_cloud(
    points: Points,
    min_range: float,
    max_range: float,
    voxel_size: float,
    normals: bool,
    normals_max_nn: int = 10,
) -> o3d.geometry.PointCloud:
    """Crop, voxel down-sample (ground kept: it pins z, roll and pitch) and optionally estimate normals
    from at most ``normals_max_nn`` neighbours within two voxels."""
    cropped = crop_range(points, min_range, max_range)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cropped[:, :3].astype(np.float64)))
    cloud = cloud.voxel_down_sample(voxel_size)
    if normals and len(cloud.points) >= 3:
        search = o3d.geometry.KDTreeSearchParamHybrid(radius=2.0 * voxel_size, max_nn=normals_max_nn)
        cloud.estimate_normals(search)
    return cloud


def too_few_points(
    source: o3d.geometry.PointCloud, target: o3d.geometry.PointCloud, guess: Transform, name: str
):
    """The graceful answer for a degenerate pair: the initial guess, fitness 0, and a warning."""
    counts = (len(source.points), len(target.points))
    if min(counts) >= _MIN_POINTS:
        return None
    warnings.warn(
        f"{name}: too few points to register (source, target) = {counts}", DataWarning, stacklevel=3
    )
    return RegistrationResult(guess, fitness=0.0, info={"status": TOO_FEW_POINTS, "points": counts})


@dataclass
class Open3dIcp:
    """open3d ``registration_icp`` on voxel-down-sampled frames.

    Defaults, measured on the real KITTI sample (59 consecutive pairs, frames 0-59):
    ``voxel_size=0.5`` m (1.0 m costs 2-5 cm of accuracy, 0.3 m doubles the time for no gain);
    ``max_correspondence_distance=1.0`` m (covers KITTI's <= 1 m inter-frame motion from identity;
    2 m was slightly worse on 3 of 4 sampled pairs); ``max_iterations=100`` with relative
    fitness/RMSE 1e-6 is "converged", 10 is the paper's ICP(10) (point-to-plane converges within
    10 here: both give 2.3 cm / 0.075° RMSE per pair, ~50 ms/pair with preparation).
    Point-to-point is markedly worse on real scans (~8-10 cm RMSE): ring patterns on the road drag it.
    Ranges as in pre-processing (2-80 m: no ego-car returns, no sparse far field).
    ``normals_max_nn=10``: at 0.5 m voxels the 2-voxel ball holds few more than 10 points; against 30,
    the VCR + ICP odometry on kitti-sample at strides 1, 5 and 10 kept its per-pair RMSE (within
    0.007°, 1 mm) and end-point drift (within 0.03 %), and normals cost ~6 ms less per frame.
    """

    variant: str = "point_to_plane"
    max_iterations: int = 100
    relative_fitness: float = 1e-6
    relative_rmse: float = 1e-6
    voxel_size: float = 0.5
    max_correspondence_distance: float = 1.0
    min_range: float = 2.0
    max_range: float = 80.0
    normals_max_nn: int = 10
    name: str = ""
    needs_initial_guess: bool = True

    def __post_init__(self) -> None:
        if self.variant not in ICP_VARIANTS:
            raise ConfigError(f"variant must be one of {', '.join(ICP_VARIANTS)}; got {self.variant!r}")
        if self.max_iterations < 1 or self.voxel_size <= 0 or self.max_correspondence_distance <= 0:
            raise ConfigError("need max_iterations >= 1, voxel_size > 0 and max_correspondence_distance > 0")
        if self.normals_max_nn < 3:
            raise ConfigError(
                f"normals_max_nn must be >= 3 (a plane needs 3 points); got {self.normals_max_nn}"
            )
        if not self.name:
            short = "p2l" if self.variant == "point_to_plane" else "p2p"
            self.name = f"icp-{short}({self.max_iterations})"

    def prepare(self, points: Points) -> o3d.geometry.PointCloud:
        normals = self.variant == "point_to_plane"
        return prepare_cloud(
            points, self.min_range, self.max_range, self.voxel_size, normals, self.normals_max_nn
        )

    def register(
        self,
        source: o3d.geometry.PointCloud,
        target: o3d.geometry.PointCloud,
        initial_guess: Transform | None = None,
    ) -> RegistrationResult:
        guess = identity_guess(initial_guess)
        degenerate = too_few_points(source, target, guess, self.name)
        if degenerate is not None:
            return degenerate
        registration = o3d.pipelines.registration
        estimation = (
            registration.TransformationEstimationPointToPlane()
            if self.variant == "point_to_plane"
            else registration.TransformationEstimationPointToPoint()
        )
        criteria = registration.ICPConvergenceCriteria(
            self.relative_fitness, self.relative_rmse, self.max_iterations
        )
        result = registration.registration_icp(
            source, target, self.max_correspondence_distance, guess, estimation, criteria
        )
        return RegistrationResult(
            transform=np.asarray(result.transformation, dtype=np.float64).copy(),
            fitness=float(result.fitness),
            inlier_rmse=float(result.inlier_rmse),
            info={"correspondences": len(result.correspondence_set)},
        )
