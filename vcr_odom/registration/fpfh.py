"""open3d FPFH features + RANSAC: the classical global registration, needing no initial guess.

It is the baseline that, like VCR-Net, must find large motions on its own (``--stride``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from pydantic import Field

from vcr_odom.data.base import Points
from vcr_odom.geometry import Transform
from vcr_odom.registration.base import RegistrationResult
from vcr_odom.registration.open3d_icp import prepare_cloud, too_few_points
from vcr_odom.settings import Settings


@dataclass
class FpfhPrepared:
    """A frame ready for matching: the down-sampled cloud (with normals) and its FPFH descriptors."""

    cloud: o3d.geometry.PointCloud
    features: o3d.pipelines.registration.Feature


class FpfhRansac(Settings):
    """FPFH + RANSAC (open3d), deterministic for ``seed``; ``initial_guess`` is ignored.

    Why these defaults (docs/results.md has the figures): ``voxel_size=0.5`` m, since coarser
    grids lose accuracy faster than they save time; normals over two voxels and FPFH over five
    (large enough to see a car or a facade corner, the usual open3d choice); ``inlier_distance`` half
    a voxel, because hypotheses are scored by inlier count and a looser gate lets many slightly-off
    hypotheses tie; mutual filter and an edge-length checker reject inconsistent triplets early;
    ``max_range=60`` m, since sparse far rings give noisy normals and descriptors. No polish is built
    in: ``fpfh+icp`` and ``fpfh+kiss-icp`` polish it as they polish any global method.
    """

    voxel_size: float = Field(default=0.5, gt=0)
    feature_radius_factor: float = Field(default=5.0, gt=0)
    normal_radius_factor: float = Field(default=2.0, gt=0)
    feature_max_nn: int = Field(default=100, ge=1)
    inlier_distance_factor: float = Field(default=0.5, gt=0)
    edge_length_ratio: float = Field(default=0.9, gt=0, lt=1)
    mutual_filter: bool = True
    max_iterations: int = Field(default=100_000, ge=1)
    confidence: float = Field(default=0.999, gt=0, lt=1)
    min_range: float = Field(default=2.0, ge=0)
    max_range: float = Field(default=60.0, gt=0)
    seed: int = 0
    name: str = "fpfh"
    needs_initial_guess: bool = False

    def prepare(self, points: Points) -> FpfhPrepared:
        cloud = prepare_cloud(points, self.min_range, self.max_range, self.voxel_size, normals=False)
        search = o3d.geometry.KDTreeSearchParamHybrid
        if len(cloud.points) < 3:  # degenerate frame: no features; register() answers with a warning
            return FpfhPrepared(cloud, o3d.pipelines.registration.Feature())
        cloud.estimate_normals(search(radius=self.normal_radius_factor * self.voxel_size, max_nn=30))
        features = o3d.pipelines.registration.compute_fpfh_feature(
            cloud, search(radius=self.feature_radius_factor * self.voxel_size, max_nn=self.feature_max_nn)
        )
        return FpfhPrepared(cloud, features)

    def register(
        self, source: FpfhPrepared, target: FpfhPrepared, initial_guess: Transform | None = None
    ) -> RegistrationResult:
        del initial_guess  # a global method: the answer must not depend on a prior
        degenerate = too_few_points(source.cloud, target.cloud, np.eye(4), self.name)
        if degenerate is not None:
            return degenerate
        registration = o3d.pipelines.registration
        distance = self.inlier_distance_factor * self.voxel_size
        checkers = [
            registration.CorrespondenceCheckerBasedOnEdgeLength(self.edge_length_ratio),
            registration.CorrespondenceCheckerBasedOnDistance(distance),
        ]
        o3d.utility.random.seed(int(self.seed))  # per pair, so a result never depends on earlier pairs
        result = registration.registration_ransac_based_on_feature_matching(
            source.cloud,
            target.cloud,
            source.features,
            target.features,
            self.mutual_filter,
            distance,
            registration.TransformationEstimationPointToPoint(False),
            3,
            checkers,
            registration.RANSACConvergenceCriteria(self.max_iterations, self.confidence),
        )
        return RegistrationResult(
            transform=np.asarray(result.transformation, dtype=np.float64).copy(),
            fitness=float(result.fitness),
            inlier_rmse=float(result.inlier_rmse),
            info={"ransac_fitness": float(result.fitness)},
        )
