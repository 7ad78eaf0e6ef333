"""Loop closure: candidates, verification on real scans, the pose graph, the map command."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation

from vcr_odom.cli.main import cli
from vcr_odom.geometry import invert, make_transform, rotation_angle, rotation_from_euler_zyx
from vcr_odom.loops.candidates import Chain, LoopCandidate, find_candidates
from vcr_odom.loops.graph import LoopEdge, correct_frames, optimise, select_loops
from vcr_odom.loops.nodes import Node
from vcr_odom.loops.settings import LoopSettings

EXACT = np.diag([1e6] * 3 + [1e4] * 3)  # a loop measured to 1 mrad and 1 cm


def information(sigma_m: float, sigma_deg: float) -> np.ndarray:
    """An edge's information (open3d's order: rotation, then translation) from isotropic sigmas."""
    return np.diag([math.radians(sigma_deg) ** -2] * 3 + [sigma_m**-2] * 3)


def chain_of(poses: list | np.ndarray, sigma_m: float = 0.05, sigma_deg: float = 0.05) -> Chain:
    """The chain of ``poses`` whose every edge has the same isotropic uncertainty."""
    poses = np.stack(poses)
    return Chain(poses, [information(sigma_m, sigma_deg)] * (len(poses) - 1))


def _node(k: int, pose: np.ndarray, path_m: float) -> Node:
    return Node(position=k, frame_index=k, pose=pose, path_m=path_m, cloud=np.zeros((0, 3), np.float32))


def _circle(count: int, radius: float, heading_drift_deg_per_node: float = 0.0) -> tuple[list, list]:
    """True poses around a circle and odometry poses whose heading drifts a little at every step."""
    truth, odometry = [np.eye(4)], [np.eye(4)]
    step = make_transform(
        rotation_from_euler_zyx(2 * math.pi / count, 0, 0), [2 * math.pi * radius / count, 0, 0]
    )
    drifted = make_transform(
        rotation_from_euler_zyx(2 * math.pi / count + math.radians(heading_drift_deg_per_node), 0, 0),
        step[:3, 3],
    )
    for _ in range(count + count // 4):  # a lap and a quarter
        truth.append(truth[-1] @ step)
        odometry.append(odometry[-1] @ drifted)
    return truth, odometry


def _nodes(poses: list) -> list[Node]:
    path = np.concatenate(
        [[0.0], np.cumsum([np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in itertools.pairwise(poses)])]
    )
    return [_node(k, pose, float(path[k])) for k, pose in enumerate(poses)]


def test_candidates_are_revisits_within_the_uncertainty_and_none_on_a_street() -> None:
    truth, odometry = _circle(60, 40.0, heading_drift_deg_per_node=0.05)
    nodes = _nodes(odometry)
    candidates = find_candidates(nodes, chain_of(odometry), LoopSettings())
    assert candidates, "a lap and a quarter revisits the start"
    true_distances = []
    for candidate in candidates:
        assert candidate.source > 60 - 5 and candidate.target < candidate.source - 40
        assert candidate.path_m == pytest.approx(
            nodes[candidate.source].path_m - nodes[candidate.target].path_m
        )
        true_distances.append(np.linalg.norm(truth[candidate.source][:3, 3] - truth[candidate.target][:3, 3]))
    assert min(true_distances) < 5.0
    street = [make_transform(np.eye(3), [3.0 * k, 0, 0]) for k in range(200)]
    assert find_candidates(_nodes(street), chain_of(street), LoopSettings()) == []


def test_an_odometry_certain_to_centimetres_proposes_no_node_beyond_the_sensors_overlap() -> None:
    """A return along a street 12 m to the side of the way out (another street: the sensor's overlap is
    5 m), by an odometry whose position is uncertain by a few centimetres there: the chance that the
    two visits stand within 5 m is nil, and no candidate should be proposed."""
    out = [make_transform(np.eye(3), [3.0 * k, 0, 0]) for k in range(41)]
    back = [make_transform(np.eye(3), [3.0 * k, 12.0, 0]) for k in range(40, -1, -1)]
    poses = out + back
    chain = chain_of(poses, sigma_m=0.005, sigma_deg=0.0005)
    assert find_candidates(_nodes(poses), chain, LoopSettings()) == []


def test_a_crossing_is_attempted_at_the_node_nearest_the_earlier_street() -> None:
    """A street crossed at 90 deg after a detour: the gate admits nodes short of the crossing, and the
    attempts must not be spent there but at the crossing itself."""
    east = [make_transform(np.eye(3), [3.0 * k - 60.0, 0, 0]) for k in range(41)]  # x -60..60 along y=0
    north = rotation_from_euler_zyx(math.pi / 2, 0, 0)
    detour = [make_transform(np.eye(3), [60.0, 3.0 * k, 0]) for k in range(1, 11)]  # up to y=30
    back = [make_transform(np.eye(3), [60.0 - 3.0 * k, 30.0, 0]) for k in range(1, 21)]  # west to x=0
    south = [make_transform(north.T, [1.0, 30.0 - 3.0 * k, 0]) for k in range(20)]  # down x=1, y=0 at k=10
    poses = east + detour + back + south
    nodes = _nodes(poses)
    candidates = find_candidates(nodes, chain_of(poses), LoopSettings())
    crossing = [c for c in candidates if c.source > len(east) + len(detour) + len(back)]
    assert crossing, "the southbound street crosses the first one"
    nearest = min(crossing, key=lambda c: c.distance_m)
    assert nearest.distance_m < 1.5  # (1, 0) against (0, 0): the crossing itself
    sources = [c.source for c in crossing]
    assert len(sources) == len(set(sources))
    gaps = np.diff(sorted(nodes[j].path_m for j in sources))
    assert (gaps >= 6.0).all(), "attempts stay one every 6 m of path"


def test_a_long_passage_is_attempted_at_most_twenty_times_and_a_short_one_every_6_m() -> None:
    """A return along the same street, a lane apart: every node of the way back revisits, and a
    registration every 6 m would be ~50 of them on 300 m; 20 spread over the passage pin it."""

    def out_and_back(length_m: float) -> list[np.ndarray]:
        count = int(length_m / 3.0)
        out = [make_transform(np.eye(3), [3.0 * k, 0, 0]) for k in range(count + 1)]
        back = [make_transform(np.eye(3), [3.0 * k, 3.5, 0]) for k in range(count, -1, -1)]
        return out + back

    def candidates(length_m: float, settings: LoopSettings) -> tuple[list[Node], list[LoopCandidate]]:
        poses = out_and_back(length_m)
        nodes = _nodes(poses)
        return nodes, find_candidates(nodes, chain_of(poses), settings)

    for length_m, expected_spacing in ((300.0, 13.5), (90.0, 6.0)):
        nodes, found = candidates(length_m, LoopSettings())
        path = sorted(nodes[c.source].path_m for c in found)
        passage_m = path[-1] - path[0]
        assert passage_m > 0.8 * length_m - 30, "the whole way back is attempted, end to end"
        assert np.diff(path).min() >= expected_spacing - 1e-9
        assert np.diff(path).max() <= 2 * expected_spacing + 3.0, "no stretch is left unattempted"
        assert {c.passage for c in found} == {0}, "one passage"
    assert 18 <= len(candidates(300.0, LoopSettings())[1]) <= 21
    assert len(candidates(300.0, LoopSettings(passage_attempts=1000))[1]) >= 40


def test_a_loop_pulls_a_drifted_circle_back_and_no_loop_changes_nothing() -> None:
    truth, odometry = _circle(60, 40.0, heading_drift_deg_per_node=0.1)
    poses = np.stack(odometry)
    edges = [information(0.05, 0.05)] * (len(poses) - 1)
    assert np.array_equal(optimise(poses, edges, []), poses)
    loops = [LoopEdge(j, j - 60, invert(truth[j - 60]) @ truth[j], EXACT) for j in range(60, 76, 3)]
    after = optimise(poses, edges, loops)
    error_before = np.linalg.norm(odometry[-1][:3, 3] - truth[-1][:3, 3])
    error_after = np.linalg.norm(after[-1][:3, 3] - truth[-1][:3, 3])
    assert error_before > 3.0
    assert error_after < error_before / 5
    assert np.allclose(after[0], poses[0]), "the first node holds the frame"


def test_the_graph_leaves_out_a_loop_that_disagrees_with_the_others() -> None:
    truth, odometry = _circle(60, 40.0, heading_drift_deg_per_node=0.05)
    chain = chain_of(odometry)
    true_loops = [LoopEdge(j, j - 60, invert(truth[j - 60]) @ truth[j], EXACT) for j in range(60, 76, 3)]
    block_away = make_transform(np.eye(3), [30.0, 0, 0])  # a look-alike place one block further on
    false_loop = LoopEdge(70, 20, block_away @ invert(truth[20]) @ truth[70], EXACT)
    selection = select_loops([*true_loops, false_loop], chain, LoopSettings())
    assert selection.verdicts[:-1] == [None] * len(true_loops)
    check, reason = selection.verdicts[-1]
    assert check == "inconsistent"
    assert f"with {len(true_loops)} of the {len(true_loops)} loops kept" in reason
    kept = [loop for loop, verdict in zip(true_loops, selection.verdicts, strict=False) if verdict is None]
    edges = [information(0.05, 0.05)] * (len(odometry) - 1)
    after = optimise(np.stack(odometry), edges, kept, scale=selection.odometry_scale)
    error = np.linalg.norm(after[-1][:3, 3] - truth[-1][:3, 3])
    assert error < np.linalg.norm(odometry[-1][:3, 3] - truth[-1][:3, 3]) / 5


def test_frames_between_nodes_follow_their_nodes_smoothly() -> None:
    frames = np.stack([make_transform(np.eye(3), [float(k), 0, 0]) for k in range(11)])
    before = frames[[0, 10]]
    after = before.copy()
    after[1] = make_transform(rotation_from_euler_zyx(math.radians(10), 0, 0), [10.0, 2.0, 0])
    corrected = correct_frames(frames, [0, 10], before, after)
    assert np.allclose(corrected[0], frames[0]) and np.allclose(corrected[10], after[1])
    steps = np.linalg.norm(np.diff(corrected[:, :3, 3], axis=0), axis=1)
    assert steps.max() - steps.min() < 0.1  # no jump anywhere
    turns = [math.degrees(rotation_angle(a[:3, :3].T @ b[:3, :3])) for a, b in itertools.pairwise(corrected)]
    assert max(turns) == pytest.approx(1.0, abs=1e-6)


@pytest.fixture(scope="module")
def sample_nodes(kitti_sample_root: Path) -> tuple[list[Node], np.ndarray]:
    """Nodes of real frames 0 and 6 (about 5 m apart) and their true relative pose."""
    from vcr_odom.data.kitti import KittiSequence
    from vcr_odom.loops.nodes import NodeRecorder

    sequence = KittiSequence(kitti_sample_root, "00")
    recorder = NodeRecorder(spacing_m=1e-6)
    for index in (0, 6):
        recorder(index, sequence.gt_poses[index], sequence.frame(index))
    nodes = recorder.finish()
    return nodes, invert(sequence.gt_poses[0]) @ sequence.gt_poses[6]


@pytest.fixture(scope="module")
def network():
    from vcr_odom.registration.vcr import VcrRegistrar

    return VcrRegistrar(device="cpu")


def drifted_pair(
    sample_nodes: tuple[list[Node], np.ndarray], error: np.ndarray, path_m: float
) -> tuple[list[Node], LoopCandidate]:
    """The two nodes as an odometry ``error`` off the truth placed them (the first at the origin), and
    the candidate between them (``path_m`` driven between the visits)."""
    nodes, truth = sample_nodes
    prior = error @ truth
    placed = [dataclasses.replace(nodes[0], pose=np.eye(4)), dataclasses.replace(nodes[1], pose=prior)]
    distance = float(np.linalg.norm(prior[:3, 3]))
    return placed, LoopCandidate(1, 0, prior, path_m, distance, frames=int(path_m))


def verify_pair(
    network, nodes: list[Node], candidate: LoopCandidate, sigma_m: float, sigma_deg: float, **settings
):
    """``LoopVerifier.verify`` with the odometry between the two nodes uncertain by the sigmas given."""
    from vcr_odom.loops.nodes import NodeNormals
    from vcr_odom.loops.verify import LoopVerifier

    chain = chain_of([node.pose for node in nodes], sigma_m, sigma_deg)
    verifier = LoopVerifier(network, chain, LoopSettings(**settings), NodeNormals(nodes))
    return verifier.verify(candidate, nodes)


def test_a_revisit_is_registered_without_the_odometry_and_accepted(sample_nodes, network) -> None:
    drifted = make_transform(rotation_from_euler_zyx(math.radians(4), 0, 0), [1.5, -1.0, 0.2])
    nodes, candidate = drifted_pair(sample_nodes, drifted, 150.0)
    decision = verify_pair(network, nodes, candidate, 3.0, 3.0)
    assert decision.accepted, decision.reason
    row = decision.to_dict()
    assert row["failed_check"] is None and row["reason"] == "accepted"
    assert row["source_frame"] == 6 and row["target_frame"] == 0 and row["frames_between"] == 150
    error = invert(sample_nodes[1]) @ decision.loop.transform
    assert np.linalg.norm(error[:3, 3]) < 0.2
    assert math.degrees(rotation_angle(error[:3, :3])) < 0.5
    assert decision.loop is not None and np.all(np.linalg.eigvalsh(decision.loop.information) > 0)
    # what it asked of the odometry is the drift added, measured against the truth independently
    assert row["correction_m"] == pytest.approx(
        np.linalg.norm((invert(candidate.prior) @ sample_nodes[1])[:3, 3]), abs=0.2
    )
    assert row["correction_deg"] == pytest.approx(4.0, abs=0.5)
    json.dumps(row)  # loops.json holds it as it is


def test_a_correction_beyond_the_odometrys_uncertainty_is_rejected_within_it_accepted(
    sample_nodes, network
) -> None:
    """The same fit asks the odometry for 14 m: within an odometry whose propagated uncertainty is
    metres (a long walk), a look-alike place where it is half a metre."""
    drifted = make_transform(rotation_from_euler_zyx(math.radians(3), 0, 0), [11.0, -8.5, 0.5])
    nodes, candidate = drifted_pair(sample_nodes, drifted, 280.0)
    walk = verify_pair(network, nodes, candidate, 10.0, 5.0)
    assert walk.accepted, walk.reason
    assert walk.scores.correction_m > 13.0
    assert np.linalg.norm((invert(sample_nodes[1]) @ walk.loop.transform)[:3, 3]) < 0.2
    car = verify_pair(network, nodes, candidate, 0.5, 0.5)
    assert car.check == "odometry", car.reason
    assert car.reason.startswith("rejected: asks the odometry for")
    assert car.scores.odometry_chi2 > walk.scores.odometry_chi2
    assert car.to_dict()["failed_check"] == "odometry"


def test_a_look_alike_a_block_away_is_rejected(sample_nodes, network) -> None:
    """The same two scans, but the odometry puts them 30 m apart after 60 m of driving: the fit is
    perfect, and only the odometry's uncertainty can say that it is not this place."""
    block = make_transform(np.eye(3), [30.0, 0.0, 0.0])
    nodes, candidate = drifted_pair(sample_nodes, block, 60.0)
    decision = verify_pair(network, nodes, candidate, 1.0, 1.0)
    assert not decision.accepted
    assert decision.check in ("odometry", "overlap"), decision.reason
    assert decision.to_dict()["failed_check"] == decision.check  # loops.json names it


