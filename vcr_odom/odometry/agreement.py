"""When two registration results agree, and when one fits markedly worse than another.

The doubt rule (:class:`~vcr_odom.odometry.chain.DoubtRule`) and the polishes
(:mod:`~vcr_odom.odometry.polish`, :mod:`~vcr_odom.odometry.guided_kiss`) judge results by the same two
measures: whether two starts lie in one basin of the local method, and whether one fit is markedly
worse than another. They live here so that neither module sets the other's thresholds.
"""

from __future__ import annotations

from vcr_odom.geometry import Transform, motion_difference

MARKEDLY_WORSE = 0.8
"""A fit below this share of another's is markedly worse: a wrong result leaves a fifth or more of the
points the right one places without a partner. Two fits closer than that cannot be ranked by the fit:
both near-saturated in a stretch that repeats itself, where a result a metre off places every point
too, or both poor. There the fit gives no reason to leave kiss-icp's own start, so its result stays
(docs/benchmarks.md, "Which start wins")."""

BASIN_M = 0.5
BASIN_DEG = 2.0
"""Starts this close end in the same local result: running the local method from both only costs time."""


def within_basin(a: Transform, b: Transform) -> bool:
    """Whether two motions (or poses) lie within one basin of the local method (:data:`BASIN_M`,
    :data:`BASIN_DEG`)."""
    change_m, change_deg = motion_difference(a, b)
    return change_m < BASIN_M and change_deg < BASIN_DEG
