"""Loop closure where a narrow field of view crosses its own path: a 70 deg Avia scan of one street
and one of the crossing street share no point, so the crossing is registered as the two nodes'
submaps (their neighbours' clouds placed by the odometry)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from vcr_odom.data import open_sequence
from vcr_odom.geometry import invert, make_transform, rotation_from_euler_zyx
from vcr_odom.loops import verify
from vcr_odom.loops.candidates import Chain, LoopCandidate
from vcr_odom.loops.nodes import (
    NODE_SPACING_M,
    Node,
    NodeNormals,
    azimuth_coverage,
    submap_cloud,
    submap_members,
    voxel_cloud,
)
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.registration.vcr import VcrRegistrar
from vcr_odom.synth import SensorConfig, SynthSequence

WINDOW_M = 32.0
SETTINGS = LoopSettings()


@pytest.fixture(scope="module")
def network() -> VcrRegistrar:
    return VcrRegistrar(device="cpu")


def verify_candidate(
    network: VcrRegistrar,
    nodes: list[Node],
    candidate: LoopCandidate,
    settings: LoopSettings = SETTINGS,
    sigma_m: float = 0.3,
    sigma_deg: float = 0.5,
):
    """``candidate`` verified on ``nodes`` as an odometry that drifted between the visits placed them:
    the later visit's nodes (those nearer it along the path) moved together so that the source stands
    where the prior puts it; every edge uncertain by the sigmas given."""
    poses = np.stack([node.pose for node in nodes])
    drift = poses[candidate.target] @ candidate.prior @ invert(poses[candidate.source])
    source_path, target_path = nodes[candidate.source].path_m, nodes[candidate.target].path_m
    for k, node in enumerate(nodes):
        if abs(node.path_m - source_path) < abs(node.path_m - target_path):
            poses[k] = drift @ poses[k]
    placed = [dataclasses.replace(node, pose=pose) for node, pose in zip(nodes, poses, strict=True)]
    edge = np.diag([math.radians(sigma_deg) ** -2] * 3 + [sigma_m**-2] * 3)
    chain = Chain(poses, [edge] * (len(nodes) - 1))
    return verify.LoopVerifier(network, chain, settings, NodeNormals(placed)).verify(candidate, placed)


@pytest.fixture(scope="module")
def crossing() -> tuple[list[Node], LoopCandidate, np.ndarray]:
    """Nodes (from ground truth) around both passes of an Avia figure eight's crossing (frames 413
    and 716, 0.3 m apart, turned 94 deg), and the candidate with a prior 1.3 m / 3 deg off."""
    drive = SynthSequence(
        frames=800, seed=3, sensor=SensorConfig.model("avia"), scene="avenue", route="figure8"
    )
    poses = drive.world_poses
    path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))])
    earlier, later = 413, 716
    frames = [
        k
        for k in range(len(poses))
        if min(abs(path[k] - path[earlier]), abs(path[k] - path[later])) <= WINDOW_M
    ]
    nodes: list[Node] = []
    for k in frames:
        if not nodes or path[k] - nodes[-1].path_m >= NODE_SPACING_M or k in (earlier, later):
            nodes.append(Node(k, k, poses[k], float(path[k]), voxel_cloud(drive.frame(k))))
    target = next(n for n, node in enumerate(nodes) if node.frame_index == earlier)
    source = next(n for n, node in enumerate(nodes) if node.frame_index == later)
    truth = invert(poses[earlier]) @ poses[later]
    drift = make_transform(rotation_from_euler_zyx(math.radians(3.0), 0.0, 0.0), [1.0, -0.8, 0.2])
    apart = float(np.linalg.norm(truth[:3, 3]))
    return (
        nodes,
        LoopCandidate(source, target, drift @ truth, float(path[later] - path[earlier]), apart),
        truth,
    )


def test_a_narrow_field_is_told_from_a_spinning_one(kitti_sample_root: Path, crossing) -> None:
    nodes, candidate, _ = crossing
    street = voxel_cloud(np.asarray(open_sequence("00", data_root=kitti_sample_root).frame(0)))
    assert azimuth_coverage(street) == 1.0
    assert azimuth_coverage(nodes[candidate.source].cloud) < 0.3
    members = submap_members(nodes, candidate.source, None, SETTINGS.submap_half_path_m)
    submap = submap_cloud(nodes, candidate.source, members, SETTINGS.submap_radius_m)
    assert azimuth_coverage(submap) > 0.9  # the streets driven before and after, seen from the node
    assert np.linalg.norm(submap[:, :2], axis=1).max() <= SETTINGS.submap_radius_m + 1e-3


@pytest.mark.filterwarnings("ignore::vcr_odom.errors.DataWarning")
def test_a_narrow_field_crossing_whose_submaps_hold_only_ground_is_degenerate(crossing, network) -> None:
    """The avenue's facades stand 23-38 m from the nodes: cropped to the submaps' 20 m, both visits'
    submaps are road, which holds neither position along it nor across. Whatever the fit, it measured
    no place, and it is turned away by name instead of pinning the map where the start left it."""
    nodes, candidate, _ = crossing
    decision = verify_candidate(network, nodes, candidate)
    assert decision.scores.submaps and decision.to_dict()["submaps"] is True
    assert decision.check == "degenerate" and not decision.accepted
    assert decision.scores.weakest_share < SETTINGS.min_normal_share / 10


@pytest.mark.filterwarnings("ignore::vcr_odom.errors.DataWarning")
def test_a_narrow_field_crossing_is_not_closed_by_its_single_scans(crossing, network) -> None:
    """Turned 94 deg, the two visits' 70 deg scans share no point: registered as they are, no fit."""
    nodes, candidate, _ = crossing
    scans_only = SETTINGS.with_changes(narrow_field_coverage=1e-6)  # no node counts as narrow
    single = verify_candidate(network, nodes, candidate, scans_only)
    assert not single.accepted and not single.scores.submaps


