"""A global registrar polished by ICP on the very clouds it was given: the pairs protocol's ``NAME+icp``.

Why not :mod:`vcr_odom.refine`: odometry polishes on the full frames (ground kept, 0.5 m voxels,
point-to-plane), but a pair of the paper's protocol is only two N-point clouds, a few metres apart
point to point, where normals are meaningless. Measured on kitti-sample frames 40-59 (N=512, start
within 1°/0.25 m of the truth, FPS over all points as pre-processing then did): point-to-point ICP
with a 0.5 m gate reached 0.022°/1.6 cm, point-to-plane (3 m normals) 0.025°/2.1 cm at 3x the time, a
2 m gate alone 0.053°/3.6 cm. A 0.5 m gate alone does not reach a start more than ~0.5 m off, hence
the coarse-to-fine gates. With FPS from a 16k-point subset (the pre-processing now) the two clouds
share fewer points; a last 0.25 m gate then matters. Measured on frames 0-39 (not the test block),
from VCR-Net's two-pass estimate: gates (2, 1, 0.5) m gave 0.078°/3.3 cm on same-scan pairs and
0.116°/5.1 cm on consecutive pairs; (2, 1, 0.5, 0.25) m gave 0.036°/1.8 cm and 0.133°/4.0 cm;
generalized ICP and point-to-plane (3-5 m normals) were worse on both.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import open3d as o3d

from vcr_odom.data.base import Points
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import Transform
from vcr_odom.registration.base import Registrar, RegistrationResult, identity_guess

PAIR_POLISHES = ("icp",)
"""Polishes that make sense on an isolated pair (kiss-icp's needs the local map of a sequence)."""


@dataclass
class SparseIcp:
    """Point-to-point ICP on the clouds as given (no voxel grid: they are already sparse)."""

    distances: tuple[float, ...] = (2.0, 1.0, 0.5, 0.25)
    max_iterations: int = 30
    name: str = "sparse-icp"
    needs_initial_guess: bool = True

    def __post_init__(self) -> None:
        if not self.distances or any(d <= 0 for d in self.distances) or self.max_iterations < 1:
            raise ConfigError("SparseIcp needs positive correspondence distances and max_iterations >= 1")

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