def _fit(transform: np.ndarray, fitness: float, rmse: float = 0.3, weakest_share: float = 0.2):
    """A polished fit as :func:`~vcr_odom.loops.verify.polish` returns it (``weakest_share``: its
    correspondences' normals' share along their weakest direction)."""
    from vcr_odom.loops.verify import Fit

    return Fit(np.asarray(transform, dtype=np.float64), fitness, rmse, information(0.05, 0.1), weakest_share)


@pytest.mark.parametrize(
    ("fitness", "rmse", "weakest_share", "check", "reason"),
    [
        (0.45, 0.3, 0.2, "overlap", "rejected: overlap 0.45 < 0.5"),
        (0.9, 0.7, 0.2, "fit_rmse", "rejected: fit RMSE 0.70 m > 0.60 m"),
        (0.9, 0.3, 0.005, "degenerate", "rejected: degenerate: 0.005 of its surfaces' normals"),
        (0.9, 0.3, 0.2, "", "accepted"),
    ],
)
def test_a_spinning_sensors_fit_is_judged_by_overlap_rmse_and_weakest_direction(
    sample_nodes, network, monkeypatch, fitness, rmse, weakest_share, check, reason
) -> None:
    """The overlap a narrow field gets away with (0.4: tests/test_loops_narrow_field.py) is not enough
    for a spinning sensor, whose two visits see all round; a fit whose surfaces lie apart, or whose
    normals hardly face one direction (a corridor it can slide along), measures no place."""
    from vcr_odom.loops import verify

    nodes, candidate = drifted_pair(sample_nodes, np.eye(4), 150.0)
    fit = _fit(sample_nodes[1], fitness, rmse, weakest_share)
    monkeypatch.setattr(verify, "polish", lambda *args: fit)
    decision = verify_pair(network, nodes, candidate, 1.0, 1.0)
    assert decision.check == check and decision.reason.startswith(reason), decision.reason
    assert decision.accepted is (check == "")


