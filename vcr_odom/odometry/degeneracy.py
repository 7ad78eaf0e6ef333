"""Scans in which motion cannot be measured, wholly or along some direction.

Almost every point on one plane (a sensor facing the road or a wall): any scan matcher then slides
along that plane where the scans give it nothing to hold, and its fit stays as good as ever, so
nothing else in the run notices. Such frames are named in the run's output (``single_plane_frames``
in metrics.json) rather than passed off as measured.

Surfaces that all face a few ways (a footpath between parallel walls, a wall ahead and the ground)
leave one direction unmeasured: no surface normal points along it. A scan matcher's result moves
along it by whatever pulls hardest (a far corner, noise), and a constant-velocity prior then carries
each such step into the next frame, so the error ramps up frame after frame. :func:`weak_axes` finds
such directions and :func:`hold_along` keeps the start's position along them: the classic
solution remapping of degeneracy-aware ICP (Zhang, Kaess and Singh, ICRA 2016), on translation.

Measured on synthetic drives: a narrow-field (Livox Avia-like) sensor at a turnaround that sees only
road gives 0.13-0.15 m of thickness (its odometry slid 0.3-0.6 m a frame there); scans that register
well give 0.39 m (Avia keyframes) to 4 m, KITTI scans 0.8 m (docs/benchmarks.md)."""

from __future__ import annotations

import numpy as np

from vcr_odom.data.base import Points

SINGLE_PLANE_M = 0.25
"""Thickness (standard deviation across the best-fitting plane) below which a scan is one plane."""
SAMPLE_POINTS = 2000
"""Points the thickness is measured on (an even stride through the scan: deterministic and ~0.1 ms)."""


def plane_thickness(points: Points) -> float:
    """The spread of ``points`` across their best-fitting plane, in metres (inf under 10 points)."""
    xyz = np.asarray(points)[:, :3]
    xyz = xyz[:: max(1, len(xyz) // SAMPLE_POINTS)]
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    if len(xyz) < 10:
        return float("inf")
    smallest = np.linalg.eigvalsh(np.cov(xyz.T.astype(np.float64)))[0]
    return float(np.sqrt(max(smallest, 0.0)))


def single_plane(points: Points) -> float | None:
    """The scan's thickness where it is one plane (under :data:`SINGLE_PLANE_M`), else None."""
    thickness = plane_thickness(points)
    return thickness if thickness < SINGLE_PLANE_M else None


WEAK_AXIS_SHARE = 0.02
"""A direction with less than this share of the scan's surface normals (an eigenvalue of the mean of
their outer products; the three add up to 1) is one the scan cannot measure translation along.
Measured on a courtyard walk with a Livox Avia (docs/benchmarks.md, "Directions a scan cannot
measure"): 0.001-0.006 on the footpath where kiss-icp slid, 0.04-0.23 where it held."""
NORMAL_NEIGHBOURS = 20
"""Neighbours a surface normal is fitted to (at most), and the fewest points worth measuring."""


def normal_shares(points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """How the surface normals of ``points`` (estimated within ``radius``, open3d) share the three
    directions: eigenvalues (ascending, adding up to 1) and eigenvectors (columns) of the mean outer
    product of the normals. NaN shares under 20 points."""
    import open3d as o3d

    xyz = np.asarray(points, dtype=np.float64)[:, :3]
    if len(xyz) < NORMAL_NEIGHBOURS:
        return np.full(3, np.nan), np.eye(3)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=NORMAL_NEIGHBOURS))
    return shares_of(np.asarray(cloud.normals))


def shares_of(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending, adding up to 1) and eigenvectors (columns) of the mean outer product of
    unit ``normals`` (rows): how much of the surfaces faces each direction."""
    return np.linalg.eigh(normals.T @ normals / len(normals))


def weak_axes(points: np.ndarray, radius: float, share: float = WEAK_AXIS_SHARE) -> np.ndarray:
    """Unit directions (rows, in the points' frame) along which the surfaces of ``points`` hold no
    translation: those whose :func:`normal_shares` is under ``share``. None (a 0 x 3 array) under 20
    points, or with ``share`` 0."""
    if share <= 0:
        return np.zeros((0, 3))
    values, vectors = normal_shares(points, radius)
    return vectors[:, values < share].T


def hold_along(pose: np.ndarray, start: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """``pose`` (a sensor pose whose scan has the weak ``axes``, sensor frame) with its position along
    those axes moved back to ``start``'s: what the registration could not measure stays where it began."""
    if len(axes) == 0:
        return pose
    world_axes = axes @ pose[:3, :3].T
    held = np.array(pose, dtype=np.float64, copy=True)
    held[:3, 3] += world_axes.T @ (world_axes @ (start[:3, 3] - pose[:3, 3]))
    return held
