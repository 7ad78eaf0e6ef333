"""Loop closure: candidates, verification on real scans, the robust pose graph, the map command."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from vcr_odom.cli.main import cli
from vcr_odom.geometry import invert, make_transform, rotation_angle, rotation_from_euler_zyx
from vcr_odom.loops.candidates import find_candidates
from vcr_odom.loops.drift import DriftModel
from vcr_odom.loops.graph import LoopEdge, correct_frames, optimise
from vcr_odom.loops.nodes import Node
from vcr_odom.loops.odometry_doubts import OdometryDoubts

EXACT = np.diag([1e6] * 3 + [1e4] * 3)  # a loop measured to 1 mrad and 1 cm


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


def test_candidates_are_revisits_within_the_drift_and_none_on_a_street() -> None:
    truth, odometry = _circle(60, 40.0, heading_drift_deg_per_node=0.05)
    candidates = find_candidates(_nodes(odometry))
    assert candidates, "a lap and a quarter revisits the start"
    true_distances = []
    for candidate in candidates:
        assert candidate.source > 60 - 5 and candidate.target < candidate.source - 40
        true_distances.append(np.linalg.norm(truth[candidate.source][:3, 3] - truth[candidate.target][:3, 3]))
        assert true_distances[-1] < 5.0 + DriftModel().translation_bound(candidate.path_m)
    assert min(true_distances) < 5.0
    street = [make_transform(np.eye(3), [3.0 * k, 0, 0]) for k in range(200)]
    assert find_candidates(_nodes(street)) == []


def test_a_crossing_is_attempted_at_the_node_nearest_the_earlier_street() -> None:
    """A street crossed at 90 deg after a detour: the drift bound admits nodes 10-20 m short of the
    crossing, and the one attempt must not be spent there but at the crossing itself."""
    east = [make_transform(np.eye(3), [3.0 * k - 60.0, 0, 0]) for k in range(41)]  # x -60..60 along y=0
    north = rotation_from_euler_zyx(math.pi / 2, 0, 0)
    detour = [make_transform(np.eye(3), [60.0, 3.0 * k, 0]) for k in range(1, 11)]  # up to y=30
    back = [make_transform(np.eye(3), [60.0 - 3.0 * k, 30.0, 0]) for k in range(1, 21)]  # west to x=0
    south = [make_transform(north.T, [1.0, 30.0 - 3.0 * k, 0]) for k in range(20)]  # down x=1, y=0 at k=10
    nodes = _nodes(east + detour + back + south)
    candidates = find_candidates(nodes)
    crossing = [c for c in candidates if c.source > len(east) + len(detour) + len(back)]
    assert crossing, "the southbound street crosses the first one"
    nearest = min(crossing, key=lambda c: c.distance_m)
    assert nearest.distance_m < 1.5  # (1, 0) against (0, 0): the crossing itself; first come, 3 m short
    sources = [c.source for c in crossing]
    assert len(sources) == len(set(sources))
    gaps = np.diff(sorted(nodes[j].path_m for j in sources))
    assert (gaps >= 6.0).all(), "attempts stay one every 6 m of path"


def test_a_long_passage_is_attempted_at_most_twenty_times_and_a_short_one_every_6_m() -> None:
    """A return along the same street, a lane apart: every node of the way back revisits, and a
    registration every 6 m would be ~50 of them on 300 m; 20 spread over the passage pin it."""

    def out_and_back(length_m: float) -> list[Node]:
        count = int(length_m / 3.0)
        out = [make_transform(np.eye(3), [3.0 * k, 0, 0]) for k in range(count + 1)]
        back = [make_transform(np.eye(3), [3.0 * k, 3.5, 0]) for k in range(count, -1, -1)]
        return _nodes(out + back)

    for length_m, expected_spacing in ((300.0, 13.5), (90.0, 6.0)):
        nodes = out_and_back(length_m)
        candidates = find_candidates(nodes)
        path = sorted(nodes[c.source].path_m for c in candidates)
        passage_m = path[-1] - path[0]
        assert passage_m > 0.8 * length_m - 30, "the whole way back is attempted, end to end"
        assert np.diff(path).min() >= expected_spacing - 1e-9
        assert np.diff(path).max() <= 2 * expected_spacing + 3.0, "no stretch is left unattempted"
    assert 18 <= len(find_candidates(out_and_back(300.0))) <= 21
    assert len(find_candidates(out_and_back(300.0), max_passage_attempts=1000)) >= 40


def test_a_loop_pulls_a_drifted_circle_back_and_no_loop_changes_nothing() -> None:
    truth, odometry = _circle(60, 40.0, heading_drift_deg_per_node=0.1)
    nodes = _nodes(odometry)
    unchanged = optimise(nodes, [])
    assert np.array_equal(unchanged.node_poses, np.stack(odometry))
    loops = [LoopEdge(j, j - 60, invert(truth[j - 60]) @ truth[j], EXACT) for j in range(60, 76, 3)]
    result = optimise(nodes, loops)
    error_before = np.linalg.norm(odometry[-1][:3, 3] - truth[-1][:3, 3])
    error_after = np.linalg.norm(result.node_poses[-1][:3, 3] - truth[-1][:3, 3])
    assert error_before > 3.0
    assert error_after < error_before / 5
    assert all(result.kept)


def test_the_graph_drops_a_loop_that_disagrees_with_the_others() -> None:
    truth, odometry = _circle(60, 40.0, heading_drift_deg_per_node=0.05)
    nodes = _nodes(odometry)
    true_loops = [LoopEdge(j, j - 60, invert(truth[j - 60]) @ truth[j], EXACT) for j in range(60, 76, 3)]
    block_away = make_transform(np.eye(3), [30.0, 0, 0])  # a look-alike place one block further on
    false_loop = LoopEdge(70, 20, block_away @ invert(truth[20]) @ truth[70], EXACT)
    result = optimise(nodes, [*true_loops, false_loop])
    assert result.kept == [True] * len(true_loops) + [False]
    error = np.linalg.norm(result.node_poses[-1][:3, 3] - truth[-1][:3, 3])
    assert error < np.linalg.norm(odometry[-1][:3, 3] - truth[-1][:3, 3]) / 5


def test_a_walks_lone_loop_is_kept_where_its_two_starts_agreed() -> None:
    """A 60 m lap whose heading drifted 26 deg (1.3 deg a node, as the handheld Avia walks drift):
    the odometry's sigmas call the one right loop an outlier; corroborated by its two starts and
    with no other loop to weigh it against, it is kept and closes the lap."""
    truth, odometry = _circle(20, 9.0, heading_drift_deg_per_node=1.3)
    nodes = _nodes(odometry)
    measured = invert(truth[1]) @ truth[21]
    error_before = np.linalg.norm(odometry[21][:3, 3] - truth[21][:3, 3])
    doubted = optimise(nodes, [LoopEdge(21, 1, measured, EXACT)])
    assert doubted.kept == [False] and np.array_equal(doubted.node_poses, np.stack(odometry))
    kept = optimise(nodes, [LoopEdge(21, 1, measured, EXACT, corroborated=True)])
    assert kept.kept == [True] and kept.weights == [1.0] and kept.trusted == 1 and doubted.trusted == 0
    assert error_before > 3.0
    assert np.linalg.norm(kept.node_poses[21][:3, 3] - truth[21][:3, 3]) < 0.1


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


def test_drift_bounds_grow_with_the_path() -> None:
    drift = DriftModel()
    assert drift.translation_bound(0) == drift.translation_floor_m
    assert drift.translation_bound(1000) == pytest.approx(drift.translation_floor_m + 30.0)
    assert drift.translation_bound(200) < 30.0  # a block away is never within the drift of a short loop


def test_a_walkers_many_frames_count_as_path() -> None:
    """Drift grows with each registration: a walk at 10 Hz (0.13 m a frame) gathers a car's drift of
    three times its path; a car's frames (~1 m) leave the bound as its path makes it."""
    drift = DriftModel()
    walk = drift.translation_bound(280.0, frames=2200)
    assert walk == pytest.approx(drift.translation_floor_m + 0.03 * 2200 / 3)
    assert walk > 15.0  # handheld Avia walk 871's right loops asked for 13.4-15.3 m
    assert drift.translation_bound(600.0, frames=700) == drift.translation_bound(600.0)
    walker, car = drift.step_sigmas(3.0, frames=23), drift.step_sigmas(3.0, frames=3)  # the graph's too
    assert walker[0] > car[0] and walker[1] > car[1]
    assert drift.step_sigmas(3.0, frames=3) == drift.step_sigmas(3.0)


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