@pytest.mark.parametrize(("other_fitness", "ambiguous"), [(0.85, True), (0.55, False)])
def test_starts_that_end_apart_and_overlap_alike_are_ambiguous(
    sample_nodes, network, monkeypatch, other_fitness: float, ambiguous: bool
) -> None:
    """The network's start ends at the truth, the odometry's 3 m along: both within the odometry's
    uncertainty. Overlapping alike (a repetitive place) the loop is ambiguous; where the truth's fit
    overlaps clearly better, it wins."""
    from vcr_odom.loops import verify

    truth = sample_nodes[1]
    nodes, candidate = drifted_pair(sample_nodes, make_transform(np.eye(3), [1.0, 0.5, 0.0]), 150.0)
    fits = iter([_fit(truth, 0.9), _fit(truth @ make_transform(np.eye(3), [3.0, 0, 0]), other_fitness)])
    # the network's start first, then the odometry's; its turned starts reach the truth's fit
    monkeypatch.setattr(verify, "polish", lambda *args: next(fits, _fit(truth, 0.9)))
    decision = verify_pair(network, nodes, candidate, 5.0, 5.0)
    assert decision.scores.start == "network" and decision.scores.starts_apart_m == pytest.approx(3.0)
    assert (decision.check == "ambiguous") is ambiguous, decision.reason
    assert decision.accepted is not ambiguous


