"""Gravity priors: each node's roll and pitch held to the up measured in its own cloud, where the
odometry's tilt drifted from it.

Why: loops cannot see a tilt that drifted between them, since a lobe driven in a tilted plane still
meets itself at its ends. Walls, fences and the faces of poles stand along gravity wherever the road
goes: in a node's voxel cloud they are the normals near horizontal that gather round one direction
(:func:`walls_up`; trees, cars and embankments spread theirs evenly), and each wall measures the tilt
about its own horizontal axis. Where too few nodes see walls (a highway's verges, a field), the ground
measures up (:func:`ground_normal`), loosely: roads slope. Either is given only where the odometry's
tilt differs from it by more than the measurement's own noise explains
(:attr:`~vcr_odom.loops.settings.LoopSettings.tilt_test_sigmas`): where the odometry's tilt is better,
priors would add their error to the map.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from vcr_odom.geometry import adjoint, invert
from vcr_odom.loops.candidates import LoopEdge
from vcr_odom.loops.nodes import Node, NodeNormals
from vcr_odom.loops.settings import LoopSettings

SEARCH_DEG = 25.0
"""Normals within this of the node's horizontal are the first guess at walls (a node tilts a few
degrees from the world's up; a walk's more)."""
BAND_DEG = 8.0
"""Then the normals within this of perpendicular to the walls' up, refined twice."""
WALL_DEG = 2.0
WALL_SHARE = 0.5
"""Walls, not clutter: at least this share of the band's normals within :data:`WALL_DEG` of it."""
FIT_DEG = 3.0
"""The up is fitted to the normals within this of perpendicular to it: the walls themselves."""
MIN_NORMALS = 40
NEAR_WEIGHT = 5.0
"""Walls facing one way leave the tilt about their normal free; the last estimate (first the node's
own z) holds it, weighing as much as this many normals (against hundreds where walls face two ways)."""
CORRELATED_NORMALS = 10.0
"""Neighbouring normals share most of their points (20 neighbours within 2.5 voxels): this many
count as one measurement."""
FLOOR_DEG = 0.5
"""Walls lean, and a coarse grid biases normals: no node's up is trusted better than this."""


@dataclass(frozen=True)
class WallsUp:
    """``up``: the walls' up in the node's frame; ``information`` (3x3, rad^-2): on the node's
    rotation, about the walls' horizontal axes only; ``scatter``: the sum of the walls' normals'
    outer products with ``up`` held as :func:`_least_tilted` holds it (3x3, the node's frame), which
    nodes pool where each sees walls facing one way."""

    up: NDArray[np.float64]
    information: NDArray[np.float64]
    scatter: NDArray[np.float64]


def walls_up(cloud: NDArray[np.float32], normals: NDArray[np.float64]) -> WallsUp | None:
    """The up of the walls in a node's cloud (``normals`` its normals), or None where too few normals
    are walls'."""
    if len(cloud) < MIN_NORMALS:
        return None
    up = np.array([0.0, 0.0, 1.0])
    for band in (SEARCH_DEG, BAND_DEG, BAND_DEG):
        up = _least_tilted(_within(normals, up, band), up)
        if up is None:
            return None
    band = _within(normals, up, BAND_DEG)
    walls = _within(normals, up, FIT_DEG)
    if len(band) < MIN_NORMALS or len(_within(band, up, WALL_DEG)) < WALL_SHARE * len(band):
        return None
    up = _least_tilted(walls, up)
    if up is None:
        return None
    axes = np.cross(up, walls)  # a wall tilts about its horizontal axis
    spread = axes.T @ axes / len(walls)  # trace 1: all of it across one axis for walls facing one way
    residual = float(np.mean((walls @ up) ** 2))
    variance = residual * CORRELATED_NORMALS / len(walls) + math.radians(FLOOR_DEG) ** 2
    # x2: walls facing two ways put half the spread on each axis, 1 / variance each
    return WallsUp(up, 2.0 * spread / variance, walls.T @ walls + _pull(up))


def _within(normals: NDArray[np.float64], up: NDArray[np.float64], degrees: float) -> NDArray[np.float64]:
    """The normals within ``degrees`` of perpendicular to ``up``."""
    return normals[np.abs(normals @ up) < math.sin(math.radians(degrees))]


