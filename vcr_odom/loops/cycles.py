"""What pairs of loops say about the odometry and about each other.

Two loops between the same two passages close a cycle through two short stretches of odometry (one
between their sources, one between their targets): its misclosure is those stretches' error plus the
two loops'. Over every such pair, the median misclosure, in the pose graph's own odometry sigmas, says
whether the odometry is noisier than the drift model assumes (handheld 16-beam walks at 10 Hz: 5-6.5
times), and the graph's robust rounds scale its sigmas by it; a loop whose cycles with the loops near
it mostly misclose is wrong, whatever the graph could bend the odometry into.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from vcr_odom.geometry import Transform, invert
from vcr_odom.loops.nodes import Node

if TYPE_CHECKING:
    from vcr_odom.loops.graph import LoopEdge

CYCLE_SPAN_M = 60.0
"""Two loops close a cycle where their sources, and their targets, are within this path of each other:
short stretches, whose odometry error is the random part the graph's sigmas model (a long stretch's is
mostly systematic drift, which the loops are there to correct)."""
MIN_CYCLES = 5
"""Fewer cycles than this leave the odometry's sigmas as the drift model has them: a median of a
handful can be one false loop's."""
MISCLOSURE_SIGMAS = 3.0
"""A cycle misclosed beyond this many (scaled) sigmas says one of its two loops is wrong."""
OUTLIER_SCALE_FLOOR = 0.5
"""Where the cycles' median misclosure is below 1 (odometry better than the drift model, a car's,
assumes), a cycle is judged against that median, down to this share of the model's sigmas
(:meth:`OdometryScale.outlier_scale`). On an Avia figure eight whose odometry is six times better than
the model (807 with the polish's point-to-plane finish: median 0.16) an own-cloud fit 1.14 m off closed
cycles misclosing at 1.0-2.0 of the model's sigmas where the right loops' closed at 0.0-0.4, and the
model's limit of 3 kept it."""


@dataclass(frozen=True)
class Cycle:
    """Loops ``first`` and ``second`` (indices into the graph's loops) and their cycle's misclosure in
    the odometry's and the loops' sigmas (the larger of the rotation's and the translation's)."""

    first: int
    second: int
    ratio: float


@dataclass(frozen=True)
class OdometryScale:
    """How far the odometry's error exceeds the drift model's step sigmas: ``scale`` (1 where it does
    not), from ``cycles`` pairs of loops near each other, whose median misclosure is ``median_ratio``."""

    scale: float
    cycles: int
    median_ratio: float | None

    @property
    def outlier_scale(self) -> float:
        """The sigmas' factor :func:`cycle_outliers` judges the cycles by: :attr:`scale` where it is 1 or
        more or the cycles are too few to measure it, else the median misclosure, at least
        :data:`OUTLIER_SCALE_FLOOR`. Only the judging: the graph's own sigmas never shrink below the
        model's (a tighter odometry would let the loops' own scatter into the map)."""
        if self.median_ratio is None:
            return self.scale
        return max(self.median_ratio, OUTLIER_SCALE_FLOOR)

    def to_dict(self) -> dict[str, object]:
        ratio = None if self.median_ratio is None else round(self.median_ratio, 3)
        return {
            "scale": round(self.scale, 3),
            "cycles": self.cycles,
            "median_ratio": ratio,
            "outlier_scale": round(self.outlier_scale, 3),
        }


def loop_cycles(
    nodes: Sequence[Node],
    loops: Sequence[LoopEdge],
    step_sigmas: tuple[NDArray[np.float64], NDArray[np.float64]],
) -> list[Cycle]:
    """Every pair of loops whose sources, and whose targets, are within :data:`CYCLE_SPAN_M` of path;
    ``step_sigmas`` the odometry edges' (m, rad: :meth:`~vcr_odom.loops.drift.DriftModel.chain_sigmas`)."""
    path = np.array([node.path_m for node in nodes])
    variance_t = np.concatenate([[0.0], np.cumsum(step_sigmas[0] ** 2)])
    variance_r = np.concatenate([[0.0], np.cumsum(step_sigmas[1] ** 2)])
    loop_variances = [_loop_variances(loop) for loop in loops]
    order = sorted(range(len(loops)), key=lambda k: loops[k].source)
    cycles = []
    for rank, i in enumerate(order):
        first = loops[i]
        for j in order[rank + 1 :]:
            second = loops[j]
            if path[second.source] - path[first.source] > CYCLE_SPAN_M:
                break
            if not within_cycle_span(nodes, (first.source, first.target), (second.source, second.target)):
                continue
            expected_t = expected_r = 0.0
            for a, b in ((first.source, second.source), (first.target, second.target)):
                lo, hi = min(a, b), max(a, b)
                lever = float(np.linalg.norm(nodes[hi].pose[:3, 3] - nodes[lo].pose[:3, 3]))
                rotation = variance_r[hi] - variance_r[lo]
                expected_r += rotation
                expected_t += variance_t[hi] - variance_t[lo] + rotation * lever**2
            for loop in (i, j):
                expected_r += loop_variances[loop][0]
                expected_t += loop_variances[loop][1]
            misclosure = _misclosure(nodes, first, second)
            rotation_ratio = float(np.linalg.norm(misclosure[:3])) / math.sqrt(3 * expected_r)
            translation_ratio = float(np.linalg.norm(misclosure[3:])) / math.sqrt(3 * expected_t)
            cycles.append(Cycle(i, j, max(rotation_ratio, translation_ratio)))
    return cycles