def _candidate(truth: np.ndarray, error: np.ndarray, path_m: float, frames: int = 0):
    from vcr_odom.loops.candidates import LoopCandidate

    prior = error @ truth
    return LoopCandidate(1, 0, prior, path_m, float(np.linalg.norm(prior[:3, 3])), frames)


def test_a_walk_that_drifted_14_m_in_280_m_closes_where_a_car_would_not(sample_nodes) -> None:
    """The same fit asks the odometry for 14 m after 280 m: within a 10 Hz walk's drift (2,200
    registrations), a look-alike for a car's (280)."""
    from vcr_odom.loops.verify import LoopVerifier
    from vcr_odom.registration.vcr import VcrRegistrar

    nodes, truth = sample_nodes
    drifted = make_transform(rotation_from_euler_zyx(math.radians(3), 0, 0), [11.0, -8.5, 0.5])
    verifier = LoopVerifier(VcrRegistrar(device="cpu"))
    walk = verifier.verify(_candidate(truth, drifted, 280.0, frames=2200), nodes)
    assert walk.accepted, walk.reason
    assert walk.scores["correction_m"] > 13.0
    assert np.linalg.norm((invert(truth) @ walk.measured)[:3, 3]) < 0.2
    car = verifier.verify(_candidate(truth, drifted, 280.0, frames=280), nodes)
    assert car.check == "drift_bound", car.reason


