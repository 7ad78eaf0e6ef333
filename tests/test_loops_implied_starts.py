"""A loop polished from where another loop near it puts its source: a place with two fits is ambiguous."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from vcr_odom.geometry import invert, make_transform, motion_difference
from vcr_odom.loops.candidates import LoopCandidate
from vcr_odom.loops.decision import LoopDecision
from vcr_odom.loops.implied_starts import implied_start, reject_loops_ambiguous_from_implied_starts
from vcr_odom.loops.nodes import Node, NodeNormals

PILLAR_SPACING_M = 3.0


def _street() -> np.ndarray:
    """A floor, a wall along x at y = 6 with a pillar every 3 m, and a tall end wall across the street at
    x = -15: from near the end wall the scan measures x; 20 m away only the pillars do, every 3 m alike."""
    step = 0.25
    xs = np.arange(-15.0, 45.0, step)
    floor = np.array([(x, y, 0.0) for x in xs for y in np.arange(-5.0, 6.0, 0.5)])
    wall = np.array([(x, 6.0, z) for x in xs for z in np.arange(0.0, 4.0, step)])
    pillars = np.array(
        [
            (x0 + dx, 6.0 - dy, z)
            for x0 in np.arange(-12.0, 45.0, PILLAR_SPACING_M)
            for dx in (0.0, 0.5)
            for dy in np.arange(0.0, 1.0, step)
            for z in np.arange(0.0, 4.0, step)
        ]
    )
    end = np.array([(-15.0, y, z) for y in np.arange(-5.0, 6.0, step) for z in np.arange(0.0, 8.0, step)])
    return np.vstack([floor, wall, pillars, end])


def _node(index: int, x: float, path_m: float, street: np.ndarray) -> Node:
    """A node at (x, 0, 1) seeing the street within 18 m, its cloud on a 1 m grid, the odometry exact."""
    pose = make_transform(np.eye(3), [x, 0.0, 1.0])
    seen = street[np.linalg.norm(street - pose[:3, 3], axis=1) < 18.0]
    local = (seen - pose[:3, 3]).astype(np.float64)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(local)).voxel_down_sample(1.0)
    return Node(index, index, pose, path_m, np.asarray(cloud.points, dtype=np.float32))


def _loop(nodes: list[Node], normals: NodeNormals, source: int, target: int, off_m: float) -> LoopDecision:
    """A loop the verification accepted ``off_m`` along x of the truth, with its overlap there (the
    fine stage's 1 m correspondences)."""
    truth = invert(nodes[target].pose) @ nodes[source].pose
    measured = make_transform(np.eye(3), [off_m, 0.0, 0.0]) @ truth
    registration = o3d.pipelines.registration
    fit = registration.evaluate_registration(normals.cloud(source), normals.cloud(target), 1.0, measured)
    candidate = LoopCandidate(source, target, truth, nodes[source].path_m - nodes[target].path_m, 0.0, 60)
    decision = LoopDecision(candidate, nodes[source].frame_index, nodes[target].frame_index, accepted=True)
    decision.measured = measured
    decision.scores = {"fitness": round(float(fit.fitness), 4), "submaps": False}
    return decision


def _walk() -> tuple[list[Node], NodeNormals]:
    """Out along the street and back: nodes 0 (by the end wall) and 1 (20 m on), revisited by 2 and 3."""
    street = _street()
    nodes = [_node(0, -8.0, 0.0, street), _node(1, 14.0, 22.0, street)]
    nodes += [_node(2, -8.0, 120.0, street), _node(3, 14.0, 142.0, street)]
    return nodes, NodeNormals(nodes)


def _error_m(decision: LoopDecision, nodes: list[Node]) -> float:
    c = decision.candidate
    return motion_difference(invert(nodes[c.target].pose) @ nodes[c.source].pose, decision.measured)[0]


def test_a_loop_that_also_fits_where_a_right_loop_puts_it_is_turned_away() -> None:
    nodes, normals = _walk()
    right = _loop(nodes, normals, 2, 0, 0.0)
    slid = _loop(nodes, normals, 3, 1, PILLAR_SPACING_M)
    assert slid.scores["fitness"] > 0.85, "the pillars' spacing fits as well as the place (the setup)"

    reject_loops_ambiguous_from_implied_starts([right, slid], nodes, normals)
    assert not slid.accepted and slid.check == "ambiguous"
    assert "frames 2 -> 0" in slid.reason and "3." in slid.reason
    assert right.accepted and right.check == "", "near the end wall the pillars' spacing fits no longer"


def test_loops_that_agree_are_not_polished_again() -> None:
    nodes, normals = _walk()
    loops = [_loop(nodes, normals, 2, 0, 0.0), _loop(nodes, normals, 3, 1, 0.0)]
    reject_loops_ambiguous_from_implied_starts(loops, nodes, normals)
    assert all(d.accepted for d in loops)
    assert motion_difference(implied_start(loops[1], loops[0], nodes), loops[1].measured)[0] < 0.1


def test_loops_too_far_apart_do_not_judge_each_other() -> None:
    nodes, normals = _walk()
    nodes[1].path_m, nodes[3].path_m = 200.0, 320.0  # the stretches between the loops beyond a cycle's span
    loops = [_loop(nodes, normals, 2, 0, 0.0), _loop(nodes, normals, 3, 1, PILLAR_SPACING_M)]
    reject_loops_ambiguous_from_implied_starts(loops, nodes, normals)
    assert all(d.accepted for d in loops)


def _turned_away_as_ambiguous(loop: LoopDecision) -> LoopDecision:
    """``loop`` as the verification turns away a candidate whose two starts ended in two fits, its
    better one measured."""
    loop.reject("ambiguous", "rejected: ambiguous: the two starts end apart")
    return loop


def test_a_loop_that_fits_where_an_ambiguous_candidate_puts_it_is_turned_away() -> None:
    """The drifted avenue (5604): the candidate by the end wall was turned away as ambiguous, its better
    fit on the place; the loop kept among the pillars one spacing off also fits where that fit puts it,
    so it is as ambiguous and goes."""
    nodes, normals = _walk()
    slid = _loop(nodes, normals, 3, 1, PILLAR_SPACING_M)
    reject_loops_ambiguous_from_implied_starts([slid], nodes, normals)
    assert slid.accepted, "alone, nothing says the place repeats"

    candidate = _turned_away_as_ambiguous(_loop(nodes, normals, 2, 0, 0.0))
    reject_loops_ambiguous_from_implied_starts([candidate, slid], nodes, normals)
    assert not slid.accepted and slid.check == "ambiguous"
    assert "ambiguous candidate of frames 2 -> 0" in slid.reason, slid.reason
    assert candidate.reason.endswith("the two starts end apart")  # its own verdict is left as it was


def test_a_loop_where_the_place_does_not_repeat_stays_beside_an_ambiguous_candidate() -> None:
    """Near the end wall the pillars' spacing fits no longer: polished from where an ambiguous
    candidate's fit one spacing off puts it, the right loop comes back to its own fit."""
    nodes, normals = _walk()
    right = _loop(nodes, normals, 2, 0, 0.0)
    candidate = _turned_away_as_ambiguous(_loop(nodes, normals, 3, 1, PILLAR_SPACING_M))
    reject_loops_ambiguous_from_implied_starts([right, candidate], nodes, normals)
    assert right.accepted and right.check == ""
