"""The pose graph: the nodes' odometry chain plus the accepted loops, optimised with open3d, loops
weighted by a Cauchy kernel; then every frame moved with the nodes around it.

Why a robust kernel on top of the loops' own checks: each check sees one loop; only the graph sees
whether the loops agree with each other. A loop whose residual stays large once the others pull the
trajectory into place is down-weighted round by round (iteratively re-weighted least squares), and
one that ends with a weight below :data:`DROP_WEIGHT` is dropped and named in ``loops.json``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import open3d as o3d
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from vcr_odom.geometry import Transform, invert
from vcr_odom.loops.drift import DriftModel
from vcr_odom.loops.nodes import Node

CAUCHY_SCALE = 3.0
"""Residual (in standard deviations, over the edge's 6 dimensions) where a loop's weight halves."""
ROUNDS = 5
DROP_WEIGHT = 0.1


@dataclass(frozen=True)
class LoopEdge:
    """A loop between nodes ``source`` and ``target``: ``transform`` is ``T_target_source``."""

    source: int
    target: int
    transform: Transform
    information: NDArray[np.float64]


@dataclass
class GraphResult:
    node_poses: NDArray[np.float64]
    weights: list[float]
    kept: list[bool]


def _odometry_information(drift: DriftModel, motion: Transform) -> NDArray[np.float64]:
    sigma_t, sigma_r = drift.step_sigmas(float(np.linalg.norm(motion[:3, 3])))
    return np.diag([sigma_r**-2] * 3 + [sigma_t**-2] * 3)


def _residual_chi2(poses: NDArray[np.float64], loop: LoopEdge) -> float:
    """``r^T I r`` of a loop under ``poses``, ``r`` the twist (rotation vector, translation) of the
    disagreement between the loop and the poses."""
    error = invert(loop.transform) @ invert(poses[loop.target]) @ poses[loop.source]
    twist = np.concatenate([Rotation.from_matrix(error[:3, :3]).as_rotvec(), error[:3, 3]])
    return float(twist @ loop.information @ twist)


def optimise(
    nodes: Sequence[Node], loops: Sequence[LoopEdge], drift: DriftModel | None = None
) -> GraphResult:
    """Node poses after optimisation; without loops, the odometry's, untouched."""
    drift = drift or DriftModel()
    odometry = np.stack([node.pose for node in nodes])
    if not loops:
        return GraphResult(odometry.copy(), [], [])
    weights = [1.0] * len(loops)
    poses = odometry
    for _ in range(ROUNDS):
        poses = _solve(odometry, loops, weights, drift)
        chi2 = [_residual_chi2(poses, loop) for loop in loops]
        new = [1.0 / (1.0 + c / (6.0 * CAUCHY_SCALE**2)) for c in chi2]
        if np.allclose(new, weights, atol=1e-3):
            break
        weights = new
    kept = [w >= DROP_WEIGHT for w in weights]
    if not all(kept):
        poses = _solve(odometry, loops, [w if k else 0.0 for w, k in zip(weights, kept, strict=True)], drift)
    return GraphResult(poses, weights, kept)


def _solve(
    odometry: NDArray[np.float64], loops: Sequence[LoopEdge], weights: Sequence[float], drift: DriftModel
) -> NDArray[np.float64]:
    registration = o3d.pipelines.registration
    graph = registration.PoseGraph()
    for pose in odometry:
        graph.nodes.append(registration.PoseGraphNode(pose))
    for k in range(len(odometry) - 1):
        motion = invert(odometry[k]) @ odometry[k + 1]
        info = _odometry_information(drift, motion)
        graph.edges.append(registration.PoseGraphEdge(k + 1, k, motion, info, uncertain=False))
    for loop, weight in zip(loops, weights, strict=True):
        if weight > 0:
            edge = registration.PoseGraphEdge(
                loop.source, loop.target, loop.transform, loop.information * weight, uncertain=False
            )
            graph.edges.append(edge)
    option = registration.GlobalOptimizationOption(
        max_correspondence_distance=1.0, edge_prune_threshold=0.0, reference_node=0
    )
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        registration.global_optimization(
            graph,
            registration.GlobalOptimizationLevenbergMarquardt(),
            registration.GlobalOptimizationConvergenceCriteria(),
            option,
        )
    return np.stack([np.asarray(node.pose) for node in graph.nodes])


def correct_frames(
    frame_poses: NDArray[np.float64],
    node_positions: Sequence[int],
    node_before: NDArray[np.float64],
    node_after: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Every frame moved by its nodes' corrections (``after @ inv(before)``), interpolated between the
    two nodes around it (rotation by slerp, translation linearly, by frame), so that the trajectory
    has no steps at nodes; the nodes themselves land exactly on ``node_after``."""
    corrections = node_after @ np.linalg.inv(node_before)
    positions = np.asarray(node_positions, dtype=np.float64)
    frames = np.clip(np.arange(len(frame_poses), dtype=np.float64), positions[0], positions[-1])
    interpolated = np.tile(np.eye(4), (len(frame_poses), 1, 1))
    if len(positions) == 1:
        interpolated[:] = corrections[0]
    else:
        rotations = Slerp(positions, Rotation.from_matrix(corrections[:, :3, :3]))
        interpolated[:, :3, :3] = rotations(frames).as_matrix()
        for axis in range(3):
            interpolated[:, axis, 3] = np.interp(frames, positions, corrections[:, axis, 3])
    return interpolated @ frame_poses
