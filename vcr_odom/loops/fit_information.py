"""What a loop's polished fit measures: its information for the pose graph, the translation it holds
least (for the degeneracy probe), and how evenly its surfaces face every direction."""

from __future__ import annotations

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from vcr_odom.geometry import Transform
from vcr_odom.odometry.degeneracy import shares_of

EFFECTIVE_POINTS = 50.0
"""Independent points behind a loop's uncertainty: voxel points are correlated, so the ICP Hessian of
all of them would make a loop ~100x more certain than the odometry it corrects."""


def fit_hessian(
    source: o3d.geometry.PointCloud, target: o3d.geometry.PointCloud, transform: Transform, distance: float
) -> NDArray[np.float64]:
    """The fit's ICP Hessian (open3d order: rotation, then translation) at correspondence ``distance``:
    what both the loop's information and the probe's direction are read from."""
    return np.asarray(
        o3d.pipelines.registration.get_information_matrix_from_point_clouds(
            source, target, distance, transform
        )
    )


def loop_information(hessian: NDArray[np.float64], rmse: float) -> NDArray[np.float64]:
    """The loop edge's information: the fit's :func:`fit_hessian` scaled to :data:`EFFECTIVE_POINTS`
    points of the fit's own noise."""
    count = max(float(hessian[5, 5]), 1.0)  # the translation block's diagonal counts correspondences
    noise = max(float(rmse), 0.05)
    return hessian * (EFFECTIVE_POINTS / count) / noise**2


def weakest_translation(hessian: NDArray[np.float64]) -> NDArray[np.float64]:
    """The unit translation the fit constrains least (the translation block of its :func:`fit_hessian`
    with rotation eliminated: its eigenvector of the smallest eigenvalue), in the target frame."""
    rotation, cross, translation = hessian[:3, :3], hessian[:3, 3:], hessian[3:, 3:]
    reduced = translation - cross.T @ np.linalg.pinv(rotation) @ cross
    _, vectors = np.linalg.eigh(reduced)
    return vectors[:, 0]


def weakest_share(
    target: o3d.geometry.PointCloud, fit: o3d.pipelines.registration.RegistrationResult
) -> float:
    """The smallest share of the fit's correspondence normals (``target``'s, at the pairs open3d's ICP
    ended with) along any direction (:func:`~vcr_odom.odometry.degeneracy.shares_of`). Near 0 where the
    fit could slide; 0 without a pair."""
    pairs = np.asarray(fit.correspondence_set)
    if len(pairs) == 0:
        return 0.0
    return float(shares_of(np.asarray(target.normals)[pairs[:, 1]])[0][0])
