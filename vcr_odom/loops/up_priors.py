"""Up priors: each node's roll and pitch held to the up measured in its cloud, where the odometry's
tilt drifted from it.

Why: loops cannot see a tilt that drifted between them, since a lobe driven in a tilted plane still
meets itself at its ends. Walls measure the up whatever the road's grade (:mod:`~vcr_odom.loops.walls`);
where fewer than :data:`REFERENCE_NODES` nodes saw walls (a highway's verges, a field), the ground
does (:mod:`~vcr_odom.loops.ground`), loosely (:data:`ATTITUDE_SIGMA_DEG`: roads slope).

Either is given only where the odometry's tilt disagrees with it beyond what the measurement's own
error explains, since where the odometry's tilt is already better, priors add their error to the map.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from vcr_odom.geometry import invert
from vcr_odom.loops.edges import GraphEdge
from vcr_odom.loops.nodes import Node, NodeNormals, mostly_narrow
from vcr_odom.loops.walls import WallsUp, walls_up

ATTITUDE_SIGMA_DEG = 2.0
"""How far a node's ground may be from the true up: road slopes plus the fit's noise (the measured
up is within 0.6-2.3 deg of true up at p99 on the tuning drives and the KITTI sample). Chosen on
synthetic seeds 532-539 from 0.5-5 deg: 1 deg suited a 19 deg tilt drift best, 3 deg a 2 deg one.
The walls' weight is their own (:attr:`~vcr_odom.loops.walls.WallsUp.information`); 0 turns both off."""
UP_REFERENCE_M = 30.0
"""The world's up is measured on the nodes within this path of the first that measured it (the
ground's: of the start), where the odometry's tilt has not drifted yet."""
REFERENCE_NODES = 5
"""Walls seen by fewer nodes than this give no priors (the ground's are used); the walls' reference
pools at least this many nodes."""
TILT_AGREEMENT_DEG = 6.0
"""The ground's priors are given only where the odometry's up disagrees with the ground by more than
this at 10 % of the nodes: beyond what a road's grade explains. The ground is only as level as the road,
and where the odometry's tilt is better than that the priors add the slopes' error: on synthetic
drives whose roads slope 2-6 deg (a highway, an old town) they doubled to quadrupled the map's ATE
with the odometry 2-4 deg off the ground; on a 16-beam drive whose tilt drifted 19 deg they cut it from
0.42 to 0.09 of the odometry's (tuning seeds 532-539)."""
SMOOTHING_NODES = 9
"""The walls' disagreement with the odometry is a moving median over this many wall nodes: a drift
is smooth along the path, a node's walls err node by node (a narrow field of view's by 2-3 deg)."""
WALLS_AGREEMENT_DEG = 2.5
"""The walls' priors are given only where that smoothed disagreement exceeds this at 10 % of the
wall nodes. On synthetic drives whose odometry tilt stayed within 1.2 deg (p90) it measured 0.4-2.2
deg (Avia car crossings 562, 831, 841, 842: 1.9-2.2), where the priors raised the map's ATE (841:
0.074 -> 0.309 m without this rule); on those whose tilt drifted 3-9 deg, 3.2-8.9 deg, where they
cut it by 0.3-0.8 (802: 0.529 -> 0.110 m)."""
WALLS_AGREEMENT_NARROW_DEG = 4.0
"""The same for a narrow field of view (:func:`~vcr_odom.loops.nodes.mostly_narrow`): it sees a street's
walls from one end, at a slant, and their up errs alike over many nodes in a row, where smoothing does
not help. On Avia drives whose odometry's tilt was right to 0.14-0.56 deg (p90) the walls
disagreed by 0.46-2.58 deg (807, 2306, 2309, 2319), and by 3.29 where only five nodes saw walls (2320,
a highway); at 2.58 (2306, an avenue loop) the priors raised the map's ATE from 0.056 to 0.423 m, its
height swinging +-0.5 m. On the Avia courtyard walks, where the odometry's tilt does drift (0.6-18 deg
at p90), the priors moved no map by more than 0.02 m between 2.5 and 4 deg (16 of 105 walks)."""
MEASURED_SHARE = 0.1
"""A tilt axis counts as measured by a node's walls where its information is at least this share of
the strongest axis' (walls facing one way measure one axis)."""


@dataclass(frozen=True)
class AttitudePrior(GraphEdge):
    """Node ``source``'s roll and pitch held to the world's up: an edge to node 0 (the fixed first
    node) whose transform is the node's pose turned so that its measured up points up, with
    information only about the axes across it."""

    dof: int = 2


@dataclass(frozen=True)
class UpPriors:
    """The up directions the graph was given: ``edges`` (empty when left out), and why: the odometry's
    disagreement with the measured up (90th percentile over the ``nodes_measured``, measured by
    ``measured_by``: "walls" or "ground")."""

    edges: list[AttitudePrior]
    tilt_p90_deg: float | None
    nodes_measured: int
    measured_by: str | None = None

    def to_dict(self) -> dict[str, object]:
        return {
            "priors": len(self.edges),
            "measured_by": self.measured_by,
            "nodes_measured": self.nodes_measured,
            "odometry_tilt_p90_deg": None if self.tilt_p90_deg is None else round(self.tilt_p90_deg, 3),
            "used": bool(self.edges),
        }