def within_cycle_span(nodes: Sequence[Node], first: tuple[int, int], second: tuple[int, int]) -> bool:
    """Whether two loops, each (source, target) node indices, close a cycle: their sources, and their
    targets, within :data:`CYCLE_SPAN_M` of path of each other."""
    return all(
        abs(nodes[a].path_m - nodes[b].path_m) <= CYCLE_SPAN_M for a, b in zip(first, second, strict=True)
    )


def odometry_scale(cycles: Sequence[Cycle]) -> OdometryScale:
    """The odometry sigmas' factor: the cycles' median misclosure where it is above 1, never below 1
    (a tighter odometry would let the loops' own scatter into the map). The median, because a false
    loop's cycles are few among the right loops'."""
    if len(cycles) < MIN_CYCLES:
        return OdometryScale(1.0, len(cycles), None)
    median = float(np.median([cycle.ratio for cycle in cycles]))
    return OdometryScale(max(1.0, median), len(cycles), median)


def cycle_outliers(cycles: Sequence[Cycle], scale: float) -> dict[int, tuple[int, int]]:
    """Loops (index -> (misclosed, cycles)) more than half of whose cycles, at least three, misclose
    beyond :data:`MISCLOSURE_SIGMAS` of the scaled sigmas, or every one of whose cycles, at least two,
    misclose with loops that close a cycle with each other: two that agree outvote one. Why beside the
    graph's robust kernel: where the odometry's sigmas are scaled up, the graph can bend the odometry to
    fit a false loop and the loop's residual stays small; its cycles with the right loops near it still
    misclose. Why two against one: where the loops are too few to scale the sigmas, a corroborated loop
    keeps its full weight in the graph (:mod:`~vcr_odom.loops.graph`), and a fit that slid along a
    footpath both its starts slid along (walk 1111: 6.5 m off) is corroborated."""
    limit = MISCLOSURE_SIGMAS * scale
    partners: dict[int, dict[int, bool]] = {}
    for cycle in cycles:
        misclosed = cycle.ratio > limit
        partners.setdefault(cycle.first, {})[cycle.second] = misclosed
        partners.setdefault(cycle.second, {})[cycle.first] = misclosed
    outliers = {}
    for loop, verdicts in partners.items():
        bad, total = sum(verdicts.values()), len(verdicts)
        if (total >= 3 and 2 * bad > total) or (total >= 2 and bad == total and _agree(verdicts, partners)):
            outliers[loop] = (bad, total)
    return outliers


def _agree(verdicts: dict[int, bool], partners: dict[int, dict[int, bool]]) -> bool:
    """Whether two of a loop's partners (``verdicts``' keys) close a cycle with each other."""
    others = list(verdicts)
    return any(partners[p].get(q) is False for k, p in enumerate(others) for q in others[k + 1 :])


def _loop_variances(loop: LoopEdge) -> tuple[float, float]:
    """A loop's mean variance per axis, rotation (rad^2) and translation (m^2)."""
    covariance = np.linalg.inv(loop.information)
    return float(np.trace(covariance[:3, :3])) / 3, float(np.trace(covariance[3:, 3:])) / 3


def _misclosure(nodes: Sequence[Node], first: LoopEdge, second: LoopEdge) -> NDArray[np.float64]:
    """The twist (rotation vector, translation) by which the odometry from ``first``'s source to
    ``second``'s and the path through the two loops and the odometry between their targets disagree."""

    def between(a: int, b: int) -> Transform:
        return invert(nodes[a].pose) @ nodes[b].pose

    through_loops = invert(first.transform) @ between(first.target, second.target) @ second.transform
    error = invert(between(first.source, second.source)) @ through_loops
    return np.concatenate([Rotation.from_matrix(error[:3, :3]).as_rotvec(), error[:3, 3]])