def test_the_odometrys_start_is_also_tried_turned_and_moved_by_its_uncertainty(
    sample_nodes, network, monkeypatch
) -> None:
    """Besides the network's and the odometry's starts, the odometry's turned two sigmas of its heading
    uncertainty (about the world's up) either way, and moved two sigmas of its position uncertainty
    along the level direction it is least sure of, each with nothing else about it changed."""
    from vcr_odom.loops import verify

    nodes, candidate = drifted_pair(sample_nodes, np.eye(4), 150.0)
    tilted = make_transform(rotation_from_euler_zyx(0.5, 0.1, 0.2), [3.0, -2.0, 1.0])  # the world's up off z
    nodes = [dataclasses.replace(node, pose=tilted @ node.pose) for node in nodes]
    starts = []

    def polish(source, target, start, *args):
        starts.append(np.array(start))
        return _fit(sample_nodes[1], 0.9)

    monkeypatch.setattr(verify, "polish", polish)
    verify_pair(network, nodes, candidate, 1.0, 3.0)
    assert len(starts) == 6
    assert np.allclose(starts[1], candidate.prior)
    sigma = math.radians(3.0) * math.sqrt(len(nodes) - 1)  # one edge of 3 deg
    for turned, sign in zip(starts[2::2], (-1.0, 1.0), strict=True):
        turn = turned[:3, :3] @ candidate.prior[:3, :3].T  # in the first node's frame
        in_world = tilted[:3, :3] @ turn @ tilted[:3, :3].T
        assert np.allclose(turned[:3, 3], candidate.prior[:3, 3])
        assert np.allclose(Rotation.from_matrix(in_world).as_rotvec(), [0.0, 0.0, sign * 2.0 * sigma])
    # one edge of 1 m and 3 deg moves the later node's position d by rho + omega x d (the first node's
    # frame): covariance 1 + sigma^2 (|d|^2 - d d^T); its largest variance across the world's up
    d, up = candidate.prior[:3, 3], tilted[2, :3]
    position = np.eye(3) + sigma**2 * (d @ d * np.eye(3) - np.outer(d, d))
    level = np.linalg.svd(np.eye(3) - np.outer(up, up))[0][:, :2]
    variances, directions = np.linalg.eigh(level.T @ position @ level)
    expected = 2.0 * math.sqrt(variances[-1]) * level @ directions[:, -1]
    moves = [moved[:3, 3] - d for moved in starts[3::2]]
    assert all(np.allclose(moved[:3, :3], candidate.prior[:3, :3]) for moved in starts[3::2])
    assert np.allclose(moves[0], -moves[1]) and np.allclose(abs(moves[0] @ expected), expected @ expected)
    assert np.linalg.norm(moves[0]) > 2.0  # beyond the edge's own metre: the heading's lever counts