def test_a_revisit_is_registered_without_the_odometry_and_accepted(sample_nodes) -> None:
    from vcr_odom.loops.verify import LoopVerifier
    from vcr_odom.registration.vcr import VcrRegistrar

    nodes, truth = sample_nodes
    drifted = make_transform(rotation_from_euler_zyx(math.radians(4), 0, 0), [1.5, -1.0, 0.2])
    decision = LoopVerifier(VcrRegistrar(device="cpu")).verify(_candidate(truth, drifted, 150.0), nodes)
    assert decision.accepted, decision.reason
    assert decision.to_dict()["failed_check"] is None
    error = invert(truth) @ decision.measured
    assert np.linalg.norm(error[:3, 3]) < 0.2
    assert math.degrees(rotation_angle(error[:3, :3])) < 0.5
    assert decision.information is not None and np.all(np.linalg.eigvalsh(decision.information) > 0)
    # the network's start, 1.8 m from the odometry's, ends in the same fit
    assert decision.corroborated, decision.scores
    assert decision.to_dict()["corroborated"] is True


def test_starts_that_begin_together_corroborate_only_a_fit_that_faces_every_way(sample_nodes) -> None:
    """An odometry 0.4 m off: the network's start lands within a metre of it, so their ending in one
    fit says nothing a single start would not; the street's surfaces face every way, and that alone
    corroborates the fit."""
    from vcr_odom.loops.corroboration import CORROBORATING_STARTS_M, STRONG_SHARE, corroborated
    from vcr_odom.loops.verify import LoopVerifier
    from vcr_odom.registration.vcr import VcrRegistrar

    nodes, truth = sample_nodes
    close = make_transform(rotation_from_euler_zyx(math.radians(2), 0, 0), [0.3, -0.25, 0.0])
    decision = LoopVerifier(VcrRegistrar(device="cpu")).verify(_candidate(truth, close, 150.0), nodes)
    assert decision.accepted, decision.reason
    assert decision.scores["starts_before_m"] < CORROBORATING_STARTS_M
    assert decision.scores["weakest_share"] >= STRONG_SHARE
    assert decision.corroborated
    together = decision.scores | {"weakest_share": 0.04}  # a footpath's: one start could slide along it
    assert not corroborated(together, 0.5)
    converged = together | {
        "starts_before_m": 2.0,
        "starts_apart_m": 0.0,
        "other_start_fitness": together["fitness"],
    }
    assert corroborated(converged, 0.5)
    assert not corroborated(converged | {"weakest_share": 0.015}, 0.5)  # both slid along it


