"""A global registrar polished by ICP on the very clouds it was given: the pairs protocol's ``NAME+icp``.

Why not the odometry polish (:mod:`vcr_odom.odometry.polish`): odometry polishes full frames (ground
kept, 0.5 m voxels, point-to-plane), but a pair of the paper's protocol is only two N-point clouds,
metres apart point to point, where normals are meaningless. Point-to-point ICP with shrinking
correspondence gates reaches a start that is decimetres off and still ends as tight as the clouds'
sampling allows; the gates were chosen on kitti-sample frames 0-39 (the model card has the figures).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import open3d as o3d
from pydantic import Field, PositiveFloat

from vcr_odom.data.base import Points
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import Transform
from vcr_odom.registration.base import Registrar, RegistrationResult, identity_guess
from vcr_odom.settings import Settings

PAIR_POLISHES = ("icp",)
"""Polishes that make sense on an isolated pair (kiss-icp's needs the local map of a sequence)."""


class SparseIcp(Settings):
    """Point-to-point ICP on the clouds as given (no voxel grid: they are already sparse)."""

    distances: tuple[PositiveFloat, ...] = Field(default=(2.0, 1.0, 0.5, 0.25), min_length=1)
    max_iterations: int = Field(default=30, ge=1)
    name: str = "sparse-icp"
    needs_initial_guess: bool = True

    def prepare(self, points: Points) -> o3d.geometry.PointCloud:
        xyz = np.asarray(points, dtype=np.float64)[:, :3]
        return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(xyz)))

    def register(
        self,
        source: o3d.geometry.PointCloud,
        target: o3d.geometry.PointCloud,
        initial_guess: Transform | None = None,
    ) -> RegistrationResult:
        registration = o3d.pipelines.registration
        transform = identity_guess(initial_guess)
        criteria = registration.ICPConvergenceCriteria(1e-6, 1e-6, self.max_iterations)
        result = None
        for distance in self.distances:
            result = registration.registration_icp(
                source,
                target,
                distance,
                transform,
                registration.TransformationEstimationPointToPoint(),
                criteria,
            )
            transform = np.asarray(result.transformation, dtype=np.float64).copy()
        assert result is not None
        return RegistrationResult(transform, float(result.fitness), float(result.inlier_rmse))


class PolishedRegistrar:
    """``global_method`` then ``local_method`` started from its estimate; one Registrar for both."""

    needs_initial_guess = False

    def __init__(self, global_method: Registrar, local_method: Registrar, polish_name: str = "icp") -> None:
        self.global_method = global_method
        self.local_method = local_method
        self.name = f"{global_method.name}+{polish_name}"

    def prepare(self, points: Points) -> tuple[Any, Any]:
        return self.global_method.prepare(points), self.local_method.prepare(points)

    def register(
        self, source: tuple[Any, Any], target: tuple[Any, Any], initial_guess: Transform | None = None
    ) -> RegistrationResult:
        coarse = self.global_method.register(source[0], target[0], initial_guess)
        fine = self.local_method.register(source[1], target[1], coarse.transform)
        info = {"global_transform": coarse.transform, **fine.info}
        return RegistrationResult(fine.transform, fine.fitness, fine.inlier_rmse, info)


def polished_for_pairs(global_method: Registrar, polish: str) -> Registrar:
    """``NAME+POLISH`` for the pairs protocol; a clear error for a polish that needs a sequence."""
    if polish not in PAIR_POLISHES:
        raise ConfigError(
            f"+{polish} cannot polish an isolated pair (it needs a sequence's local map); "
            f"pairs-protocol polishes: {', '.join(PAIR_POLISHES)}"
        )
    return PolishedRegistrar(global_method, SparseIcp(), polish)
