"""The pose graph: the nodes' odometry chain, the accepted loops and each node's measured up
direction, optimised with open3d; loops and up directions weighted by a Cauchy kernel; then every
frame moved with the nodes around it.

Why a robust kernel on top of the loops' own checks: each check sees one loop; only the graph sees
whether the loops agree with each other. A loop whose residual stays large once the others pull the
trajectory into place is down-weighted round by round (iteratively re-weighted least squares), and
one that ends with a weight below :data:`DROP_WEIGHT` is dropped and named in ``loops.json``.

Why the rounds weigh the odometry by what the loops measured (:mod:`~vcr_odom.loops.cycles`): with
sigmas tighter than the odometry's noise, right loops disagree with it and are dropped (a handheld
VLP-16 walk at 10 Hz: 2 of 7, its odometry 5.5x noisier than the drift model). Only the rounds, which
decide what is kept: the final solve keeps the model's sigmas, as :data:`LOOP_SHARE` was tuned with
them; scaled there too, a VLP-16 walk whose odometry's orientation was 17 deg off on a stretch where
its positions were right ended 0.35 m off the truth against 0.28 m (unseen 877).

Why a corroborated loop keeps its full weight where the loops close too few cycles to measure the
odometry's noise: a handheld walk's heading drifts 15-27 deg a lap round a ~60 m courtyard, inside the
drift bound, and the graph's sigmas (a car's) made its one or two right loops outliers; the rounds
dropped them (weights 0.02-0.47) as they dropped the false fits (0.00-0.47), and no weight told them
apart. A loop whose two starts, a metre or more apart, polished into the one fit on a scene that
measures every direction (:attr:`~vcr_odom.loops.verify.LoopDecision.corroborated`) was right on every
courtyard walk and indoor walk replayed, and so was a fit whose surfaces face every direction well
(:data:`~vcr_odom.loops.corroboration.STRONG_SHARE`) whatever its starts did. Not on every drive: an HDL-64E figure eight (825) has a
corroborated fit 1.25 m off, and only the cycles of its 25 neighbours tell; so where cycles are many,
they scale the sigmas and every loop is weighed. Scaling the odometry's sigmas by the drift the
corroborated loops measure, instead of trusting them, let false fits along indoor corridors through
the rounds (docs/benchmarks.md, "Loops that measure the drift").

Why the final solve's odometry heading sigmas differ from edge to edge
(:mod:`~vcr_odom.loops.heading_support`): a walk's heading error is made in a few stretches where the
scans held it weakly, and a loop's correction belongs there, not spread evenly over the lap. Only
the final solve: with them in the rounds too, a loop 2.3 m off along a corridor (indoor walk 902, its
heading drifted 15 deg per 100 m on purpose) was kept, since loose edges let the graph bend to it.
The same holds for the edges whose frames fitted their predecessors poorly
(:mod:`~vcr_odom.loops.odometry_doubts`), whose factor scales both sigmas in the final solve.

Why up directions (:mod:`~vcr_odom.loops.up_priors`): loops cannot see a tilt that drifted between
them, since a lobe driven in a tilted plane still meets itself at its ends. Each node's measured up
(its walls', else its ground's) holds its roll and pitch; its heading and position stay free. They act
only with loops: without any, or where the rounds drop every loop, the odometry is returned untouched
(a walk whose one verified loop the rounds dropped was otherwise moved 2.5 m by its walls' up alone,
with `map` reporting no loop).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from vcr_odom.geometry import invert
from vcr_odom.loops.cycles import MIN_CYCLES, OdometryScale, cycle_outliers, loop_cycles, odometry_scale
from vcr_odom.loops.drift import DriftModel
from vcr_odom.loops.edges import GraphEdge
from vcr_odom.loops.heading_support import heading_sigma_factors
from vcr_odom.loops.nodes import Node, NodeNormals
from vcr_odom.loops.up_priors import ATTITUDE_SIGMA_DEG, UpPriors, up_priors

CAUCHY_SCALE = 3.0
"""Residual (in standard deviations, over the edge's dimensions) where an edge's weight halves."""
ROUNDS = 5
DROP_WEIGHT = 0.5
"""A loop whose Cauchy weight ends below this is dropped: its residual, once the other loops pull the
trajectory into place, is beyond 3 sigma per dimension. Every right loop on tuning seeds 532-543 ends
at 0.95 or more; a 1.25 m misfit on unseen drive 825 (both starts converged on it, fitness 0.75) ended
at 0.21 and was kept under the earlier 0.1."""
LOOP_SHARE = 0.04
"""The loops' information in the final solve, as a share of their own (sigma x5); the rounds that find
disagreeing loops use all of it. A passage is pinned by a loop every 6 m, each measured to 2-8 cm,
while the odometry between two nodes 3 m apart is better than that; at full weight the loops impose
their own scatter on the passage's shape. Chosen on tuning seeds 532-543 from 1, 0.2, 0.04 and 0.01:
at 0.04 the map's ATE fell on eight of ten drives (0.255 -> 0.195 m on an Avia figure eight, 0.075
-> 0.050 m on a highway loop) and rose on two by 4-7 %; the outlier rounds are unchanged, so no loop
they drop is kept (weaker loops there would let a 7 m false loop through the Cauchy kernel). Only
where the loops close enough cycles to weigh each other (:func:`loop_share`): a walk's one to four
loops impose no scatter, and at 1/25 a lone loop closed about half the heading it measured."""


@dataclass(frozen=True)
class LoopEdge(GraphEdge):
    """A loop between nodes ``source`` and ``target``: ``transform`` is ``T_target_source``;
    ``corroborated`` (:attr:`~vcr_odom.loops.verify.LoopDecision.corroborated`): kept at full weight
    by the rounds where the loops close too few cycles to weigh it (:func:`_trusted`)."""

    corroborated: bool = False


@dataclass
class GraphResult:
    node_poses: NDArray[np.float64]
    weights: list[float]
    kept: list[bool]
    up: UpPriors | None = None
    up_dropped: int = 0
    odometry: OdometryScale | None = None
    cycle_outliers: dict[int, tuple[int, int]] = field(default_factory=dict)
    """Loops dropped before the rounds (index -> misclosed cycles, cycles): :func:`cycle_outliers`."""
    heading_factors: NDArray[np.float64] | None = None
    """Each odometry edge's heading sigma factor (:func:`~vcr_odom.loops.heading_support.heading_sigma_factors`)."""
    fit_factors: NDArray[np.float64] | None = None
    """Each odometry edge's factor on both sigmas (:func:`~vcr_odom.loops.odometry_doubts.fit_sigma_factors`)."""
    trusted: int = 0
    """Loops the rounds kept at full weight (:func:`_trusted`)."""
    loop_share: float | None = None
    """Each kept loop's share of its information in the final solve (:func:`loop_share`)."""