@pytest.mark.parametrize(("network_fitness", "ambiguous"), [(0.5, False), (0.8, True)])
def test_a_network_start_that_ends_in_a_clearly_worse_fit_missed(
    sample_nodes, network, monkeypatch, network_fitness: float, ambiguous: bool
) -> None:
    """The network's start ends 4 m along, every start of the odometry's at the truth. Where its fit
    overlaps clearly less the network missed (a narrow view it cannot register) and the loop stands;
    where it overlaps alike, the place repeats."""
    from vcr_odom.loops import verify

    truth = sample_nodes[1]
    nodes, candidate = drifted_pair(sample_nodes, np.eye(4), 150.0)
    away = make_transform(np.eye(3), [4.0, 0.0, 0.0]) @ truth
    fits = iter([_fit(away, network_fitness)])  # the network's start is polished first
    monkeypatch.setattr(verify, "polish", lambda *args: next(fits, _fit(truth, 0.9)))
    decision = verify_pair(network, nodes, candidate, 3.0, 3.0)
    assert decision.scores.start == "odometry" and decision.scores.starts_apart_m == pytest.approx(4.0)
    assert (decision.check == "ambiguous") is ambiguous, decision.reason
    assert decision.accepted is not ambiguous


@pytest.mark.parametrize(("turned_fitness", "ambiguous"), [(0.8, True), (0.6, False)])
def test_a_fit_the_odometrys_heading_uncertainty_leaves_for_another_alike_is_ambiguous(
    sample_nodes, network, monkeypatch, turned_fitness: float, ambiguous: bool
) -> None:
    """The network's and the odometry's starts end in one fit, but a start the odometry's heading
    uncertainty allows ends 20 deg away in a fit that overlaps nearly as well: the place allows several
    headings (a bent submap, a symmetric yard), and the two starts that agree only shared a basin."""
    from vcr_odom.loops import verify

    truth = sample_nodes[1]
    nodes, candidate = drifted_pair(sample_nodes, np.eye(4), 150.0)
    away = make_transform(rotation_from_euler_zyx(math.radians(20), 0, 0), [0.0, 0.0, 0.0])
    fits = iter([_fit(truth, 0.9), _fit(truth, 0.9), _fit(away @ truth, turned_fitness)])
    monkeypatch.setattr(verify, "polish", lambda *args: next(fits, _fit(truth, 0.9)))
    decision = verify_pair(network, nodes, candidate, 3.0, 10.0)
    assert (decision.check == "ambiguous") is ambiguous, decision.reason
    assert decision.accepted is not ambiguous
    assert decision.scores.starts_apart_deg == pytest.approx(20.0)
    if ambiguous:
        assert "odometry turned -2 sigma" in decision.reason, decision.reason