def test_submaps_with_nothing_near_the_node_are_rejected_by_name(network) -> None:
    """A narrow field that saw only far walls (every point beyond the submaps' 20 m) has nothing to register."""
    rng = np.random.default_rng(0)
    azimuth = rng.uniform(-0.5, 0.5, 400)
    far = np.column_stack([40 * np.cos(azimuth), 40 * np.sin(azimuth), rng.uniform(0, 5, 400)]).astype(
        np.float32
    )
    turned = make_transform(rotation_from_euler_zyx(math.radians(90.0), 0.0, 0.0), [0.0, 0.0, 0.0])
    nodes = [Node(0, 0, np.eye(4), 0.0, far), Node(1, 100, turned, 200.0, far)]
    candidate = LoopCandidate(1, 0, turned, 200.0, 0.0)
    decision = verify_candidate(network, nodes, candidate)
    assert not decision.accepted and decision.check == "points"
    assert decision.reason == "rejected: too few points to register"
    assert decision.to_dict()["failed_check"] == "points"


@pytest.fixture(scope="module")
def folded_street() -> tuple[list[Node], LoopCandidate]:
    """An Avia drive 36 m down a straight street whose odometry believes it drove 18 m out and back:
    the last node is placed on the first, turned round, though truly 36 m on (what a collapsed
    odometry makes of a walk)."""
    drive = SynthSequence(frames=80, seed=5, sensor=SensorConfig.model("avia"))
    poses = drive.world_poses
    path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))])
    length = 12 * NODE_SPACING_M
    turned = make_transform(rotation_from_euler_zyx(math.pi, 0.0, 0.0), [0.0, 0.0, 0.0])
    nodes: list[Node] = []
    for step in range(13):
        travelled = step * NODE_SPACING_M
        frame = int(np.argmin(np.abs(path - travelled)))
        believed = int(np.argmin(np.abs(path - min(travelled, length - travelled))))
        pose = poses[believed] if travelled <= length / 2 else poses[believed] @ turned
        nodes.append(Node(frame, frame, pose, travelled, voxel_cloud(drive.frame(frame))))
    prior = invert(nodes[0].pose) @ nodes[-1].pose
    return nodes, LoopCandidate(len(nodes) - 1, 0, prior, length, float(np.linalg.norm(prior[:3, 3])))


