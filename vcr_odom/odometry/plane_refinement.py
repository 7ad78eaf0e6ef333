"""A point-to-plane finish for the kiss-icp polish's point-to-point fit, on scans of few points.

kiss-icp registers each frame's points to the nearest points of its local map. On a solid-state scan
(few registration points, a narrow or nodding field) at a walk's small steps that fit slides back
towards standing still, in stretches of a few frames where the step comes out 40-125 % short, though
the surfaces face the way of travel: point-to-point ICP between two such frames started from the truth
slides the same way, point-to-plane does not (docs/benchmarks.md, "A point-to-plane finish for
solid-state scans"). The finish measures each registration point's distance to the map along that
point's own surface normal, so only what the surfaces say counts, not where along them the samples
fell. Normals come from the frame's denser down-sampled cloud, which the polish already has, so the
map needs only a KD-tree.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from vcr_odom.geometry import Transform, motion_difference

NORMAL_NEIGHBOURS = 10
"""Points of the down-sampled frame (half a map voxel apart) a registration point's normal is fitted to."""

MAP_STRIDE = 3
"""Every this-many-th point of kiss-icp's local map (up to 20 a voxel) goes into the finish's KD-tree:
the normals come from the frame, so the map only needs to lie on its surfaces, and the tree is the
finish's largest cost (a Mid-360 drive's map held 220,000 points: 11 ms for the 68,000 of a third of
it near the frame)."""

ASSOCIATIONS = 3
"""Nearest-neighbour searches per fit; between them the linearised problem is solved to its minimum."""

MAX_CHANGE_SIGMAS = 3.0
MAX_CHANGE_DEG = 2.0
"""A finish that moves kiss-icp's result further than this many kiss-icp sigmas (its correspondence
gate) or degrees is not a finish: the point-to-point result is kept."""

MIN_POINTS = 20
"""Fewer usable registration points, map points or matches than this: nothing to finish with."""


def registration_normals(source: np.ndarray, downsample: np.ndarray) -> np.ndarray:
    """Unit surface normals (rows) at ``source`` from their :data:`NORMAL_NEIGHBOURS` nearest points of
    ``downsample``; NaN rows where the frame has too few points for a plane."""
    source = np.asarray(source, dtype=np.float64)
    downsample = np.asarray(downsample, dtype=np.float64)
    if len(source) == 0 or len(downsample) < 3:
        return np.full((len(source), 3), np.nan)
    neighbours = min(NORMAL_NEIGHBOURS, len(downsample))
    _, index = cKDTree(downsample).query(source, k=neighbours)
    patches = downsample[index.reshape(len(source), neighbours)]
    centred = patches - patches.mean(axis=1, keepdims=True)
    _, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
    return vectors[:, :, 0]


def refine_point_to_plane(
    pose: Transform, source: np.ndarray, normals: np.ndarray, map_points: np.ndarray, sigma: float
) -> Transform:
    """``pose`` (the frame in the world, from kiss-icp) refined so that ``source`` lies on the map's
    surfaces along its ``normals``: Gauss-Newton with a Geman-McClure weight of scale ``sigma`` and
    kiss-icp's gate of 3 ``sigma``. Returns ``pose`` unchanged where there is too little to fit or the
    result moves it by more than the gate (:data:`MAX_CHANGE_SIGMAS`)."""
    pose = np.asarray(pose, dtype=np.float64)
    usable = np.isfinite(normals).all(axis=1)
    source, normals = np.asarray(source, dtype=np.float64)[usable], normals[usable]
    gate = 3.0 * sigma
    if not np.isfinite(gate) or gate <= 0 or len(source) < MIN_POINTS:
        return pose
    target = _map_near(map_points[::MAP_STRIDE], source @ pose[:3, :3].T + pose[:3, 3], gate)
    if len(target) < MIN_POINTS:
        return pose
    tree = cKDTree(target, balanced_tree=False, compact_nodes=False)
    refined = pose
    for _ in range(ASSOCIATIONS):
        moved = source @ refined[:3, :3].T + refined[:3, 3]
        distance, index = tree.query(moved, distance_upper_bound=gate)
        matched = np.isfinite(distance)
        if matched.sum() < MIN_POINTS:
            return pose
        refined = _solved(refined, source[matched], normals[matched], target[index[matched]], sigma)
    change_m, change_deg = motion_difference(pose, refined)
    if change_m > MAX_CHANGE_SIGMAS * sigma or change_deg > MAX_CHANGE_DEG:
        return pose
    return refined


def _map_near(map_points: np.ndarray, moved: np.ndarray, gate: float) -> np.ndarray:
    """The map's points within the frame's bounding box, widened by the gate."""
    low, high = moved.min(axis=0) - gate, moved.max(axis=0) + gate
    return map_points[np.all((map_points >= low) & (map_points <= high), axis=1)]


def _solved(
    pose: Transform, source: np.ndarray, normals: np.ndarray, target: np.ndarray, sigma: float, steps: int = 3
) -> Transform:
    """Gauss-Newton on fixed correspondences: each source point's distance to its target point along
    its normal (both turned with the pose), linearised about the sensor's position (not the world's
    origin, which may lie kilometres away)."""
    centre = pose[:3, 3].copy()
    target = target - centre
    for _ in range(steps):
        moved = source @ pose[:3, :3].T + (pose[:3, 3] - centre)
        turned = normals @ pose[:3, :3].T
        residual = np.einsum("ij,ij->i", moved - target, turned)
        jacobian = np.hstack([np.cross(target, turned), turned])
        weight = 1.0 / (1.0 + (residual / sigma) ** 2) ** 2
        hessian = jacobian.T @ (jacobian * weight[:, None])
        damping = 1e-9 * max(float(np.trace(hessian)), 1e-12)
        delta = -np.linalg.solve(hessian + damping * np.eye(6), jacobian.T @ (weight * residual))
        rotation = Rotation.from_rotvec(delta[:3]).as_matrix()
        turned_pose = np.eye(4)
        turned_pose[:3, :3] = rotation @ pose[:3, :3]
        turned_pose[:3, 3] = rotation @ (pose[:3, 3] - centre) + delta[3:] + centre
        pose = turned_pose
        if np.linalg.norm(delta) < 1e-6:
            break
    return pose