def test_a_kept_loop_records_the_information_the_graph_gave_it(sample_nodes, network, monkeypatch) -> None:
    """loops.json's ``information`` of a kept loop is exactly what the graph weighed it by (its fit's,
    in its target's frame): what a user needs to judge its error or to reuse it in another back-end."""
    from vcr_odom.loops import pipeline
    from vcr_odom.loops.verify import LoopDecision

    nodes, candidate = drifted_pair(sample_nodes, np.eye(4), 150.0)
    information = np.diag([4e4, 3e4, 2e4, 900.0, 400.0, 100.0])

    def accepted(self, candidate, nodes):
        edge = LoopEdge(candidate.source, candidate.target, candidate.prior, information)
        return LoopDecision(candidate, 1, 0, accepted=True, reason="accepted", loop=edge)

    given = []
    optimise = pipeline.optimise
    monkeypatch.setattr(pipeline, "find_candidates", lambda *args: [candidate])
    monkeypatch.setattr(pipeline.LoopVerifier, "verify", accepted)
    monkeypatch.setattr(pipeline, "optimise", lambda *a, **k: given.append(a[2]) or optimise(*a, **k))
    poses = np.stack([node.pose for node in nodes])
    closed = pipeline.close_loops(LoopSettings(), network, nodes, poses)
    (decision,) = closed.decisions
    ((edge,),) = given
    assert decision.accepted and np.array_equal(np.array(decision.extra["information"]), edge.information)
    np.testing.assert_allclose(edge.information, information)  # an own-cloud loop: its fit's alone
    assert json.loads(json.dumps(decision.to_dict()))["information"] == edge.information.tolist()


def test_a_node_with_an_empty_scan_is_rejected_not_an_error(sample_nodes, network) -> None:
    nodes, candidate = drifted_pair(sample_nodes, np.eye(4), 60.0)
    empty = [nodes[0], dataclasses.replace(nodes[1], cloud=np.zeros((0, 3), np.float32))]
    decision = verify_pair(network, empty, candidate, 1.0, 1.0)
    assert not decision.accepted and decision.check == "points"
    assert decision.reason.startswith("rejected: too few points")


def _map(data_root: Path, results: Path, *options: str):
    """``vcr-odom map`` on the small synthetic sequence 00, as a user runs it."""
    return CliRunner().invoke(
        cli, ["map", "--data-root", str(data_root), "--seq", "00", "--results-dir", str(results), *options]
    )


def test_map_without_revisits_keeps_the_odometry_and_writes_every_file(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    result = _map(small_synthetic_root, tmp_path)
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in tmp_path.iterdir() if p.name.startswith("20")]
    for name in ("trajectory_kitti.txt", "trajectory_tum.txt", "odometry_kitti.txt", "loops.json", "map.ply"):
        assert (folder / name).is_file(), name
    assert np.array_equal(
        np.loadtxt(folder / "trajectory_kitti.txt"), np.loadtxt(folder / "odometry_kitti.txt")
    )
    loops = json.loads((folder / "loops.json").read_text())
    assert loops["candidates"] == [] and loops["nodes"][0]["frame"] == 0
    marker = json.loads((folder / "result.json").read_text())
    assert marker["status"] == "complete" and marker["frames_done"] == 8
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["loops"]["accepted"] == 0 and metrics["memory"]["nodes"] == len(loops["nodes"])
    assert metrics["loops"]["candidates"] == 0 and metrics["loops"]["by_outcome"] == {}
    assert metrics["loops"]["ground_up"] == {"used": False}, "no loop: no graph, no up priors"
    assert metrics["loops"]["odometry_covariance_scale"] == 1.0, "no loop measured the odometry"
    assert metrics["loops"]["node_voxel_m"] == 1.0  # a street: the nodes keep their 1 m grid
    assert metrics["odometry"]["ate_rpe"] == metrics["ate_rpe"]
    config = json.loads((folder / "config.json").read_text())["config"]
    assert config["command"] == "map" and config["revisit_radius_m"] == 5.0


