"""A weak, uncorroborated loop that a corroborated loop near it puts elsewhere is turned away."""

from __future__ import annotations

import numpy as np

from vcr_odom.geometry import invert, make_transform
from vcr_odom.loops.candidates import LoopCandidate
from vcr_odom.loops.decision import LoopDecision
from vcr_odom.loops.nodes import Node
from vcr_odom.loops.outranked import reject_weak_loops_corroborated_ones_contradict


def _lap() -> list[Node]:
    """Two laps of a 60 m square street, a node every 3 m (nodes 0-39, then 40-79 over the same
    places): the odometry exact."""
    nodes = []
    for k in range(80):
        s = 3.0 * (k % 40)
        side, along = divmod(s, 30.0)
        corners = [(0, 0), (30, 0), (30, 30), (0, 30)]
        directions = [(1, 0), (0, 1), (-1, 0), (0, -1)]
        x0, y0 = corners[int(side)]
        dx, dy = directions[int(side)]
        pose = make_transform(np.eye(3), [x0 + dx * along, y0 + dy * along, 0.0])
        nodes.append(Node(k, k, pose, 3.0 * k, np.zeros((0, 3), np.float32)))
    return nodes


def _loop(
    nodes: list[Node], source: int, target: int, off_m: float, share: float, corroborated: bool
) -> LoopDecision:
    truth = invert(nodes[target].pose) @ nodes[source].pose
    candidate = LoopCandidate(source, target, truth, nodes[source].path_m - nodes[target].path_m, 0.0, 40)
    decision = LoopDecision(candidate, source, target, accepted=True, corroborated=corroborated)
    decision.measured = make_transform(np.eye(3), [off_m, 0.0, 0.0]) @ truth
    decision.scores = {"fitness": 0.8, "submaps": False, "weakest_share": share}
    return decision


def test_a_weak_fit_a_corroborated_loop_puts_metres_away_is_turned_away() -> None:
    nodes = _lap()
    strong = _loop(nodes, 41, 1, 0.0, 0.15, corroborated=True)
    slid = _loop(nodes, 45, 5, 1.8, 0.003, corroborated=False)
    reject_weak_loops_corroborated_ones_contradict([strong, slid], nodes)
    assert strong.accepted
    assert not slid.accepted and slid.check == "ambiguous"
    assert "frames 41 -> 1" in slid.reason and "1.8 m" in slid.reason


def test_what_the_rule_leaves_to_the_graph() -> None:
    nodes = _lap()
    strong = _loop(nodes, 41, 1, 0.0, 0.15, corroborated=True)
    close = _loop(nodes, 45, 5, 0.5, 0.003, corroborated=False)  # within the odometry's noise
    facing = _loop(nodes, 47, 7, 1.8, 0.05, corroborated=False)  # its surfaces face every way
    far = _loop(nodes, 79, 39, 1.8, 0.003, corroborated=False)  # beyond a cycle's span of the strong one
    loops = [strong, close, facing, far]
    reject_weak_loops_corroborated_ones_contradict(loops, nodes)
    assert all(d.accepted for d in loops)


def test_where_the_loops_close_enough_cycles_the_cycles_judge() -> None:
    nodes = _lap()
    loops = [_loop(nodes, 41 + k, 1 + k, 0.0, 0.15, corroborated=True) for k in range(3)]
    slid = _loop(nodes, 45, 5, 1.8, 0.003, corroborated=False)
    reject_weak_loops_corroborated_ones_contradict([*loops, slid], nodes)  # four loops: six cycles
    assert slid.accepted
