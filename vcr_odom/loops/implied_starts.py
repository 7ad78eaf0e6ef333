"""A third start for a loop: where another loop near it, and the odometry between the two, put its
source.

Why: the verification polishes each candidate from two starts (the network's and the odometry's), and
a place whose surfaces hardly face one way can take both into one wrong fit. On a courtyard walk
(Avia, 2212) a fit 3.0 m off (480 -> 0, overlap 0.68) passed every check beside a right loop a few
metres on (519 -> 66); their one cycle misclosed by 2.4 m, and one cycle cannot say which loop is
wrong. Polished from where the right loop puts it, the false loop's source ends on the truth at an
overlap of 0.56: the place has two fits that overlap cannot tell apart, the verification's own
definition of ambiguous (:data:`~vcr_odom.loops.verify.AMBIGUITY`). The right loop, polished from
where the false one puts it, ends 21 m away at 0.19: it is not ambiguous, and it stays.

A candidate turned away as ambiguous (two fits overlap could not tell apart) still puts a loop near it,
by its better fit. On an Avia loop down an avenue whose odometry drifted 1 deg per 100 m (synthetic
5604, `benchmarks/loop_drift.py`), the second pass lay one tree-spacing (~10 m) along from the first;
seven loops were kept 10-15 m off, three with both starts in the look-alike, while the candidates
between them had one start on the place and one on the look-alike, were turned away, and had the
place as their better fit. Polished from where those put them, the kept ones end on the place as well
as on the look-alike, and go too. The other fit of an ambiguous candidate is not used: indoors, where
corridors leave such candidates at every turn, it turned away right loops (synthetic OS0 walks 902
and 903 with their heading drifted 15-20 deg per 100 m).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vcr_odom.geometry import Transform, invert, motion_difference
from vcr_odom.loops.cycles import within_cycle_span
from vcr_odom.loops.decision import LoopDecision
from vcr_odom.loops.nodes import Node, NodeNormals
from vcr_odom.loops.verify import AMBIGUITY, distance_scale, one_fit, polish


def implied_start(loop: LoopDecision, other: LoopDecision, nodes: Sequence[Node]) -> Transform:
    """``loop``'s ``T_target_source`` as ``other``'s measurement and the odometry between the two loops'
    sources, and between their targets, put it."""
    a, b = loop.candidate, other.candidate
    assert other.measured is not None
    placed_source = (
        nodes[b.target].pose @ other.measured @ invert(nodes[b.source].pose) @ nodes[a.source].pose
    )
    return invert(nodes[a.target].pose) @ placed_source


def _implied_by(decisions: Sequence[LoopDecision]) -> list[LoopDecision]:
    """What may put a loop's source: each accepted loop, and each candidate turned away as ambiguous
    (by its better fit: the place repeats there, and that fit may be the right one)."""
    return [d for d in decisions if d.measured is not None and (d.accepted or d.check == "ambiguous")]


def reject_loops_ambiguous_from_implied_starts(
    decisions: Sequence[LoopDecision], nodes: Sequence[Node], normals: NodeNormals
) -> None:
    """Turns away every accepted loop on its nodes' own clouds that, polished from where another
    accepted loop, or a candidate turned away as ambiguous (by its better fit), within
    :data:`~vcr_odom.loops.cycles.CYCLE_SPAN_M` of path puts it (more than
    :data:`~vcr_odom.loops.verify.AMBIGUITY`'s distance or turn from its own fit), ends that far from
    its fit at an overlap within AMBIGUITY's margin of its own. Every verdict is taken against the loops
    accepted before any is turned away, so two loops that make each other ambiguous both go."""
    accepted = [d for d in decisions if d.accepted and d.measured is not None]
    implied = _implied_by(decisions)
    close_fitness = AMBIGUITY[2]
    rejected: list[tuple[LoopDecision, LoopDecision, str, float, float, float]] = []
    for loop in accepted:
        if loop.scores.get("submaps"):
            continue  # its clouds are submaps; a node's own cloud measures something else
        scale = distance_scale(nodes[loop.candidate.source])
        own_fitness = float(loop.scores["fitness"])
        clouds = None  # made once, where a start needs polishing
        for other in implied:
            if other is loop or not within_cycle_span(nodes, loop.ends, other.ends):
                continue
            start = implied_start(loop, other, nodes)
            if one_fit(motion_difference(start, loop.measured), scale):
                continue  # the two loops agree
            clouds = clouds or (normals.cloud(loop.candidate.source), normals.cloud(loop.candidate.target))
            fit = polish(*clouds, start, scale)
            apart = motion_difference(np.asarray(fit.transformation), loop.measured)
            if not one_fit(apart, scale) and fit.fitness > own_fitness - close_fitness:
                which = "loop" if other.accepted else "ambiguous candidate"  # before any is turned away
                rejected.append((loop, other, which, *apart, float(fit.fitness)))
                break
    for loop, other, which, apart_m, apart_deg, fitness in rejected:
        loop.reject(
            "ambiguous",
            f"rejected: ambiguous: polished from where the {which} of frames {other.source_frame} -> "
            f"{other.target_frame} and the odometry put the source, it ends {apart_m:.1f} m / "
            f"{apart_deg:.0f} deg from this fit at overlap {fitness:.2f} (this fit's "
            f"{loop.scores['fitness']:.2f})",
        )
