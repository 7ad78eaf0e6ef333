"""The walls' up: the direction a node's walls stand along, measured where the ground tells the road's
grade instead of the world's up.

Why: the ground's normal is the road's, and roads slope 2-6 deg over hills hundreds of metres long,
the scale at which a scan matcher's tilt drifts, so ground priors trade the drift for the grade
(docs/benchmarks.md, "Maps that close their loops"). Walls, fences and the faces of poles stand along
gravity wherever the road goes. In a node's 1 m voxel cloud they are the normals within a few degrees
of horizontal, and a wall is a plane: its normals gather within a degree or two of one direction, where
trees, cars and embankments spread theirs evenly over the same band. Only a node whose near-horizontal
normals gather so (:data:`WALL_SHARE`) measures up; a highway's verge and trees, which do not, were
2 deg off on average, and a street's walls 0.2-0.5 deg (median, synthetic drives 801-826).

A wall fixes a tilt about its own horizontal axis only: walls facing one way leave the tilt about
their normal free, and the information says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vcr_odom.loops.nodes import normal_cloud

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


def walls_up(
    cloud: NDArray[np.float32], voxel: float, normals: NDArray[np.float64] | None = None
) -> WallsUp | None:
    """The up of the walls in a node's cloud, or None where too few normals are walls'. ``normals``:
    the cloud's, where already estimated (:class:`~vcr_odom.loops.nodes.NodeNormals`)."""
    if len(cloud) < MIN_NORMALS:
        return None
    if normals is None:
        normals = np.asarray(normal_cloud(cloud, voxel).normals)
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
    """``near`` counted as :data:`NEAR_WEIGHT` normals perpendicular to the up sought: it holds the
    tilt that walls facing one way leave free, and is nothing against walls facing two ways."""
    return NEAR_WEIGHT * (np.eye(3) - np.outer(near, near))
