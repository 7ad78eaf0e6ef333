"""The pose graph: which loops agree, then one least-squares solve, then every frame moved with its nodes.

Consistency (:func:`consistent_loops`): pairwise consistency maximisation (PCM; Mangelson et al.,
ICRA 2018). A false loop asks for a correction no right loop agrees with; right loops agree with each
other, whatever the odometry's drift, since the drift they correct is shared.

The solve (:func:`optimise`): odometry edges and loops weighted by what each measured
(:func:`~vcr_odom.loops.verify.fit_information`), the gravity priors, open3d's Levenberg-Marquardt.
Where no loop is kept the odometry is returned untouched: the priors alone do not move it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import networkx as nx
import numpy as np
import open3d as o3d
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from vcr_odom.geometry import adjoint, invert, twist
from vcr_odom.loops.candidates import Chain, LoopEdge, chi2_gate, mahalanobis2
from vcr_odom.loops.gravity import UpPriors
from vcr_odom.loops.settings import LoopSettings


def consistent_loops(
    loops: Sequence[LoopEdge], chain: Chain, confidence: float
) -> tuple[list[bool], list[bool], NDArray]:
    """Per loop, whether every largest mutually consistent set holds it, whether some largest set does
    (where two equally large sets disagree, the loops cannot say which is right: PCM's premise, that
    right loops outnumber any set of false ones that agree, decides nothing), and each pair's squared
    Mahalanobis distance (the cycle's misclosure under its uncertainty: the odometry edges one loop
    spans and the other does not, and both loops' own)."""
    count = len(loops)
    corrections = [chain.correction(loop) for loop in loops]
    own = [chain.loop_covariance(loop) for loop in loops]
    distances = np.zeros((count, count))
    for a in range(count):
        for b in range(a + 1, count):
            spans = chain.between((loops[a].target, loops[a].source), (loops[b].target, loops[b].source))
            spread = spans + own[a] + own[b]
            distances[a, b] = distances[b, a] = mahalanobis2(corrections[a] - corrections[b], spread)
    gate = chi2_gate(confidence, 6)
    graph = nx.Graph()
    graph.add_nodes_from(range(count))
    graph.add_edges_from((a, b) for a in range(count) for b in range(a + 1, count) if distances[a, b] <= gate)
    cliques = sorted(map(set, nx.find_cliques(graph)), key=len, reverse=True)  # every maximal one
    largest = [clique for clique in cliques if len(clique) == len(cliques[0])]
    in_every = set.intersection(*largest) if largest else set()
    in_some = set.union(*largest) if largest else set()
    return [k in in_every for k in range(count)], [k in in_some for k in range(count)], distances


@dataclass
class Selection:
    """Which loops the graph takes: per loop, None or the (check, reason) it failed; and the factor the
    kept loops measured on the odometry's covariance."""

    verdicts: list[tuple[str, str] | None]
    odometry_scale: float


def select_loops(loops: Sequence[LoopEdge], chain: Chain, settings: LoopSettings) -> Selection:
    """The largest mutually consistent set (:func:`consistent_loops`; where equally large sets disagree,
    only the loops all of them hold), then, in rounds, the odometry's
    drift measured by the loops kept (:func:`odometry_scale`) and every loop whose correction that drift
    makes unlikely (``odometry_confidence``) left out: a look-alike place the fit information allowed."""
    consistent, contested, distances = consistent_loops(loops, chain, settings.pairwise_confidence)
    pairwise = chi2_gate(settings.pairwise_confidence, 6)
    verdicts: list[tuple[str, str] | None] = [None] * len(loops)
    members = [k for k in range(len(loops)) if consistent[k]]
    for k in range(len(loops)):
        if contested[k] and not consistent[k]:
            verdicts[k] = (
                "inconsistent",
                "rejected: an equally large set of loops that disagrees with its own is as likely",
            )
        elif not consistent[k]:
            misclosed = sum(distances[k, b] > pairwise for b in members)
            verdicts[k] = (
                "inconsistent",
                f"rejected: its cycles with {misclosed} of the {len(members)} loops kept do not close",
            )
    gate = chi2_gate(settings.odometry_confidence, 6)
    scale = 1.0
    for _ in range(ROUNDS):
        scale = odometry_scale([loops[k] for k in members], chain)
        beyond = [k for k in members if chain.loop_chi2(loops[k], scale) > gate]
        if not beyond or len(beyond) == len(members):
            break
        for k in beyond:
            verdicts[k] = (
                "odometry",
                f"rejected: asks the odometry for more than its drift as the other loops measured it "
                f"(chi2 {chain.loop_chi2(loops[k], scale):.1f} > {gate:.1f})",
            )
        members = [k for k in members if k not in beyond]
    return Selection(verdicts, scale)


ROUNDS = 5
"""Rounds of measuring the odometry's drift on the loops kept and leaving out the unlikely ones."""


def odometry_scale(loops: Sequence[LoopEdge], chain: Chain) -> float:
    """The factor on the odometry's covariance that makes the loops' corrections as likely as their
    dimensions say (the median squared Mahalanobis distance that of chi-square on 6 dof: a robust
    variance component estimate). The fit information says which directions each edge holds well,
    not how far a frame-to-map odometry drifts along them: the loops measure that."""
    if not loops:
        return 1.0
    target = chi2_gate(0.5, 6)  # chi-square's median on 6 dof

    def median_chi2(log_scale: float) -> float:
        return float(np.median([chain.loop_chi2(loop, math.exp(log_scale)) for loop in loops]))

    low, high = math.log(1e-6), math.log(1e4)
    for _ in range(40):  # the distances fall as the scale grows: bisect
        middle = 0.5 * (low + high)
        low, high = (middle, high) if median_chi2(middle) > target else (low, middle)
    return math.exp(0.5 * (low + high))


def optimise(
    node_poses: NDArray[np.float64],
    odometry_information: Sequence[NDArray[np.float64]],
    loops: Sequence[LoopEdge],
    up: UpPriors | None = None,
    scale: float = 1.0,
) -> NDArray[np.float64]:
    """Node poses after optimisation (the odometry's covariance times ``scale``); without loops, the
    odometry's, untouched."""
    if not loops:
        return np.array(node_poses, copy=True)
    registration = o3d.pipelines.registration
    graph = registration.PoseGraph()
    for pose in node_poses:
        graph.nodes.append(registration.PoseGraphNode(pose))
    odometry = [
        LoopEdge(k + 1, k, invert(node_poses[k]) @ node_poses[k + 1], information / scale)
        for k, information in enumerate(odometry_information)
    ]
    for edge in [*odometry, *loops, *([] if up is None else up.edges)]:
        graph.edges.append(
            registration.PoseGraphEdge(
                edge.source, edge.target, edge.transform, source_frame_information(edge), uncertain=False
            )
        )
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


def source_frame_information(edge: LoopEdge) -> NDArray[np.float64]:
    """The edge's information (the target's frame, as a fit measures it) in its source's frame, where
    open3d's pose graph reads it: its error is ``X^-1 T_target^-1 T_source``, a twist of the source."""
    lever = adjoint(edge.transform)
    return lever.T @ edge.information @ lever


def residual_chi2(poses: NDArray[np.float64], loop: LoopEdge) -> float:
    """``r^T I r`` of a loop under ``poses`` (how far the solved graph is from what it measured)."""
    residual = twist(invert(loop.transform) @ invert(poses[loop.target]) @ poses[loop.source])
    return float(residual @ source_frame_information(loop) @ residual)  # the error is the source's


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
