"""Whether a verified loop's two starts corroborate its fit: the network's start and the odometry's,
far apart, polished into the one fit, on a scene that measures every direction.

Why: a handheld walk's odometry drifts 15-27 deg a lap, and where its loops are too few to close
cycles the pose graph could only weigh them against the drift model's car-sized sigmas, which dropped
right loops as readily as false ones (:mod:`~vcr_odom.loops.graph`). Two starts a metre or more apart
that end in one fit are a second measurement of the place; the fit's correspondence normals must
hold every direction, since along a footpath or a corridor both starts slide to the same wrong place.
A fit whose surfaces face every direction well (:data:`STRONG_SHARE`) corroborates itself: there is
no direction left for it to slide along.
"""

from __future__ import annotations

from typing import Any

from vcr_odom.odometry.degeneracy import WEAK_AXIS_SHARE

CORROBORATING_STARTS_M = 1.0
CORROBORATING_FITNESS = 0.02
"""The two starts at least this far apart (metres, on every node grid: the network's error does not
shrink indoors) must end within the probe's return distance of each other at overlaps this close.
Starts that differ by a turn only corroborate nothing: on the indoor walks with their heading drifted
10-20 deg per 100 m, false fits 2.3-3.6 m along a corridor had both starts converge from 0.1-0.9 m
apart; right ones from 1.3-12.6 m on the courtyard walks and 1.7-2.6 m indoors (docs/benchmarks.md,
"Loops that measure the drift")."""

STRONG_SHARE = 0.1
"""A fit on the nodes' own clouds with at least this share of its correspondence normals along every
direction is corroborated whatever its starts did. On the recorded courtyard walks every false fit on
the nodes' own clouds the verification kept slid along a footpath (weakest share 0.0097-0.0201), and
an indoor walk with its heading drifted 20 deg per 100 m kept one at 0.0509 with 0.05; right loops the
rounds dropped had 0.06-0.17, one start's fit ending 15-28 m from the other's or the starts beginning
under 1 m apart (docs/benchmarks.md, "Fits that face every way")."""


def corroborated(scores: dict[str, Any], returns_m: float) -> bool:
    """From a loop's scores (:class:`~vcr_odom.loops.verify.LoopDecision`): ``weakest_share`` is at
    least :data:`STRONG_SHARE`, or its starts began at least
    :data:`CORROBORATING_STARTS_M` apart and ended within ``returns_m`` at overlaps
    :data:`CORROBORATING_FITNESS` apart, and ``weakest_share`` is at least the polish's
    :data:`~vcr_odom.odometry.degeneracy.WEAK_AXIS_SHARE` (along a footpath seen end on, both starts
    slid to the same place 1.4 m off on courtyard walk 945). Only fits of the nodes' own clouds are
    scored so: a submap is the odometry's picture, and both starts fit a bent one alike (walk 950:
    11.8 deg off)."""
    if scores["weakest_share"] >= STRONG_SHARE:
        return True
    return (
        scores["starts_before_m"] >= CORROBORATING_STARTS_M
        and scores["starts_apart_m"] <= returns_m
        and abs(scores["fitness"] - scores["other_start_fitness"]) <= CORROBORATING_FITNESS
        and scores["weakest_share"] >= WEAK_AXIS_SHARE
    )