def factor_summary(factors: NDArray[np.float64]) -> dict[str, float | int | None]:
    """What ``metrics.json`` says of the odometry edges' sigma factors (:attr:`GraphResult.heading_factors`
    or :attr:`GraphResult.fit_factors`): how many edges were raised, and how far."""
    raised = factors[factors > 1.0]
    return {
        "edges": len(factors),
        "raised": len(raised),
        "median_raised": round(float(np.median(raised)), 3) if len(raised) else None,
        "largest": round(float(factors.max()), 3) if len(factors) else None,
    }


def _residual_chi2(poses: NDArray[np.float64], edge: GraphEdge) -> float:
    """``r^T I r`` of an edge under ``poses``, ``r`` the twist (rotation vector, translation) of the
    disagreement between the edge and the poses."""
    error = invert(edge.transform) @ invert(poses[edge.target]) @ poses[edge.source]
    twist = np.concatenate([Rotation.from_matrix(error[:3, :3]).as_rotvec(), error[:3, 3]])
    return float(twist @ edge.information @ twist)


def optimise(
    nodes: Sequence[Node],
    loops: Sequence[LoopEdge],
    drift: DriftModel | None = None,
    attitude_sigma_deg: float = ATTITUDE_SIGMA_DEG,
    fit_factors: NDArray[np.float64] | None = None,
    normals: NodeNormals | None = None,
) -> GraphResult:
    """Node poses after optimisation; without loops, the odometry's, untouched.
    ``attitude_sigma_deg``: the up directions' weight (0 leaves them out); ``fit_factors``: per
    odometry edge, a factor on both its sigmas in the final solve, where the odometry fitted poorly
    (:func:`~vcr_odom.loops.odometry_doubts.fit_sigma_factors`; None: all 1); ``normals``: the nodes'
    normals where the loop phase already holds them."""
    drift = drift or DriftModel()
    odometry = np.stack([node.pose for node in nodes])
    frames = np.diff([node.position for node in nodes]).astype(int).tolist()
    if not loops:
        return GraphResult(odometry.copy(), [], [])
    normals = NodeNormals(nodes) if normals is None else normals
    up = up_priors(nodes, attitude_sigma_deg, normals)
    sigmas = drift.chain_sigmas(odometry, frames)
    cycles = loop_cycles(nodes, loops, sigmas)
    scale = odometry_scale(cycles)
    outliers = cycle_outliers(cycles, scale.outlier_scale)
    edges: list[GraphEdge] = [*loops, *up.edges]
    trusted = _trusted(edges, len(cycles))
    weights = [0.0 if k in outliers else 1.0 for k in range(len(edges))]
    poses = odometry
    for _ in range(ROUNDS):
        poses = _solve(odometry, sigmas, edges, weights, scale.scale)
        chi2 = [_residual_chi2(poses, edge) for edge in edges]
        new = [
            0.0 if k in outliers else 1.0 if trusted[k] else 1.0 / (1.0 + c / (edge.dof * CAUCHY_SCALE**2))
            for k, (c, edge) in enumerate(zip(chi2, edges, strict=True))
        ]
        if np.allclose(new, weights, atol=1e-3):
            break
        weights = new
    kept = [w >= DROP_WEIGHT for w in weights]
    n = len(loops)
    if not any(kept[:n]):  # every loop dropped: the up priors alone do not move the odometry
        return GraphResult(odometry.copy(), weights[:n], kept[:n], None, 0, scale, outliers)
    share = loop_share(sum(kept[:n]), len(cycles))
    final = [
        w * (share if isinstance(edge, LoopEdge) else 1.0) if k else 0.0
        for w, k, edge in zip(weights, kept, edges, strict=True)
    ]
    heading_factors = heading_sigma_factors(nodes, normals)
    fitted = np.ones(len(sigmas[0])) if fit_factors is None else np.asarray(fit_factors, dtype=np.float64)
    final_sigmas = (sigmas[0] * fitted, sigmas[1] * heading_factors * fitted)
    poses = _solve(odometry, final_sigmas, edges, final)
    return GraphResult(
        poses,
        weights[:n],
        kept[:n],
        up,
        kept[n:].count(False),
        scale,
        outliers,
        heading_factors,
        fitted,
        sum(trusted[:n]),
        share,
    )