def test_starts_that_end_apart_on_surfaces_facing_one_way_are_ambiguous(sample_nodes, monkeypatch) -> None:
    """The odometry's start 14 m off ends 3 m from the network's fit at overlap 0.63 against 0.90:
    on the street, whose surfaces face every way, the better fit wins; were they to hardly face one
    way (a footpath seen end on: walk 971's false loop, 6.3 m off at overlaps 0.87 and 0.71), overlap
    says nothing along it and the candidate is ambiguous. Starts that end in one fit stay accepted."""
    from vcr_odom.loops import verify
    from vcr_odom.odometry.degeneracy import WEAK_AXIS_SHARE
    from vcr_odom.registration.vcr import VcrRegistrar

    nodes, truth = sample_nodes
    network = VcrRegistrar(device="cpu")
    far = _candidate(
        truth, make_transform(rotation_from_euler_zyx(math.radians(3), 0, 0), [11.0, -8.5, 0.5]), 280.0, 2200
    )
    near = _candidate(
        truth, make_transform(rotation_from_euler_zyx(math.radians(3), 0, 0), [8.0, 0.0, 0.0]), 280.0, 2200
    )
    street = verify.LoopVerifier(network).verify(far, nodes)
    assert street.accepted, street.reason
    scores = street.scores
    assert scores["starts_apart_m"] > 2.0 and scores["fitness"] - scores["other_start_fitness"] > 0.2
    assert scores["weakest_share"] >= WEAK_AXIS_SHARE
    monkeypatch.setattr(verify, "weakest_share", lambda target, fit: 0.001)
    footpath = verify.LoopVerifier(network).verify(far, nodes)
    assert footpath.check == "ambiguous" and "weakest share 0.001" in footpath.reason
    together = verify.LoopVerifier(network).verify(near, nodes)
    assert together.accepted and together.scores["starts_apart_m"] < 0.1, together.reason


def test_what_counts_as_two_fits_overlap_cannot_tell_apart() -> None:
    """Walk 971's false loop and the right loops whose fits hardly face one way (starts that ended
    together), or face every way (924: 11 m apart, overlaps 0.22 apart), or are submaps (no share)."""
    from vcr_odom.loops.verify import ambiguous

    walk_971 = {"starts_apart_m": 4.342, "weakest_share": 0.0025}
    assert ambiguous(walk_971, 0.158, 0.0, 1.0)
    assert not ambiguous({"starts_apart_m": 11.123, "weakest_share": 0.0304}, 0.224, 0.0, 1.0)
    assert not ambiguous({"starts_apart_m": 0.006, "weakest_share": 0.0057}, 0.002, 0.0, 1.0)
    assert ambiguous({"starts_apart_m": 0.2, "weakest_share": 0.003}, 0.3, 8.0, 1.0)  # turned apart
    submaps = {"starts_apart_m": 7.776}
    assert not ambiguous(submaps, 0.177, 0.0, 1.0) and ambiguous(submaps, 0.1, 0.0, 1.0)
    indoors = {"starts_apart_m": 0.8, "weakest_share": 0.003}  # a room's grid halves the distances
    assert ambiguous(indoors, 0.3, 0.0, 0.5) and not ambiguous(indoors, 0.3, 0.0, 1.0)


