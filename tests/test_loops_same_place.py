"""Submap fits of one place that put the source metres apart: the accepted one is turned away."""

from __future__ import annotations

import numpy as np

from vcr_odom.geometry import invert, make_transform
from vcr_odom.loops.candidates import LoopCandidate
from vcr_odom.loops.decision import LoopDecision
from vcr_odom.loops.nodes import Node
from vcr_odom.loops.same_place import reject_disagreeing_submap_fits


def _crossing_nodes() -> list[Node]:
    """A street driven east (nodes 0-19, 3 m apart), then a return along y crossing it at x = 30 m
    (nodes 20-39): the odometry is exact."""
    nodes = []
    for k in range(40):
        if k < 20:
            pose = make_transform(np.eye(3), [3.0 * k, 0.0, 0.0])
        else:
            pose = make_transform(np.eye(3), [30.0, 3.0 * (k - 30), 0.0])
        nodes.append(Node(k, k, pose, 3.0 * k, np.zeros((0, 3), np.float32)))
    return nodes


def _decision(nodes: list[Node], source: int, target: int, slid_m: float, check: str = "") -> LoopDecision:
    """A submap fit of ``source`` on ``target`` that puts the source ``slid_m`` along x from the truth."""
    truth = invert(nodes[target].pose) @ nodes[source].pose
    candidate = LoopCandidate(source, target, truth, 90.0, 0.0, frames=30)
    decision = LoopDecision(candidate, source, target, accepted=not check, check=check)
    decision.measured = make_transform(np.eye(3), [slid_m, 0.0, 0.0]) @ truth
    decision.scores = {"submaps": True}
    return decision


def test_a_fit_that_slid_along_a_repeating_street_is_turned_away_by_its_neighbours() -> None:
    nodes = _crossing_nodes()
    slid = _decision(nodes, 30, 10, slid_m=6.0)
    neighbours = [_decision(nodes, 29, 10, 0.1, "degenerate"), _decision(nodes, 31, 11, -0.2, "degenerate")]
    reject_disagreeing_submap_fits([slid, *neighbours], nodes)
    assert not slid.accepted and slid.check == "ambiguous"
    assert "frames 29 -> 10" in slid.reason or "frames 31 -> 11" in slid.reason
    assert [d.check for d in neighbours] == ["degenerate", "degenerate"], "the others are left as they are"


def test_neighbours_that_agree_keep_their_loops() -> None:
    nodes = _crossing_nodes()
    group = [_decision(nodes, 29, 10, 0.1), _decision(nodes, 30, 10, 0.5), _decision(nodes, 31, 11, -0.3)]
    reject_disagreeing_submap_fits(group, nodes)
    assert all(d.accepted for d in group)


def test_two_accepted_fits_that_disagree_are_left_to_the_pose_graph() -> None:
    nodes = _crossing_nodes()
    pair = [_decision(nodes, 29, 10, 0.3), _decision(nodes, 31, 11, 6.4)]
    reject_disagreeing_submap_fits(pair, nodes)
    assert all(d.accepted for d in pair), "the graph weighs them against each other, with their cycles"


def test_only_fits_of_the_same_place_that_passed_the_drift_bound_count() -> None:
    nodes = _crossing_nodes()
    far = _decision(nodes, 30, 10, 0.0)
    beyond_bound = _decision(nodes, 29, 10, 12.0, "drift_bound")  # a look-alike the bound turned away
    elsewhere = _decision(nodes, 39, 19, 8.0, "degenerate")  # 27 m further along both visits
    own_cloud = _decision(nodes, 31, 11, 8.0, "degenerate")
    own_cloud.scores = {"submaps": False}
    reject_disagreeing_submap_fits([far, beyond_bound, elsewhere, own_cloud], nodes)
    assert far.accepted