def _least_tilted(walls: NDArray[np.float64], near: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """The direction most perpendicular to ``walls``, with ``near`` counted as :data:`NEAR_WEIGHT`
    normals' worth; None for too few walls or an up beyond :data:`SEARCH_DEG` of the node's z (a
    single wall and the ground leave a horizontal direction perpendicular to both)."""
    if len(walls) < MIN_NORMALS:
        return None
    _, vectors = np.linalg.eigh(walls.T @ walls + _pull(near))
    up = vectors[:, 0] if vectors[:, 0] @ near >= 0 else -vectors[:, 0]
    return up if up[2] >= math.cos(math.radians(SEARCH_DEG)) else None


def _pull(near: NDArray[np.float64]) -> NDArray[np.float64]:
    """``near`` counted as :data:`NEAR_WEIGHT` normals perpendicular to the up sought."""
    return NEAR_WEIGHT * (np.eye(3) - np.outer(near, near))


UP_REFERENCE_M = 30.0
"""The world's up is measured on the nodes within this path of the first that measured it (the
ground's: of the start), where the odometry's tilt has not drifted yet."""
REFERENCE_NODES = 5
"""Walls seen by fewer nodes than this give no priors (the ground's are used); the walls' reference
pools at least this many nodes."""
SMOOTHING_NODES = 9
"""The walls' disagreement with the odometry is a moving median over this many wall nodes: a drift
is smooth along the path, a node's walls err node by node."""
MEASURED_SHARE = 0.1
"""A tilt axis counts as measured by a node's walls where its information is at least this share of
the strongest axis' (walls facing one way measure one axis)."""


@dataclass(frozen=True)
class UpPriors:
    """The up directions the graph was given: ``edges`` (empty when left out), and why: the odometry's
    disagreement with the measured up (90th percentile over the ``nodes_measured``, measured by
    ``measured_by``: "walls" or "ground")."""

    edges: list[LoopEdge]
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


def up_priors(nodes: Sequence[Node], normals: NodeNormals, settings: LoopSettings) -> UpPriors:
    """The walls' priors, else the ground's (:data:`REFERENCE_NODES`); none where ``ground_up`` is off."""
    if not settings.ground_up:
        return UpPriors([], None, 0)
    walls = [(k, found) for k in range(len(nodes)) if (found := walls_up(nodes[k].cloud, normals.normals(k)))]
    if len(walls) >= REFERENCE_NODES:
        return _walls_priors(nodes, walls, settings.tilt_test_sigmas * settings.walls_sigma_deg)
    return _ground_priors(nodes, settings.ground_sigma_deg, settings.tilt_test_sigmas)


def _walls_priors(nodes: Sequence[Node], walls: list[tuple[int, WallsUp]], threshold_deg: float) -> UpPriors:
    """One prior per wall node after the first, where the smoothed disagreement exceeds
    ``threshold_deg`` at 10 % of the wall nodes."""
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
    if tilt_p90 <= threshold_deg:
        return UpPriors([], tilt_p90, len(walls), "walls")
    measured = [(k, found.up, found.information) for k, found in walls]
    return UpPriors(_priors(nodes, measured, up), tilt_p90, len(walls), "walls")


def _ground_priors(nodes: Sequence[Node], sigma_deg: float, test_sigmas: float) -> UpPriors:
    """One prior per node after the first whose ground was seen, where the odometry's tilt disagrees
    with the ground beyond ``test_sigmas`` of its ``sigma_deg`` at 10 % of the nodes; none when the
    start saw no ground."""
    seen = [(k, node.ground) for k, node in enumerate(nodes) if node.ground is not None]
    world = [nodes[k].pose[:3, :3] @ ground for k, ground in seen]
    reference = [w for (k, _), w in zip(seen, world, strict=True) if nodes[k].path_m <= UP_REFERENCE_M]
    if not reference:
        return UpPriors([], None, len(seen), "ground")
    up = np.mean(reference, axis=0)
    up /= np.linalg.norm(up)
    tilt_p90 = float(np.percentile([math.degrees(math.acos(min(1.0, float(w @ up)))) for w in world], 90))
    if tilt_p90 <= test_sigmas * sigma_deg:
        return UpPriors([], tilt_p90, len(seen), "ground")
    weight = math.radians(sigma_deg) ** -2
    measured = [(k, ground, weight * (np.eye(3) - np.outer(ground, ground))) for k, ground in seen]
    return UpPriors(_priors(nodes, measured, up), tilt_p90, len(seen), "ground")


def _priors(
    nodes: Sequence[Node],
    measured: list[tuple[int, NDArray[np.float64], NDArray[np.float64]]],
    up: NDArray[np.float64],
) -> list[LoopEdge]:
    """Per measured node after the first (node, up in its frame, information on its rotation): an edge
    to node 0 (the fixed first node), the node's pose turned so that the measured up is the world's
    ``up``, informed only about the rotation axes across it (its roll and pitch)."""
    first_inverse = invert(nodes[0].pose)
    priors = []
    for k, node_up, information in measured:
        if k == 0:
            continue
        rotation = nodes[k].pose[:3, :3]
        wanted = nodes[k].pose.copy()
        wanted[:3, :3] = Rotation.from_rotvec(_rotation_vector(rotation @ node_up, up)).as_matrix() @ rotation
        transform = first_inverse @ wanted
        in_node = np.zeros((6, 6))
        in_node[:3, :3] = information
        to_node = adjoint(invert(transform))  # a LoopEdge's information is in its target's frame
        priors.append(LoopEdge(k, 0, transform, to_node.T @ in_node @ to_node))
    return priors


def _walls_reference(nodes: Sequence[Node], walls: list[tuple[int, WallsUp]]) -> NDArray[np.float64]:
    """The world's up: the direction most perpendicular to the early wall nodes' walls, pooled in the
    odometry's frame: nodes that each see walls facing one way measure it together."""
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
