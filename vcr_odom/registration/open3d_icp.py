"""open3d ICP (point-to-plane or point-to-point) behind the :class:`Registrar` interface.

The local baseline: accurate when started near the answer (identity or a constant-velocity guess),
wrong when the motion exceeds its correspondence distance. "ICP(10)" of the paper is 10 iterations.
"""

from __future__ import annotations

import warnings
from typing import Literal

import numpy as np
import open3d as o3d
from pydantic import Field, model_validator

from vcr_odom.data.base import Points
from vcr_odom.errors import DataWarning
from vcr_odom.geometry import Transform
from vcr_odom.preprocess import crop_range
from vcr_odom.registration.base import TOO_FEW_POINTS, RegistrationResult, identity_guess
from vcr_odom.settings import Settings

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


class Open3dIcp(Settings):
    """open3d ``registration_icp`` on voxel-down-sampled frames.

    Why these defaults (docs/results.md has the figures): ``voxel_size=0.5`` m keeps the accuracy
    of finer grids at a fraction of the points; ``max_correspondence_distance=1.0`` m covers a car's
    motion between two 10 Hz scans from the identity; 100 iterations with relative fitness/RMSE 1e-6
    is "converged", 10 is the paper's ICP(10). Point-to-point is worse on real scans, where the ring
    pattern on the road drags it. Ranges as in pre-processing (no ego-car returns, no sparse far
    field). ``normals_max_nn=10``: at 0.5 m voxels the two-voxel ball holds few more points, so more
    neighbours cost time without changing a normal. ``name``: derived from the variant when empty.
    """

    variant: Literal["point_to_plane", "point_to_point"] = "point_to_plane"
    max_iterations: int = Field(default=100, ge=1)
    relative_fitness: float = Field(default=1e-6, ge=0)
    relative_rmse: float = Field(default=1e-6, ge=0)
    voxel_size: float = Field(default=0.5, gt=0)
    max_correspondence_distance: float = Field(default=1.0, gt=0)
    min_range: float = Field(default=2.0, ge=0)
    max_range: float = Field(default=80.0, gt=0)
    normals_max_nn: int = Field(default=10, ge=3, description="a plane needs 3 points")
    name: str = ""
    needs_initial_guess: bool = True

    @model_validator(mode="after")
    def _name_from_variant(self) -> Open3dIcp:
        if not self.name:
            short = "p2l" if self.variant == "point_to_plane" else "p2p"
            object.__setattr__(self, "name", f"icp-{short}({self.max_iterations})")
        return self

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
