"""How well the scans support each odometry edge's heading: the pose graph's heading sigmas grow where
two consecutive nodes' clouds constrain rotation weakly.

Why: a walk's heading error is not spread evenly along its path. A narrow field of view sweeping round
a corner sees walls its local map does not hold yet, and the scan matcher keeps the turn rate it had:
on courtyard walk 881 (handheld Avia) frames 532-536 truly turned 2.4 deg a frame and the odometry
0.3-1.1, so that one node edge of 42 carries 12 of the lap's 16 deg. With every edge's heading equally
certain, a loop spreads its correction evenly over the lap and leaves that bend in the map. The clouds
of two nodes round such a turn overlap little, or only on a wall that lets them turn: their
point-to-plane information about rotation is what tells the graph where the heading was weakly held.
Given each edge's true error as its sigma (a one-off test), 881's map would end at 0.21 m instead of
0.71 m: the weights, not the loops, held it back. The graph uses these factors in its final solve only
(:func:`~vcr_odom.loops.graph.optimise`): which loops are kept stays the drift model's decision.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from vcr_odom.geometry import invert
from vcr_odom.loops.nodes import Node, NodeNormals, normal_cloud

MAX_SIGMA_FACTOR = 10.0
"""The most an edge's heading sigma is raised: an edge whose clouds share nothing would otherwise free
the heading entirely. On the tuning walks (881, 884, 891, 894, 898, 899) 5, 10 and 20 moved the maps'
ATE by 4 % at most from each other."""
MIN_CORRESPONDENCES = 10
CORRESPONDENCE_VOXELS = 2.0
"""A point of the later cloud pairs with the earlier cloud's nearest point within this many voxels,
at the odometry's relative pose."""


def rotation_information(
    source: Node, target: Node, target_normals: NDArray[np.float64] | None = None
) -> float:
    """The information per correspondence about the weakest rotation axis when ``source``'s cloud is
    fitted point-to-plane onto ``target``'s at the odometry's relative pose, translation left free
    (the rotation block's Schur complement): 0 where the clouds share under
    :data:`MIN_CORRESPONDENCES` points. open3d's information matrix is point-to-point, blind to a
    wall that lets a cloud turn. ``target_normals``: ``target``'s, where already estimated."""
    relative = invert(target.pose) @ source.pose
    points = source.cloud.astype(np.float64) @ relative[:3, :3].T + relative[:3, 3]
    distances, nearest = cKDTree(target.cloud).query(
        points, distance_upper_bound=CORRESPONDENCE_VOXELS * target.cloud_voxel
    )
    paired = np.isfinite(distances)
    if paired.sum() < MIN_CORRESPONDENCES:
        return 0.0
    if target_normals is None:
        target_normals = np.asarray(normal_cloud(target.cloud, target.cloud_voxel).normals)
    normals = target_normals[nearest[paired]]
    jacobian = np.hstack([np.cross(points[paired], normals), normals])
    hessian = jacobian.T @ jacobian / paired.sum()
    rotation, cross, translation = hessian[:3, :3], hessian[:3, 3:], hessian[3:, 3:]
    reduced = rotation - cross @ np.linalg.pinv(translation) @ cross.T
    return float(np.linalg.eigvalsh(reduced)[0])


def heading_sigma_factors(nodes: Sequence[Node], normals: NodeNormals | None = None) -> NDArray[np.float64]:
    """Per edge of the node chain (one fewer than the nodes), the factor on its heading sigma:
    ``sqrt(median / own)`` of :func:`rotation_information`, from 1 (as well held as the run's typical
    edge, or better) to :data:`MAX_SIGMA_FACTOR`. Relative to the run's median, so that the drift
    model's sigmas stay what they were tuned as for a typical edge of any sensor. ``normals``: the
    nodes' normals where the loop phase already holds them."""
    normals = NodeNormals(nodes) if normals is None else normals
    information = np.array(
        [rotation_information(nodes[k + 1], nodes[k], normals.normals(k)) for k in range(len(nodes) - 1)],
        dtype=np.float64,
    )
    if len(information) == 0:
        return information
    floor = 1e-9
    typical = max(float(np.median(information)), floor)
    return np.clip(np.sqrt(typical / np.maximum(information, floor)), 1.0, MAX_SIGMA_FACTOR)