def test_map_interrupted_after_the_odometry_keeps_the_odometry_marked_partial(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import vcr_odom.map_command as map_command

    def ctrl_c(*_args: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(map_command, "_map_from_nodes", ctrl_c)
    result = _map(small_synthetic_root, tmp_path)
    assert result.exit_code == 130, result.output
    (folder,) = [p for p in tmp_path.iterdir() if p.name.startswith("20")]
    marker = json.loads((folder / "result.json").read_text())
    assert marker["status"] == "partial" and marker["frames_done"] == 8
    assert "interrupted" in marker["reason"].lower()
    assert len(np.loadtxt(folder / "trajectory_kitti.txt")) == 8
    assert not (folder / "map.ply").exists()


def test_map_says_how_many_candidates_asked_the_odometry_for_too_much(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The console names the rejection a user can act on (an odometry that drifts more than its scans
    say, or look-alike places), and metrics.json and loops.json count every candidate by its check."""
    import vcr_odom.loops.pipeline as pipeline
    from vcr_odom.loops.verify import LoopDecision

    close_loops = pipeline.close_loops

    def with_rejections(*args: object, **kwargs: object):
        closed = close_loops(*args, **kwargs)
        candidate = LoopCandidate(1, 0, np.eye(4), 50.0, 0.0)
        closed.decisions += [
            LoopDecision(candidate, 5, 0, check="odometry", reason="rejected: asks the odometry for 9 m"),
            LoopDecision(candidate, 6, 0, check="inconsistent", reason="rejected: its cycles"),
            LoopDecision(candidate, 7, 0, check="inconsistent", reason="rejected: its cycles"),
        ]
        return closed

    monkeypatch.setattr(pipeline, "close_loops", with_rejections)
    result = _map(small_synthetic_root, tmp_path)
    assert result.exit_code == 0, result.output
    output = " ".join(result.output.split())
    assert "3 loop candidate(s), 0 accepted" in output
    assert "1 candidate(s) fit but asked the odometry for more than its uncertainty allows" in output
    assert "2 loop(s) passed every check of their own but close no cycle with the loops kept" in output
    (folder,) = [p for p in tmp_path.iterdir() if p.name.startswith("20")]
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["loops"]["by_outcome"] == {"odometry": 1, "inconsistent": 2}
    loops = json.loads((folder / "loops.json").read_text())
    assert [c["failed_check"] for c in loops["candidates"]] == ["odometry", "inconsistent", "inconsistent"]
    assert loops["candidates"][0]["reason"] == "rejected: asks the odometry for 9 m"


def test_compare_puts_a_mapped_row_beside_its_odometry(small_synthetic_root: Path, tmp_path: Path) -> None:
    args = [
        "compare",
        "--data-root",
        str(small_synthetic_root),
        "--seq",
        "00",
        "--results-dir",
        str(tmp_path),
    ]
    result = CliRunner().invoke(cli, [*args, "-b", "icp", "-b", "icp+loops"])
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in tmp_path.iterdir() if p.name.startswith("20")]
    rows = json.loads((folder / "compare.json").read_text())
    assert set(rows) == {"icp", "icp+loops"}
    assert (folder / "icp+loops" / "loops.json").is_file()
    mapped = np.loadtxt(folder / "icp+loops" / "trajectory_kitti.txt")
    assert np.allclose(mapped, np.loadtxt(folder / "icp" / "trajectory_kitti.txt"), atol=1e-9)  # no revisits
    bad = CliRunner().invoke(cli, [*args, "-b", "nope+loops"])
    assert bad.exit_code == 2 and "unknown method 'nope'" in bad.output


def test_map_that_cannot_write_its_map_keeps_the_trajectory_marked_partial(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from vcr_odom.mapping import VoxelMap

    def disk_full(*_args: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(VoxelMap, "save", disk_full)
    result = _map(small_synthetic_root, tmp_path)
    assert result.exit_code == 1
    (folder,) = [p for p in tmp_path.iterdir() if p.name.startswith("20")]
    marker = json.loads((folder / "result.json").read_text())
    assert marker["status"] == "partial" and "not written: map.ply" in marker["reason"]
    assert len(np.loadtxt(folder / "trajectory_kitti.txt")) == 8
    assert not (folder / "map.ply").exists() and (folder / "loops.json").exists()  # the small files stay


def test_the_loop_network_shares_the_odometrys_weights_with_its_own_passes(
    small_synthetic_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A VCR-based odometry's network is loaded once and shared with the loop closure, which runs the
    weights' own number of passes; a non-VCR odometry's loops load their own network; and run's
    --save-map, which map would ignore, is refused by name."""
    from vcr_odom.data.selection import FrameSelection
    from vcr_odom.errors import ConfigError
    from vcr_odom.loops.pipeline import loop_network
    from vcr_odom.map_command import MapSettings
    from vcr_odom.odometry.run import method_for
    from vcr_odom.registration import vcr as vcr_module

    loads = []
    original = vcr_module.load_weights
    monkeypatch.setattr(vcr_module, "load_weights", lambda *a, **k: loads.append(a) or original(*a, **k))
    settings = MapSettings(
        selection=FrameSelection(data_root=small_synthetic_root), method="vcr", device="cpu"
    )
    odometry = method_for(settings)
    network = loop_network(settings.weights, settings.device, settings.vcr_points, odometry)
    assert len(loads) == 1 and network.model is odometry.registrar.model
    assert odometry.registrar.passes == 1 and network.passes == vcr_module.default_passes(network.config)
    icp = method_for(settings.with_changes(method="icp10"))
    assert (
        loop_network(settings.weights, settings.device, settings.vcr_points, icp).model is not network.model
    )
    assert len(loads) == 2
    with pytest.raises(ConfigError, match="save_map does not apply to map"):
        MapSettings(selection=settings.selection, save_map=Path("map.ply"))


@pytest.mark.parametrize(
    ("option", "value"),
    [("--revisit-radius", "0"), ("--min-loop-path", "-3"), ("--node-spacing", "0"), ("--max-drift", "2")],
)
def test_map_refuses_a_bad_or_unknown_loop_option_by_name(
    small_synthetic_root: Path, tmp_path: Path, option: str, value: str
) -> None:
    """Out of range, or an option map no longer has (the drift bounds: the odometry's propagated
    uncertainty replaced them): a usage error naming it, and nothing written."""
    result = _map(small_synthetic_root, tmp_path, option, value)
    assert result.exit_code == 2 and option in result.output, result.output
    assert not any(tmp_path.iterdir()), "nothing written for a bad option"


def test_map_takes_passage_attempts_from_its_option_and_refuses_zero(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    args = ["map", "--data-root", str(small_synthetic_root), "--seq", "00", "--frames", "0:3"]
    refused = CliRunner().invoke(
        cli, [*args, "--results-dir", str(tmp_path / "no"), "--passage-attempts", "0"]
    )
    assert refused.exit_code == 2 and "--passage-attempts" in refused.output, refused.output
    assert not (tmp_path / "no").exists() or not any((tmp_path / "no").iterdir())
    result = CliRunner().invoke(
        cli, [*args, "--results-dir", str(tmp_path / "yes"), "--passage-attempts", "7"]
    )
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in (tmp_path / "yes").iterdir() if p.is_dir() and p.name.startswith("20")]
    assert json.loads((folder / "config.json").read_text())["config"]["passage_attempts"] == 7


def test_metrics_count_candidates_by_the_check_they_failed() -> None:
    """metrics.json's by_outcome reads the decision's check, in the order the checks are tried."""
    from vcr_odom.loops.verify import CHECKS, LoopDecision
    from vcr_odom.map_command import _loop_summary

    assert CHECKS == ("points", "overlap", "fit_rmse", "odometry", "degenerate", "ambiguous", "inconsistent")
    candidate = LoopCandidate(1, 0, np.eye(4), 50.0, 0.0)
    checks = ["odometry", "", "overlap", "odometry", "inconsistent", "", "points"]
    decisions = [LoopDecision(candidate, 1, 0, accepted=not c, check=c) for c in checks]
    summary = _loop_summary(decisions)
    assert summary["by_outcome"] == {
        "accepted": 2,
        "points": 1,
        "overlap": 1,
        "odometry": 2,
        "inconsistent": 1,
    }
    assert list(summary["by_outcome"]) == ["accepted", "points", "overlap", "odometry", "inconsistent"]
    assert summary["accepted"] == 2 and summary["candidates"] == len(checks)


def test_the_loop_phase_estimates_each_nodes_normals_once(sample_nodes, network, monkeypatch) -> None:
    """The odometry edges' information, the verification and the walls' up all read a node's normals:
    estimated once and shared, the same a fresh estimate gives."""
    from collections import Counter

    from vcr_odom.loops import gravity, verify
    from vcr_odom.loops import nodes as node_module
    from vcr_odom.loops.nodes import NodeNormals, normal_cloud

    nodes, candidate = drifted_pair(
        sample_nodes, make_transform(rotation_from_euler_zyx(math.radians(4), 0, 0), [1.5, -1.0, 0.2]), 150.0
    )
    fresh = np.asarray(normal_cloud(nodes[0].cloud, nodes[0].cloud_voxel).normals)
    estimated: Counter[bytes] = Counter()

    def counted(points: np.ndarray, voxel: float):
        estimated[points.tobytes()] += 1
        return normal_cloud(points, voxel)

    for module in (node_module, verify):
        monkeypatch.setattr(module, "normal_cloud", counted)
    normals = NodeNormals(nodes)
    settings = LoopSettings()
    edges = verify.odometry_information(nodes, normals, settings)
    chain = Chain(np.stack([node.pose for node in nodes]), edges)
    decision = verify.LoopVerifier(network, chain, settings, normals).verify(candidate, nodes)
    assert decision.loop is not None, decision.reason
    gravity.up_priors(nodes, normals, settings)
    assert set(estimated) == {node.cloud.tobytes() for node in nodes}
    assert set(estimated.values()) == {1}, "a node's normals estimated more than once"
    assert np.array_equal(np.asarray(normals.cloud(0).normals), fresh)


def test_map_without_loops_loads_no_network(small_synthetic_root: Path, tmp_path: Path, monkeypatch) -> None:
    """--no-loops is the odometry and its map alone: the loop network (a weights file read, its
    memory) is never built."""
    import vcr_odom.map_command as map_command

    def no_network(*_: object) -> None:
        raise AssertionError("the loop network was loaded for --no-loops")

    monkeypatch.setattr(map_command, "loop_network", no_network)
    args = ["map", "--data-root", str(small_synthetic_root), "--seq", "00", "--frames", "0:3", "--no-loops"]
    result = CliRunner().invoke(cli, [*args, "--method", "icp", "--results-dir", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "latest" / "trajectory_kitti.txt").is_file()