def up_priors(
    nodes: Sequence[Node], sigma_deg: float = ATTITUDE_SIGMA_DEG, normals: NodeNormals | None = None
) -> UpPriors:
    """The walls' priors where at least :data:`REFERENCE_NODES` nodes saw walls, otherwise the
    ground's; none where ``sigma_deg`` is 0. ``normals``: the nodes' normals where the loop phase
    already holds them."""
    if sigma_deg <= 0:
        return UpPriors([], None, 0)
    normals = NodeNormals(nodes) if normals is None else normals
    walls = [
        (k, found)
        for k, node in enumerate(nodes)
        if (found := walls_up(node.cloud, node.cloud_voxel, normals.normals(k)))
    ]
    if len(walls) >= REFERENCE_NODES:
        return _walls_priors(nodes, walls)
    return _ground_priors(nodes, sigma_deg)


def _walls_priors(nodes: Sequence[Node], walls: list[tuple[int, WallsUp]]) -> UpPriors:
    """One prior per wall node after the first, where the smoothed disagreement exceeds
    :data:`WALLS_AGREEMENT_DEG` (:data:`WALLS_AGREEMENT_NARROW_DEG` for a narrow field of view)."""
    up = _walls_reference(nodes, walls)
    asked = []
    for k, found in walls:
        rotation = nodes[k].pose[:3, :3]
        turn = rotation.T @ _rotation_vector(rotation @ found.up, up)  # in the node's frame
        asked.append(rotation @ _measured_axes(found.information) @ turn)
    smoothed = [
        np.median(asked[max(0, i - SMOOTHING_NODES // 2) : i + SMOOTHING_NODES // 2 + 1], axis=0)
        for i in range(len(asked))
    ]
    tilt_p90 = math.degrees(float(np.percentile(np.linalg.norm(smoothed, axis=1), 90)))
    if tilt_p90 <= (WALLS_AGREEMENT_NARROW_DEG if mostly_narrow(nodes) else WALLS_AGREEMENT_DEG):
        return UpPriors([], tilt_p90, len(walls), "walls")
    measured = [(k, found.up, found.information) for k, found in walls]
    return UpPriors(_priors(nodes, measured, up), tilt_p90, len(walls), "walls")


def _ground_priors(nodes: Sequence[Node], sigma_deg: float) -> UpPriors:
    """One prior per node after the first whose ground was seen, where the odometry's tilt disagrees
    with the ground beyond :data:`TILT_AGREEMENT_DEG`; none when the start saw no ground."""
    seen = [(k, node.ground) for k, node in enumerate(nodes) if node.ground is not None]
    world = [nodes[k].pose[:3, :3] @ ground for k, ground in seen]
    reference = [w for (k, _), w in zip(seen, world, strict=True) if nodes[k].path_m <= UP_REFERENCE_M]
    if not reference:
        return UpPriors([], None, len(seen), "ground")
    up = np.mean(reference, axis=0)
    up /= np.linalg.norm(up)
    tilt_p90 = float(np.percentile([math.degrees(math.acos(min(1.0, float(w @ up)))) for w in world], 90))
    if tilt_p90 <= TILT_AGREEMENT_DEG:
        return UpPriors([], tilt_p90, len(seen), "ground")
    weight = math.radians(sigma_deg) ** -2
    measured = [(k, ground, weight * (np.eye(3) - np.outer(ground, ground))) for k, ground in seen]
    return UpPriors(_priors(nodes, measured, up), tilt_p90, len(seen), "ground")


def _priors(
    nodes: Sequence[Node],
    measured: list[tuple[int, NDArray[np.float64], NDArray[np.float64]]],
    up: NDArray[np.float64],
) -> list[AttitudePrior]:
    """Per measured node after the first (node, up in its frame, information on its rotation): its
    pose turned so that the measured up is the world's ``up``."""
    first_inverse = invert(nodes[0].pose)
    priors = []
    for k, node_up, information in measured:
        if k == 0:
            continue
        wanted = nodes[k].pose.copy()
        wanted[:3, :3] = _turn_onto(nodes[k].pose[:3, :3] @ node_up, up) @ nodes[k].pose[:3, :3]
        edge_information = np.zeros((6, 6))
        edge_information[:3, :3] = information
        priors.append(AttitudePrior(k, 0, first_inverse @ wanted, edge_information))
    return priors


def _walls_reference(nodes: Sequence[Node], walls: list[tuple[int, WallsUp]]) -> NDArray[np.float64]:
    """The world's up: the direction most perpendicular to the walls of the first wall nodes (at least
    :data:`REFERENCE_NODES`, and all within :data:`UP_REFERENCE_M` of path of the first), pooled in
    the odometry's frame: nodes that each see walls facing one way measure it together."""
    first = nodes[walls[0][0]].path_m
    early = [
        (nodes[k].pose[:3, :3], found)
        for i, (k, found) in enumerate(walls)
        if i < REFERENCE_NODES or nodes[k].path_m <= first + UP_REFERENCE_M
    ]
    pooled = sum(rotation @ found.scatter @ rotation.T for rotation, found in early)
    _, vectors = np.linalg.eigh(pooled)
    up = vectors[:, 0]
    return up if up @ np.mean([rotation @ found.up for rotation, found in early], axis=0) >= 0 else -up


def _measured_axes(information: NDArray[np.float64]) -> NDArray[np.float64]:
    """The projector onto the rotation axes the information measures (:data:`MEASURED_SHARE`)."""
    values, vectors = np.linalg.eigh(information)
    kept = vectors[:, values >= MEASURED_SHARE * values[-1]]
    return kept @ kept.T


def _rotation_vector(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """The smallest rotation taking direction ``a`` onto ``b``, as axis times angle."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    axis = np.cross(a, b)
    sine = float(np.linalg.norm(axis))
    if sine < 1e-12:
        return np.zeros(3)
    return axis / sine * math.atan2(sine, float(a @ b))


def _turn_onto(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """The smallest rotation taking direction ``a`` onto ``b``."""
    return Rotation.from_rotvec(_rotation_vector(a, b)).as_matrix()
