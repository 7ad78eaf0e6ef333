"""The ground's up direction in the pose graph: measured in a scan, and holding a tilt that drifted
between loops, which the loops alone leave in place."""

from __future__ import annotations

import itertools
import math

import numpy as np

from vcr_odom.geometry import invert, make_transform, rotation_from_euler_zyx
from vcr_odom.loops.graph import LoopEdge, optimise
from vcr_odom.loops.ground import ground_normal
from vcr_odom.loops.nodes import Node

EXACT = np.diag([1e4] * 3 + [1e2] * 3)


def _street_scan(tilt_deg: float, seed: int = 0) -> np.ndarray:
    """A sensor 1.7 m above a road tilted by ``tilt_deg`` about x, with building walls and poles."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-25, 25, size=(6000, 2))
    slope = math.tan(math.radians(tilt_deg))
    road = np.column_stack([xy, -1.7 + slope * xy[:, 1] + rng.normal(0, 0.02, len(xy))])
    wall_x = rng.uniform(-25, 25, 3000)
    walls = np.column_stack([wall_x, np.where(rng.random(3000) < 0.5, -8.0, 8.0), rng.uniform(-1.5, 6, 3000)])
    poles = np.column_stack(
        [rng.choice([-10.0, 0.0, 10.0], 600), np.full(600, 5.0), rng.uniform(-1.6, 3, 600)]
    )
    return np.concatenate([road, walls, poles]).astype(np.float32)


def test_the_ground_normal_of_a_sloping_street_is_measured_and_a_wall_alone_is_not_ground() -> None:
    for tilt in (0.0, 4.0):
        normal = ground_normal(_street_scan(tilt))
        assert normal is not None
        truth = np.array([0.0, -math.sin(math.radians(tilt)), math.cos(math.radians(tilt))])
        assert math.degrees(math.acos(min(1.0, float(normal @ truth)))) < 0.3
    rng = np.random.default_rng(1)
    wall = np.column_stack([rng.uniform(1, 20, 3000), np.full(3000, 4.0), rng.uniform(-1, 5, 3000)])
    assert ground_normal(wall.astype(np.float32)) is None
    assert ground_normal(np.zeros((5, 4), np.float32)) is None


def _lap(pitch_drift_deg_per_node: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """A level lap and a quarter of 40 m radius, and odometry whose pitch drifts at every node."""
    count, radius = 60, 40.0
    step_t = [2 * math.pi * radius / count, 0, 0]
    step = make_transform(rotation_from_euler_zyx(2 * math.pi / count, 0, 0), step_t)
    drifted = make_transform(
        rotation_from_euler_zyx(2 * math.pi / count, math.radians(pitch_drift_deg_per_node), 0), step_t
    )
    truth, odometry = [np.eye(4)], [np.eye(4)]
    for _ in range(count + count // 4):
        truth.append(truth[-1] @ step)
        odometry.append(odometry[-1] @ drifted)
    return truth, odometry


def _nodes(poses: list[np.ndarray]) -> list[Node]:
    """Nodes whose scans saw level ground (up is the body's z: the true lap is level)."""
    path = np.concatenate(
        [[0.0], np.cumsum([np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in itertools.pairwise(poses)])]
    )
    return [
        Node(k, k, pose, float(path[k]), np.zeros((0, 3), np.float32), ground=np.array([0.0, 0.0, 1.0]))
        for k, pose in enumerate(poses)
    ]


def _loops(truth: list[np.ndarray]) -> list[LoopEdge]:
    return [LoopEdge(j, j - 60, invert(truth[j - 60]) @ truth[j], EXACT) for j in range(60, 76, 3)]


def _worst_height_error(poses: np.ndarray, truth: list[np.ndarray]) -> float:
    return float(np.abs(poses[:, 2, 3] - np.stack(truth)[:, 2, 3]).max())


def test_a_tilt_that_drifted_between_loops_is_held_by_the_ground_and_loops_alone_leave_it() -> None:
    truth, odometry = _lap(pitch_drift_deg_per_node=0.5)
    nodes = _nodes(odometry)
    loops_only = optimise(nodes, _loops(truth), attitude_sigma_deg=0.0)
    with_ground = optimise(nodes, _loops(truth))
    assert with_ground.up is not None and len(with_ground.up.edges) == len(nodes) - 1
    assert with_ground.up_dropped == 0 and all(with_ground.kept)
    before = _worst_height_error(loops_only.node_poses, truth)
    assert before > 2.5, "the loops close the lap but leave its middle tilted"
    assert _worst_height_error(with_ground.node_poses, truth) < before / 2
    assert optimise(nodes, []).node_poses.tolist() == np.stack(odometry).tolist(), "no loop: untouched"


def test_the_ground_is_left_out_where_the_odometrys_tilt_agrees_with_it() -> None:
    truth, odometry = _lap(pitch_drift_deg_per_node=0.0)
    nodes = _nodes(odometry)
    result = optimise(nodes, _loops(truth))
    assert result.up is not None and result.up.edges == [] and result.up.tilt_p90_deg is not None
    assert result.up.tilt_p90_deg < 0.01
    assert np.array_equal(
        result.node_poses, optimise(nodes, _loops(truth), attitude_sigma_deg=0.0).node_poses
    )


def test_a_loop_the_rounds_drop_leaves_the_odometry_untouched_whatever_the_ground_says() -> None:
    """The ground's up acts only with loops: where the one verified loop is dropped (a look-alike a
    block away), the map is the odometry, as `map` reports no loop."""
    truth, odometry = _lap(pitch_drift_deg_per_node=0.5)
    nodes = _nodes(odometry)
    block_away = make_transform(np.eye(3), [30.0, 0, 0])
    false_loop = LoopEdge(70, 10, block_away @ invert(truth[10]) @ truth[70], EXACT)
    result = optimise(nodes, [false_loop])
    assert result.kept == [False]
    assert result.up is None and result.loop_share is None
    assert result.node_poses.tolist() == np.stack(odometry).tolist()