def test_a_look_alike_a_block_away_is_rejected_as_beyond_the_drift(sample_nodes) -> None:
    """The same two scans, but the odometry puts them 30 m apart after 60 m of driving: the fit is
    perfect, and only the drift bound can say that it is not this place."""
    from vcr_odom.loops.verify import LoopVerifier
    from vcr_odom.registration.vcr import VcrRegistrar

    nodes, truth = sample_nodes
    block = make_transform(np.eye(3), [30.0, 0.0, 0.0])
    decision = LoopVerifier(VcrRegistrar(device="cpu")).verify(_candidate(truth, block, 60.0), nodes)
    assert not decision.accepted
    assert decision.check in ("drift_bound", "overlap"), decision.reason
    assert decision.to_dict()["failed_check"] == decision.check  # loops.json names it


def test_a_spinning_sensor_fit_overlapping_under_half_is_rejected(sample_nodes, monkeypatch) -> None:
    """The overlap a narrow field gets away with (0.4: tests/test_loops_narrow_field.py) is not enough
    for a spinning sensor, whose two visits see all round."""
    from types import SimpleNamespace

    from vcr_odom.loops import verify
    from vcr_odom.registration.vcr import VcrRegistrar

    nodes, truth = sample_nodes
    candidate = _candidate(truth, np.eye(4), 150.0)
    fit = SimpleNamespace(
        fitness=0.45, inlier_rmse=0.45, transformation=truth, correspondence_set=np.zeros((0, 2))
    )
    monkeypatch.setattr(verify, "polish", lambda *args: fit)
    decision = verify.LoopVerifier(VcrRegistrar(device="cpu")).verify(candidate, nodes)
    assert decision.check == "overlap" and decision.reason == "rejected: overlap 0.45 < 0.5"


