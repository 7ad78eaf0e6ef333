"""A weak loop that a corroborated loop near it contradicts.

Why: on a courtyard walk (Avia, 3306) two own-cloud fits 1.5 and 1.8 m off the truth passed every
check beside a right one; all three cycles misclosed, so no two loops outvoted the third, and the
drift model's sigmas let the graph bend the odometry to all three. The right one was corroborated
(its surfaces face every way); the false ones were not, and their surfaces hardly faced one way
(weakest share 0.0033 and 0.0146, under the polish's weak-axis share), so along that direction their
fit says little. Where the corroborated loop puts the source, with the odometry between the two, lay
2.8 and 1.6 m from their fits; for the right weak loops on the recorded walks it lay 0.07-0.83 m away.
Only where the loops close too few cycles to weigh each other (as for the graph's trust in a
corroborated loop, :data:`~vcr_odom.loops.cycles.MIN_CYCLES`): there the cycles judge every loop.
"""

from __future__ import annotations

from collections.abc import Sequence

from vcr_odom.geometry import motion_difference
from vcr_odom.loops.cycles import MIN_CYCLES, within_cycle_span
from vcr_odom.loops.decision import LoopDecision
from vcr_odom.loops.implied_starts import implied_start
from vcr_odom.loops.nodes import Node
from vcr_odom.loops.verify import distance_scale, one_fit
from vcr_odom.odometry.degeneracy import WEAK_AXIS_SHARE


def reject_weak_loops_corroborated_ones_contradict(
    decisions: Sequence[LoopDecision], nodes: Sequence[Node]
) -> None:
    """Turns away every accepted, uncorroborated own-cloud loop whose fit's weakest share is under
    :data:`~vcr_odom.odometry.degeneracy.WEAK_AXIS_SHARE` and lies more than
    :data:`~vcr_odom.loops.verify.AMBIGUITY`'s distance or turn from where a corroborated loop within a
    cycle's span puts it, where the accepted loops close fewer than :data:`MIN_CYCLES` cycles."""
    accepted = [d for d in decisions if d.accepted and d.measured is not None]
    pairs = sum(
        within_cycle_span(nodes, a.ends, b.ends) for k, a in enumerate(accepted) for b in accepted[k + 1 :]
    )
    if pairs >= MIN_CYCLES:
        return
    corroborated = [d for d in accepted if d.corroborated]
    rejected: list[tuple[LoopDecision, LoopDecision, float, float]] = []
    for loop in accepted:
        share = loop.scores.get("weakest_share", 1.0)
        if loop.corroborated or loop.scores.get("submaps") or share >= WEAK_AXIS_SHARE:
            continue
        scale = distance_scale(nodes[loop.candidate.source])
        for other in corroborated:
            if not within_cycle_span(nodes, loop.ends, other.ends):
                continue
            apart_m, apart_deg = motion_difference(implied_start(loop, other, nodes), loop.measured)
            if not one_fit((apart_m, apart_deg), scale):
                rejected.append((loop, other, apart_m, apart_deg))
                break
    for loop, other, apart_m, apart_deg in rejected:
        loop.reject(
            "ambiguous",
            f"rejected: ambiguous: its surfaces hardly face one way (weakest share "
            f"{loop.scores['weakest_share']:.3f}), and the corroborated loop of frames {other.source_frame} -> "
            f"{other.target_frame} puts the source {apart_m:.1f} m / {apart_deg:.0f} deg from this fit",
        )
