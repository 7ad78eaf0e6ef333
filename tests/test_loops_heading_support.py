"""The pose graph's heading sigmas follow how well consecutive node clouds hold rotation: a loop's
correction goes where the odometry's heading was weakly held, not evenly round the lap."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcr_odom.geometry import invert, make_transform, rotation_from_euler_zyx
from vcr_odom.loops import graph
from vcr_odom.loops.graph import LoopEdge, optimise
from vcr_odom.loops.heading_support import MAX_SIGMA_FACTOR, heading_sigma_factors, rotation_information
from vcr_odom.loops.nodes import Node

EXACT = np.diag([1e6] * 3 + [1e4] * 3)


def _room(half_x: float = 8.0, half_y: float = 6.0, spacing: float = 0.4) -> np.ndarray:
    """The four walls and floor of a box room round the origin."""
    heights = np.arange(0.2, 3.0, spacing)
    xs, ys = np.arange(-half_x, half_x, spacing), np.arange(-half_y, half_y, spacing)
    walls = [np.stack(np.meshgrid([x], ys, heights), -1).reshape(-1, 3) for x in (-half_x, half_x)]
    walls += [np.stack(np.meshgrid(xs, [y], heights), -1).reshape(-1, 3) for y in (-half_y, half_y)]
    floor = np.stack(np.meshgrid(xs, ys, [-1.5]), -1).reshape(-1, 3)
    return np.concatenate([*walls, floor])


def _round_hall(radius: float = 8.0, spacing: float = 0.4) -> np.ndarray:
    """The wall and floor of a round hall round the origin: turning about its axis changes nothing."""
    angles = np.arange(0.0, 2 * math.pi, spacing / radius)
    heights = np.arange(0.2, 3.0, spacing)
    a, h = np.meshgrid(angles, heights)
    wall = np.stack([radius * np.cos(a), radius * np.sin(a), h], -1).reshape(-1, 3)
    xs = np.arange(-radius, radius, spacing)
    floor = np.stack(np.meshgrid(xs, xs, [-1.5]), -1).reshape(-1, 3)
    return np.concatenate([wall, floor[np.linalg.norm(floor[:, :2], axis=1) < radius]])


def _node(k: int, world: np.ndarray, x: float) -> Node:
    """A node ``x`` m along the x axis (odometry right) whose cloud is ``world`` seen from there."""
    pose = make_transform(np.eye(3), [x, 0.0, 0.0])
    cloud = (world - pose[:3, 3]).astype(np.float32)
    return Node(position=k, frame_index=k, pose=pose, path_m=x, cloud=cloud)


def test_a_round_hall_holds_no_heading_and_a_room_does() -> None:
    room = rotation_information(_node(1, _room(), 1.0), _node(0, _room(), 0.0))
    hall = rotation_information(_node(1, _round_hall(), 1.0), _node(0, _round_hall(), 0.0))
    assert room > 1.0
    assert hall < room / 1000


def test_only_the_edges_whose_clouds_hold_no_heading_are_loosened() -> None:
    rooms = [_node(k, _room(), 0.5 * k) for k in range(4)]
    halls = [_node(4 + k, _round_hall(), 0.5 * k) for k in range(2)]
    factors = heading_sigma_factors([*rooms, *halls])
    assert len(factors) == 5
    assert factors[:3] == pytest.approx([1.0, 1.0, 1.0])
    assert factors[4] > MAX_SIGMA_FACTOR / 2


def test_clouds_that_share_nothing_loosen_nothing_when_all_do() -> None:
    empty = [
        Node(position=k, frame_index=k, pose=np.eye(4), path_m=k, cloud=np.zeros((0, 3), np.float32))
        for k in range(4)
    ]
    assert heading_sigma_factors(empty) == pytest.approx([1.0, 1.0, 1.0])


def _lap_bent_at(edge: int, count: int = 40, radius: float = 20.0, bend_deg: float = 8.0):
    """True poses round a circle and odometry poses right everywhere but at one edge, where the heading
    is ``bend_deg`` off (a turn the scan matcher did not follow)."""
    step = make_transform(
        rotation_from_euler_zyx(2 * math.pi / count, 0, 0), [2 * math.pi * radius / count, 0, 0]
    )
    bent = make_transform(rotation_from_euler_zyx(math.radians(bend_deg), 0, 0), [0, 0, 0]) @ step
    truth, odometry = [np.eye(4)], [np.eye(4)]
    for k in range(count + count // 4):
        truth.append(truth[-1] @ step)
        odometry.append(odometry[-1] @ (bent if k == edge else step))
    path = [2 * math.pi * radius / count * k for k in range(len(truth))]
    nodes = [
        Node(position=k, frame_index=k, pose=pose, path_m=path[k], cloud=np.zeros((0, 3), np.float32))
        for k, pose in enumerate(odometry)
    ]
    loops = [
        LoopEdge(j, j - count, invert(truth[j - count]) @ truth[j], EXACT)
        for j in range(count, len(truth), 3)
    ]
    return truth, nodes, loops


def _error(result, truth) -> float:
    """RMS of the graph's node positions against the truth."""
    positions = np.array([p[:3, 3] for p in result.node_poses])
    return float(np.sqrt(np.mean(np.sum((positions - np.array([t[:3, 3] for t in truth])) ** 2, axis=1))))


def test_a_loop_corrects_the_edge_whose_heading_was_weakly_held(monkeypatch) -> None:
    truth, nodes, loops = _lap_bent_at(edge=12)

    even = optimise(nodes, loops)
    weak = np.ones(len(nodes) - 1)
    weak[12] = MAX_SIGMA_FACTOR
    monkeypatch.setattr(graph, "heading_sigma_factors", lambda *_: weak)
    located = optimise(nodes, loops)
    assert all(located.kept)
    assert _error(located, truth) < _error(even, truth) / 2
    assert located.heading_factors is weak


def test_a_loop_corrects_the_edge_whose_frames_fitted_poorly() -> None:
    """The odometry's own fit doubts (loops.odometry_doubts) loosen the final solve like the heading's."""
    truth, nodes, loops = _lap_bent_at(edge=12)

    even = optimise(nodes, loops)
    doubted = np.ones(len(nodes) - 1)
    doubted[12] = 10.0
    located = optimise(nodes, loops, fit_factors=doubted)
    assert all(located.kept) and located.kept == even.kept  # the rounds' verdicts stay the drift model's
    assert _error(located, truth) < _error(even, truth) / 2
    assert np.array_equal(located.fit_factors, doubted)