def _map(data_root: Path, results: Path):
    """``vcr-odom map`` on the small synthetic sequence 00, as a user runs it."""
    return CliRunner().invoke(
        cli, ["map", "--data-root", str(data_root), "--seq", "00", "--results-dir", str(results)]
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
    assert metrics["loops"]["ground_up"] == {"used": False}, "no loop: no graph, no up priors"
    assert metrics["loops"]["odometry_sigma_scale"] is None
    assert metrics["loops"]["odometry_heading_sigmas"] is None, "no loop: the odometry edges left as they are"
    assert metrics["loops"]["odometry_fit_sigmas"] is None
    assert metrics["loops"]["node_voxel_m"] == 1.0  # a street: the nodes keep their 1 m grid
    assert metrics["odometry"]["ate_rpe"] == metrics["ate_rpe"]


def test_map_interrupted_after_the_odometry_keeps_the_odometry_marked_partial(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import vcr_odom.loops.pipeline as pipeline

    def ctrl_c(*_args: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(pipeline, "_map_from_nodes", ctrl_c)
    result = _map(small_synthetic_root, tmp_path)
    assert result.exit_code == 130, result.output
    (folder,) = [p for p in tmp_path.iterdir() if p.name.startswith("20")]
    marker = json.loads((folder / "result.json").read_text())
    assert marker["status"] == "partial" and marker["frames_done"] == 8
    assert "interrupted" in marker["reason"].lower()
    assert len(np.loadtxt(folder / "trajectory_kitti.txt")) == 8
    assert not (folder / "map.ply").exists()


def test_map_hands_what_the_odometry_doubted_to_the_loop_phase(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Submaps are judged by where the odometry doubted itself (verify.MAX_SUBMAP_FLAGGED) and the graph
    weighs its edges by the frames' fits: map must pass both on, not empty records."""
    import vcr_odom.loops.pipeline as pipeline

    run_odometry, close_loops = pipeline.run_odometry, pipeline.close_loops
    handed: list[OdometryDoubts] = []

    def one_flagged(*args: object, **kwargs: object):
        run = run_odometry(*args, **kwargs)
        run.per_frame_info[3] |= {"flagged": True, "reason": "a test's implausible motion"}
        return run

    def recorded(*args: object, **kwargs: object):
        handed.append(args[5])
        return close_loops(*args, **kwargs)

    monkeypatch.setattr(pipeline, "run_odometry", one_flagged)
    monkeypatch.setattr(pipeline, "close_loops", recorded)
    result = _map(small_synthetic_root, tmp_path)
    assert result.exit_code == 0, result.output
    (doubts,) = handed
    assert doubts.flagged_frames == (3,)
    assert sorted(doubts.fits) == list(range(1, 8)), "each pair's prior fit, from the second frame on"


def test_map_says_how_many_candidates_the_drift_bound_doubted_submaps_and_graph_turned_away(
    small_synthetic_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The console names the rejections a user can act on or should know of: fits beyond the drift
    bound (raise the options), submaps across frames the odometry doubted (its picture is bent) and
    verified loops the pose graph dropped (why the accepted count is lower than the fits)."""
    import vcr_odom.loops.pipeline as pipeline
    from vcr_odom.loops.verify import LoopDecision

    close_loops = pipeline.close_loops

    def with_rejections(*args: object, **kwargs: object):
        closed = close_loops(*args, **kwargs)
        candidate = _candidate(np.eye(4), np.eye(4), 50.0)
        closed.decisions += [
            LoopDecision(candidate, 5, 0, check="drift_bound"),
            LoopDecision(candidate, 6, 0, check="doubted_submap"),
            LoopDecision(candidate, 7, 0, check="doubted_submap"),
            LoopDecision(candidate, 8, 0, check="graph"),
        ]
        return closed

    monkeypatch.setattr(pipeline, "close_loops", with_rejections)
    result = _map(small_synthetic_root, tmp_path)
    assert result.exit_code == 0, result.output
    output = " ".join(result.output.split())
    assert "4 loop candidate(s), 0 accepted" in output
    assert "1 candidate(s) fit but asked the odometry for more than its drift bound" in output
    assert "2 candidate(s) not registered: the odometry replaced implausible motions" in output
    assert "doubted_submap" in output
    assert "1 candidate(s) passed every check but the pose graph dropped them" in output


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
    assert result.exit_code != 0
    (folder,) = [p for p in tmp_path.iterdir() if p.name.startswith("20")]
    marker = json.loads((folder / "result.json").read_text())
    assert marker["status"] == "partial" and "while writing the map" in marker["reason"]
    assert len(np.loadtxt(folder / "trajectory_kitti.txt")) == 8
    assert not (folder / "map.ply").exists() and not (folder / "loops.json").exists()


def test_a_node_with_an_empty_scan_is_rejected_not_an_error(sample_nodes) -> None:
    import dataclasses

    from vcr_odom.loops.verify import LoopVerifier
    from vcr_odom.registration.vcr import VcrRegistrar

    nodes, truth = sample_nodes
    empty = [nodes[0], dataclasses.replace(nodes[1], cloud=np.zeros((0, 3), np.float32))]
    decision = LoopVerifier(VcrRegistrar(device="cpu")).verify(_candidate(truth, np.eye(4), 60.0), empty)
    assert not decision.accepted and decision.reason.startswith("rejected: too few points")


def test_the_loop_network_shares_the_odometrys_weights_with_its_own_passes(
    small_synthetic_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A VCR-based odometry's network is loaded once and shared with the loop closure, which runs the
    weights' own number of passes; a non-VCR odometry's loops load their own network; and run's
    --save-map, which map would ignore, is refused by name."""
    from vcr_odom.data.selection import FrameSelection
    from vcr_odom.errors import ConfigError
    from vcr_odom.loops.pipeline import MapSettings, loop_network
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


@pytest.mark.parametrize(("option", "value"), [("--max-drift", "0"), ("--max-heading-drift", "-3")])
def test_map_rejects_a_drift_bound_that_is_not_positive(
    small_synthetic_root: Path, tmp_path: Path, option: str, value: str
) -> None:
    args = ["map", "--data-root", str(small_synthetic_root), "--seq", "00", "--results-dir", str(tmp_path)]
    result = CliRunner().invoke(cli, [*args, option, value])
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
    """metrics.json's by_outcome and the drift-bound count read the decision's check, in the order tried."""
    from vcr_odom.loops.pipeline import _loop_summary
    from vcr_odom.loops.verify import LoopDecision

    candidate = _candidate(np.eye(4), np.eye(4), 50.0)
    checks = ["drift_bound", "", "overlap", "drift_bound", "graph", ""]
    decisions = [LoopDecision(candidate, 1, 0, accepted=not c, check=c) for c in checks]
    summary = _loop_summary(decisions)
    assert summary["by_outcome"] == {"accepted": 2, "overlap": 1, "drift_bound": 2, "graph": 1}
    assert list(summary["by_outcome"]) == ["accepted", "overlap", "drift_bound", "graph"]
    assert summary["beyond_drift_bound"] == 2 and summary["accepted"] == 2


def test_a_dropped_loop_is_told_what_it_disagreed_with() -> None:
    """A lone loop the rounds drop disagreed with the odometry; there are no other loops to blame."""
    from vcr_odom.loops.pipeline import dropped_reason

    assert dropped_reason(None, 0.43, 1) == "dropped: disagrees with the odometry (graph weight 0.43)"
    assert dropped_reason(None, 0.04, 3) == (
        "dropped: disagrees with the odometry and the 2 other loop(s) (graph weight 0.04)"
    )
    assert dropped_reason((3, 4), 0.0, 5) == "dropped: 3 of its 4 cycles with the loops near it do not close"
    assert dropped_reason((2, 2), 0.0, 3) == (
        "dropped: its cycles with the two loops near it do not close, while theirs does"
    )


def test_the_loop_phase_estimates_each_nodes_normals_once(sample_nodes, monkeypatch) -> None:
    """The verification, the heading support and the walls' up all read a node's normals: estimated
    once and shared (up to three times was 10-15 % of drive 802's loop phase), the same a fresh
    estimate gives."""
    from collections import Counter

    from vcr_odom.loops import heading_support, verify, walls
    from vcr_odom.loops import nodes as node_module
    from vcr_odom.loops.graph import LoopEdge
    from vcr_odom.loops.nodes import NodeNormals, normal_cloud
    from vcr_odom.registration.vcr import VcrRegistrar

    nodes, truth = sample_nodes
    fresh = np.asarray(normal_cloud(nodes[0].cloud, nodes[0].cloud_voxel).normals)
    estimated: Counter[bytes] = Counter()

    def counted(points: np.ndarray, voxel: float):
        estimated[points.tobytes()] += 1
        return normal_cloud(points, voxel)

    for module in (node_module, verify, walls, heading_support):
        monkeypatch.setattr(module, "normal_cloud", counted)
    normals = NodeNormals(nodes)
    drifted = make_transform(rotation_from_euler_zyx(math.radians(4), 0, 0), [1.5, -1.0, 0.2])
    decision = verify.LoopVerifier(VcrRegistrar(device="cpu"), normals=normals).verify(
        _candidate(truth, drifted, 150.0), nodes
    )
    assert decision.accepted, decision.reason
    edge = LoopEdge(1, 0, decision.measured, decision.information)
    optimise(nodes, [edge], normals=normals)
    assert set(estimated) == {node.cloud.tobytes() for node in nodes}
    assert set(estimated.values()) == {1}, "a node's normals estimated more than once"
    assert np.array_equal(np.asarray(normals.cloud(0).normals), fresh)
