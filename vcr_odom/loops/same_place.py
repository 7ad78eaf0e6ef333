"""Submap fits of one place that disagree: a repeating street, measured more than once.

Why: where a narrow field of view crosses its own path, each candidate registers the two visits'
submaps, and there the network's start lands on the crossing's other arm, so the odometry's start
alone gives the fit; the source's own scan often overlaps too little to check it. Along an avenue
whose rows of trees repeat, such a fit can slide a spacing or two with as good an overlap: on unseen
Avia drive 2316 a fit 6.06 m along the avenue (overlap 0.85) passed every check and the graph kept it
(weight 0.97; the map 0.41 -> 2.95 m), while the two candidates beside it, registered from their own
starts, put the source 6.0 and 6.5 m elsewhere (and right, 0.12 and 0.42 m off the truth; the own-scan
check turned them away). Fits of one place that put the source metres apart cannot all be right, and
nothing tells which is: the accepted one is rejected as ambiguous. The neighbours that count are the
fits turned away after they passed overlap, RMSE and the drift bound: the pose graph never sees them.
Two accepted fits that disagree are the graph's to weigh, with their cycles (on unseen Avia drive
2322 it kept the right one of such a pair, 0.91 m off the truth, and dropped the one 6.4 m off;
rejecting both here left that crossing open).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from vcr_odom.loops.decision import LoopDecision
from vcr_odom.loops.nodes import Node

SAME_PLACE_PATH_M = 15.0
"""Two candidates measure one place where their sources, and their targets, lie within this much path
of each other: the odometry between them is then good to centimetres on a car, decimetres on a walk."""
DISAGREE_M = 2.0
"""Two fits of one place disagree where they put the source this far apart. Neighbouring submap fits
that were right put it 0.07-0.59 m apart on the Avia car crossings (807, 2309, 2320) and 1.31 m on a
courtyard walk (1608); 2316's false fit 5.98 and 6.46 m from its two neighbours."""
_UNMEASURED = ("points", "doubted_submap", "overlap", "fit_rmse", "drift_bound")
"""Checks that leave no fit of the place to compare with: failed at or before the drift bound, or a
submap the verification found bent (``doubted_submap``), whose fit says nothing of the place."""


def reject_disagreeing_submap_fits(decisions: Sequence[LoopDecision], nodes: Sequence[Node]) -> None:
    """Turns away every accepted submap loop that a submap fit of the same place, measured and turned
    away, contradicts (:data:`DISAGREE_M`); the others are left as they are."""
    measured = [
        d
        for d in decisions
        if d.scores.get("submaps") and d.measured is not None and d.check not in _UNMEASURED
    ]
    displacement = {id(d): _source_displacement(d, nodes) for d in measured}
    rejected: list[tuple[LoopDecision, LoopDecision, float]] = []
    for loop in (d for d in measured if d.accepted):
        worst: tuple[float, LoopDecision] | None = None
        for other in measured:
            if other.accepted or not _same_place(loop, other, nodes):
                continue
            apart = float(np.linalg.norm(displacement[id(loop)] - displacement[id(other)]))
            if apart > DISAGREE_M and (worst is None or apart > worst[0]):
                worst = (apart, other)
        if worst is not None:
            rejected.append((loop, worst[1], worst[0]))
    for loop, other, apart in rejected:
        loop.reject(
            "ambiguous",
            f"rejected: ambiguous: the submap fit of the same place from frames {other.source_frame} -> "
            f"{other.target_frame} puts the source {apart:.1f} m from where this one does",
        )


def _source_displacement(decision: LoopDecision, nodes: Sequence[Node]) -> NDArray[np.float64]:
    """Where the fit puts the source node (from its target's odometry pose), less where the odometry
    has it: the correction the loop asks, in the odometry's world."""
    candidate = decision.candidate
    placed = nodes[candidate.target].pose @ np.asarray(decision.measured, dtype=np.float64)
    return placed[:3, 3] - nodes[candidate.source].pose[:3, 3]


def _same_place(first: LoopDecision, second: LoopDecision, nodes: Sequence[Node]) -> bool:
    a, b = first.candidate, second.candidate
    return (
        abs(nodes[a.source].path_m - nodes[b.source].path_m) <= SAME_PLACE_PATH_M
        and abs(nodes[a.target].path_m - nodes[b.target].path_m) <= SAME_PLACE_PATH_M
    )