def loop_share(kept: int, cycles: int) -> float:
    """Each kept loop's share of its information in the final solve: :data:`LOOP_SHARE` where the loops
    close enough cycles to weigh each other (:data:`~vcr_odom.loops.cycles.MIN_CYCLES`, as for
    :func:`_trusted`), else one loop's worth shared among the ``kept`` loops. Over 57 recorded
    courtyard walks the median map fell from 0.82 to 0.74 of the odometry's ATE (a little on 24 held
    out), and indoor walks whose heading drifted 20 deg per 100 m from 0.53 and 0.71 m to 0.28 and
    0.25 m (901, 902; docs/benchmarks.md, "Few loops, whole loops"); car drives close many cycles and
    are unchanged."""
    if cycles >= MIN_CYCLES:
        return LOOP_SHARE
    return max(LOOP_SHARE, 1.0 / max(kept, 1))


def _trusted(edges: Sequence[GraphEdge], cycles: int) -> list[bool]:
    """Per edge, whether the rounds leave its weight at 1: a corroborated loop where the loops close
    too few cycles (:data:`~vcr_odom.loops.cycles.MIN_CYCLES`) to measure the odometry's noise, so that
    only the drift model's sigmas, a car's, would judge it. Where cycles are many, they scale the
    sigmas and every loop is weighed."""
    few = cycles < MIN_CYCLES
    return [few and isinstance(edge, LoopEdge) and edge.corroborated for edge in edges]


def _solve(
    odometry: NDArray[np.float64],
    sigmas: tuple[NDArray[np.float64], NDArray[np.float64]],
    loops: Sequence[GraphEdge],
    weights: Sequence[float],
    scale: float = 1.0,
) -> NDArray[np.float64]:
    """The graph solved once: ``odometry`` the node poses, ``sigmas`` its edges' (m, rad:
    :meth:`~vcr_odom.loops.drift.DriftModel.chain_sigmas`), ``scale`` their factor
    (:func:`~vcr_odom.loops.cycles.odometry_scale`)."""
    registration = o3d.pipelines.registration
    graph = registration.PoseGraph()
    for pose in odometry:
        graph.nodes.append(registration.PoseGraphNode(pose))
    for k, (sigma_t, sigma_r) in enumerate(zip(*sigmas, strict=True)):
        motion = invert(odometry[k]) @ odometry[k + 1]
        info = np.diag([(scale * sigma_r) ** -2] * 3 + [(scale * sigma_t) ** -2] * 3)
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