def test_submaps_of_two_visits_share_no_node(folded_street) -> None:
    nodes, candidate = folded_street
    half = SETTINGS.submap_half_path_m
    source = submap_members(nodes, candidate.source, candidate.target, half)
    target = submap_members(nodes, candidate.target, candidate.source, half)
    assert candidate.source in source and candidate.target in target
    assert not set(source) & set(target)
    halfway = len(nodes) // 2  # equally near both: in neither
    assert set(source) | set(target) == set(range(len(nodes))) - {halfway}
    alone = submap_members(nodes, candidate.source, None, half)  # no other visit: the whole half path
    assert set(alone) == {k for k, node in enumerate(nodes) if node.path_m >= nodes[-1].path_m - half}


@pytest.mark.filterwarnings("ignore::vcr_odom.errors.DataWarning")
def test_a_collapsed_odometry_does_not_confirm_itself_through_shared_submaps(folded_street, network) -> None:
    """Submaps sharing the nodes between the visits fit each other wherever the odometry put them:
    this candidate, 36 m apart, was accepted with a correction of a few centimetres."""
    nodes, candidate = folded_street
    decision = verify_candidate(network, nodes, candidate, sigma_m=2.0, sigma_deg=5.0)
    assert decision.scores.submaps
    assert not decision.accepted, decision.scores


@pytest.mark.filterwarnings("ignore::vcr_odom.errors.DataWarning")
def test_a_look_alike_the_network_finds_beyond_the_odometry_is_no_loop(
    crossing, network, monkeypatch
) -> None:
    """Submaps: the network's start ends on a fit 20 m along the street (a look-alike stretch, beyond the
    odometry's uncertainty) that overlaps better than the one the odometry's starts end on within it.
    The fit within is the candidate the odometry allows, but the place has two answers: ambiguous."""
    nodes, candidate, _ = crossing
    information = np.diag([1e4] * 3 + [400.0] * 3)
    within = verify.Fit(candidate.prior, 0.61, 0.45, information, 0.2)
    beyond = verify.Fit(
        candidate.prior @ make_transform(np.eye(3), [20.0, 0.0, 0.0]), 0.72, 0.45, information, 0.2
    )
    calls = iter([beyond])  # the network's start is polished first, then the odometry's
    monkeypatch.setattr(verify, "polish", lambda *args: next(calls, within))
    decision = verify_candidate(network, nodes, candidate)
    assert decision.scores.submaps and decision.scores.start == "odometry", decision.scores
    assert not decision.accepted and decision.check == "ambiguous", decision.reason
    assert decision.scores.starts_apart_m == pytest.approx(20.0)


@pytest.mark.filterwarnings("ignore::vcr_odom.errors.DataWarning")
@pytest.mark.parametrize(("fitness", "accepted"), [(0.45, True), (0.35, False)])
def test_a_narrow_field_fit_needs_less_overlap_than_a_spinning_one(
    crossing, network, monkeypatch, fitness: float, accepted: bool
) -> None:
    """Two visits of a narrow field see the place from view cones that overlap in part: 0.4 is
    enough there (a spinning sensor's fits need 0.5: tests/test_loops.py)."""
    nodes, candidate, _ = crossing
    fit = verify.Fit(candidate.prior, fitness, 0.45, np.diag([1e4] * 3 + [400.0] * 3), 0.2)
    monkeypatch.setattr(verify, "polish", lambda *args: fit)
    decision = verify_candidate(network, nodes, candidate)
    assert decision.accepted is accepted, decision.reason
    if not accepted:
        assert decision.check == "overlap" and decision.reason == "rejected: overlap 0.35 < 0.4"
