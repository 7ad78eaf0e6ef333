"""The odometry's uncertainty along the path, and the loop candidates it allows.

The odometry edges' covariances (:func:`~vcr_odom.loops.verify.odometry_information`), propagated
along the path to first order, give the uncertainty of any node relative to any other (:class:`Chain`):
it gates the candidates (:func:`find_candidates`), then judges what a loop asks of the odometry and
whether two loops agree with each other.

The world-frame formulation: an error ``xi`` on edge ``k`` (a left perturbation in node ``k``'s frame,
as a fit's information is) moves every later node by ``Ad(P_k) xi`` in the world frame, so the
covariance between any two nodes is a difference of prefix sums (one lookup per query).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from itertools import groupby

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from vcr_odom.geometry import Transform, adjoint, invert, skew, twist
from vcr_odom.loops.nodes import Node
from vcr_odom.loops.settings import LoopSettings


def covariance(information: NDArray[np.float64]) -> NDArray[np.float64]:
    """The inverse of an information matrix, regularised where a fit left a direction unmeasured."""
    values, vectors = np.linalg.eigh(0.5 * (information + information.T))
    values = np.maximum(values, 1e-9)
    return (vectors / values) @ vectors.T


class Chain:
    """The odometry's node poses and each edge's covariance, propagated: the uncertainty between nodes."""

    def __init__(self, poses: NDArray[np.float64], edge_information: list[NDArray[np.float64]]) -> None:
        self.poses = np.asarray(poses, dtype=np.float64)
        steps = [self.edge_covariance(k, info) for k, info in enumerate(edge_information)]
        self._prefix = np.concatenate([np.zeros((1, 6, 6)), np.cumsum(np.array(steps).reshape(-1, 6, 6), 0)])

    def world_covariance(self, first: int, second: int) -> NDArray[np.float64]:
        """The world-frame covariance the edges from node ``min`` to node ``max`` add to a later node."""
        low, high = sorted((first, second))
        return self._prefix[high] - self._prefix[low]

    def between(self, first: tuple[int, int], second: tuple[int, int]) -> NDArray[np.float64]:
        """The world-frame covariance of the edges in one node interval and not the other (two loops'
        corrections share the drift of the edges both span, which cancels)."""
        ends = sorted((*first, *second))  # the symmetric difference, whether apart, overlapping or nested
        return self.world_covariance(ends[0], ends[1]) + self.world_covariance(ends[2], ends[3])

    def correction(self, loop: LoopEdge) -> NDArray[np.float64]:
        """What a loop asks of the odometry, as a world-frame twist."""
        return twist(self.poses[loop.target] @ loop.transform @ invert(self.poses[loop.source]))

    def edge_covariance(self, target: int, information: NDArray[np.float64]) -> NDArray[np.float64]:
        """A loop's or an odometry edge's covariance in the world frame (its information: its target's)."""
        lever = adjoint(self.poses[target])
        return lever @ covariance(information) @ lever.T

    def loop_covariance(self, loop: LoopEdge, scale: float = 1.0) -> NDArray[np.float64]:
        """A loop's own world-frame covariance: its fit's, plus its submaps' placement (``scale`` times)."""
        own = self.edge_covariance(loop.target, loop.information)
        return own if loop.placement is None else own + scale * loop.placement

    def submap_placement(self, node: int, members: tuple[int, ...]) -> NDArray[np.float64]:
        """The odometry's covariance of a submap's members about its node, averaged over them."""
        return np.mean([self.world_covariance(node, k) for k in members], axis=0)

    def weighted(self, loop: LoopEdge, scale: float) -> LoopEdge:
        """The loop with its whole covariance as its information, in its target's frame (the graph's)."""
        if loop.placement is None:
            return loop
        lever = adjoint(invert(self.poses[loop.target]))
        information = np.linalg.inv(lever @ self.loop_covariance(loop, scale) @ lever.T)
        return dataclasses.replace(loop, information=0.5 * (information + information.T), placement=None)

    def loop_chi2(self, loop: LoopEdge, scale: float = 1.0) -> float:
        """The squared Mahalanobis distance of what a loop asks of the odometry, under the odometry's
        covariance between its ends times ``scale`` and the loop's own."""
        spread = scale * self.world_covariance(loop.target, loop.source) + self.loop_covariance(loop, scale)
        return mahalanobis2(self.correction(loop), spread)


def chi2_gate(confidence: float, dof: int) -> float:
    """The value a squared Mahalanobis distance on ``dof`` dimensions stays under at ``confidence``."""
    return float(chi2.ppf(confidence, dof))


def mahalanobis2(residual: NDArray[np.float64], cov: NDArray[np.float64]) -> float:
    """``r^T cov^-1 r``."""
    return float(residual @ np.linalg.solve(cov, residual))


@dataclass(frozen=True)
class LoopCandidate:
    """Node ``source`` (the later visit) against node ``target`` (the earlier one); ``prior`` is the
    odometry's ``T_target_source``, ``path_m`` the distance driven between them, ``distance_m`` the
    odometry's, ``sigma_m`` its largest position sigma there, ``passage`` the revisit passage tried."""

    source: int
    target: int
    prior: Transform
    path_m: float
    distance_m: float
    sigma_m: float = 0.0
    frames: int = 0
    passage: int = 0


@dataclass(frozen=True)
class LoopEdge:
    """A loop, or a gravity prior (:func:`~vcr_odom.loops.gravity.up_priors`): ``transform`` is
    ``T_target_source``, ``information`` on a left perturbation in the target's frame (open3d's order:
    rotation, translation), as a fit measures it; :func:`~vcr_odom.loops.graph.optimise` moves it to
    the source's frame, where open3d reads it."""

    source: int
    target: int
    transform: Transform
    information: NDArray[np.float64]
    placement: NDArray[np.float64] | None = None
    """A submap loop's: the world-frame covariance of its submaps' placement by the odometry (a submap
    is only as rigid as the odometry that placed it), which scales with the odometry's."""


def find_candidates(nodes: list[Node], chain: Chain, settings: LoopSettings) -> list[LoopCandidate]:
    """Per later node, the earlier node (at least ``min_loop_path_m`` before) most likely to be the
    same place, where the chi-square gate allows a revisit; then at most one attempt every
    ``attempt_spacing_m`` of a revisit passage (and about ``passage_attempts`` a passage), the nodes
    closest to the earlier visit first: a few loops pin a passage, and each costs a registration."""
    if len(nodes) < 2:
        return []
    positions = np.stack([node.pose[:3, 3] for node in nodes])
    path = np.array([node.path_m for node in nodes])
    gate = chi2_gate(settings.candidate_confidence, 3)
    nearest: dict[int, LoopCandidate] = {}
    for j in range(len(nodes)):
        earlier = np.flatnonzero(path <= path[j] - settings.min_loop_path_m)
        closest = earlier[np.argsort(np.linalg.norm(positions[earlier] - positions[j], axis=1))[:8]]
        scores = [(*revisit_chi2(chain, int(i), j, settings.revisit_radius_m), int(i)) for i in closest]
        allowed = [score for score in scores if score[0] <= gate]
        if allowed:
            _, sigma, i = min(allowed, key=lambda score: score[0])
            prior = invert(nodes[i].pose) @ nodes[j].pose
            distance = float(np.linalg.norm(positions[j] - positions[i]))
            frames = nodes[j].position - nodes[i].position
            nearest[j] = LoopCandidate(j, i, prior, float(path[j] - path[i]), distance, sigma, frames)
    chosen: list[LoopCandidate] = []
    runs = groupby(enumerate(sorted(nearest)), key=lambda pair: pair[1] - pair[0])  # consecutive nodes
    for number, passage in enumerate([j for _, j in run] for _, run in runs):  # a revisit passage each
        picked: list[float] = []
        length = float(path[passage[-1]] - path[passage[0]])
        spacing = max(settings.attempt_spacing_m, length / settings.passage_attempts)
        for j in sorted(passage, key=lambda k: nearest[k].distance_m):
            if all(abs(path[j] - other) >= spacing for other in picked):
                picked.append(float(path[j]))
                chosen.append(dataclasses.replace(nearest[j], passage=number))
    return sorted(chosen, key=lambda candidate: candidate.source)


def revisit_chi2(chain: Chain, earlier: int, later: int, radius_m: float) -> tuple[float, float]:
    """How unlikely it is that node ``later`` truly lies within ``radius_m`` of node ``earlier``: the
    squared Mahalanobis distance, under the odometry's position uncertainty between them, of the part
    of their offset beyond the radius; and that uncertainty's largest standard deviation (m)."""
    point = chain.poses[later][:3, 3]
    jacobian = np.hstack([-skew(point), np.eye(3)])  # d(exp(xi) p)/d xi: a rotation moves a far point more
    spread = jacobian @ chain.world_covariance(earlier, later) @ jacobian.T
    offset = point - chain.poses[earlier][:3, 3]
    distance = float(np.linalg.norm(offset))
    beyond = offset * max(0.0, 1.0 - radius_m / distance) if distance > 0 else offset
    score = mahalanobis2(beyond, spread + POSITION_FLOOR_M**2 * np.eye(3))
    return score, math.sqrt(max(float(np.linalg.eigvalsh(spread)[-1]), 0.0))


POSITION_FLOOR_M = 0.01
"""A floor on the position uncertainty (numerical: the first nodes' covariance is near zero)."""
