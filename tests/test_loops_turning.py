"""A heading drifts with each turn the odometry measures: a handheld walk round a courtyard turns
700-900 deg a lap (the lap and the looks about), and its odometry's heading comes back 16-22 deg off.
The drift bound and the pose graph's odometry sigmas grow with the angle turned, so such a walk keeps
its right loops; a car, which turns little per metre, keeps its bounds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcr_odom.geometry import invert, make_transform, rotation_from_euler_zyx
from vcr_odom.loops.drift import DriftModel
from vcr_odom.loops.graph import LoopEdge, optimise
from vcr_odom.loops.nodes import Node, NodeRecorder

LOOP_INFORMATION = np.diag([math.radians(0.2) ** -2] * 3 + [0.05**-2] * 3)  # 0.2 deg, 5 cm


def test_the_heading_bound_grows_with_the_angle_turned() -> None:
    drift = DriftModel()
    lap_of_a_courtyard = drift.rotation_bound_deg(60.0, turned_deg=800.0)
    assert drift.rotation_bound_deg(60.0) == pytest.approx(11.0)  # by the path alone
    assert lap_of_a_courtyard == pytest.approx(5.0 + 6.0 + 16.0)
    assert lap_of_a_courtyard > 22.0  # walk 881's right loops asked for 16-22 deg
    assert drift.rotation_bound_deg(60.0, turned_deg=5000.0) == drift.rotation_cap_deg
    car_corner = drift.rotation_bound_deg(100.0, turned_deg=90.0) - drift.rotation_bound_deg(100.0)
    assert car_corner == pytest.approx(1.8)
    walker, car = drift.step_sigmas(3.0, turned_deg=60.0), drift.step_sigmas(3.0, turned_deg=0.0)
    assert walker[0] == car[0] and walker[1] > car[1]  # the graph's heading sigma too


def test_nodes_count_every_turn_even_one_turned_back() -> None:
    """A look to the side and back turns the sensor twice its angle and leaves the heading where it
    was: the drift it gathers counts both turns."""
    recorder = NodeRecorder()
    points = np.random.default_rng(0).uniform(-20.0, 20.0, (4000, 4)).astype(np.float32)
    yaws = [0.0, 30.0, 60.0, 30.0, 0.0, 0.0]  # deg: out 60 and back
    for k, yaw in enumerate(yaws):
        recorder(k, make_transform(rotation_from_euler_zyx(math.radians(yaw), 0, 0), [0.1 * k, 0, 0]), points)
    nodes = recorder.finish()
    assert nodes[0].turned_deg == 0.0
    assert nodes[-1].turned_deg == pytest.approx(120.0, abs=1e-6)


def _courtyard_walk(error_per_turned: float) -> tuple[list, list, list]:
    """A walk of 1.75 laps round a 55 m loop, one node a step, looking about (60 deg out and back)
    on a stretch of the first lap only, and its odometry, which leaves ``error_per_turned`` of every
    turn in its heading, the same way whichever way it turned (the looks add drift, not heading)."""
    count = 80
    truth, odometry, positions, turned = [np.eye(4)], [np.eye(4)], [0], [0.0]
    look = [0.0, 20.0, 40.0, 60.0, 40.0, 20.0, 0.0]
    for k in range(count + 60):
        looking = 20 <= k < 20 + 4 * len(look)
        yaw = 360.0 / count + (look[(k + 1) % len(look)] - look[k % len(look)] if looking else 0.0)
        step = make_transform(rotation_from_euler_zyx(math.radians(yaw), 0, 0), [55.0 / count, 0, 0])
        off = make_transform(
            rotation_from_euler_zyx(math.radians(abs(yaw) * error_per_turned), 0, 0), [0, 0, 0]
        )
        truth.append(truth[-1] @ step)
        odometry.append(odometry[-1] @ step @ off)
        positions.append(10 * (k + 1))
        turned.append(turned[-1] + abs(yaw) * (1 + error_per_turned))
    return truth, odometry, [positions, turned]


def _walk_nodes(odometry: list, positions: list, turned: list) -> list:
    path = np.concatenate([[0.0], np.cumsum([55.0 / 80] * (len(odometry) - 1))])
    return [
        Node(
            position=p, frame_index=p, pose=pose, path_m=float(s), turned_deg=t,
            cloud=np.zeros((0, 3), np.float32),
        )
        for p, pose, s, t in zip(positions, odometry, path, turned, strict=True)
    ]  # fmt: skip


def _rms_error(poses: list, truth: list) -> float:
    return float(
        np.sqrt(np.mean([np.sum((p[:3, 3] - t[:3, 3]) ** 2) for p, t in zip(poses, truth, strict=True)]))
    )


def test_the_graph_bends_a_walk_where_it_turned() -> None:
    """Odometry leaving 2 % of every turn in its heading (15 deg after a lap of a courtyard, as walk
    881's 16 deg): with the turning in the odometry's heading sigmas, the graph puts the correction
    where the walk looked about, and ends nearer the truth than a graph whose sigmas know only the
    path (0.46 against 0.56 m here), every right loop kept."""
    truth, odometry, (positions, turned) = _courtyard_walk(0.02)
    nodes = _walk_nodes(odometry, positions, turned)
    loops = [
        LoopEdge(j, j - 80, invert(truth[j - 80]) @ truth[j], LOOP_INFORMATION) for j in (80, 88, 98, 130)
    ]
    knows_turns = optimise(nodes, loops, DriftModel())
    path_only = optimise(nodes, loops, DriftModel(step_sigma_per_turned=0.0))
    assert all(knows_turns.kept)
    assert _rms_error(knows_turns.node_poses, truth) < 0.25 * _rms_error(odometry, truth)
    assert _rms_error(knows_turns.node_poses, truth) < 0.9 * _rms_error(path_only.node_poses, truth)
