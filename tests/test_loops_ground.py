"""The ground's up direction in the pose graph: measured in a scan, and holding a tilt that drifted
between loops, which the loops alone leave in place."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from vcr_odom.geometry import invert, make_transform, rotation_from_euler_zyx
from vcr_odom.loops.graph import LoopEdge, optimise
from vcr_odom.loops.gravity import UpPriors, up_priors
from vcr_odom.loops.nodes import Node, NodeNormals
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.loops.verify import odometry_information
from vcr_odom.preprocess import ground_normal

EXACT = np.diag([1e4] * 3 + [1e2] * 3)
ODOMETRY = np.diag([math.radians(0.5) ** -2] * 3 + [0.1**-2] * 3)
"""Each odometry edge's information: half a degree and 10 cm (a loose odometry, as drifted here)."""


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


def solve(nodes: list[Node], loops: list[LoopEdge], up: UpPriors | None = None) -> np.ndarray:
    """The pose graph of ``nodes`` (the odometry's poses, every edge :data:`ODOMETRY`) with ``loops``."""
    poses = np.stack([node.pose for node in nodes])
    return optimise(poses, [ODOMETRY] * (len(nodes) - 1), loops, up)


def priors(nodes: list[Node], **settings: object) -> UpPriors:
    return up_priors(nodes, NodeNormals(nodes), LoopSettings(**settings))


def test_a_tilt_that_drifted_between_loops_is_held_by_the_ground_and_loops_alone_leave_it() -> None:
    truth, odometry = _lap(pitch_drift_deg_per_node=0.5)
    nodes = _nodes(odometry)
    up = priors(nodes)
    assert up.measured_by == "ground" and len(up.edges) == len(nodes) - 1
    assert up.to_dict()["used"] and up.to_dict()["priors"] == len(nodes) - 1
    tilts = [math.degrees(math.acos(min(1.0, pose[2, 2]))) for pose in odometry]  # against level
    assert up.tilt_p90_deg == pytest.approx(np.percentile(tilts, 90), abs=0.5)
    loops_only = solve(nodes, _loops(truth))
    before = _worst_height_error(loops_only, truth)
    assert before > 2.5, "the loops close the lap but leave its middle tilted"
    assert _worst_height_error(solve(nodes, _loops(truth), up), truth) < before / 2
    assert priors(nodes, ground_up=False).edges == [], "--no-ground-up"


def test_the_ground_is_left_out_where_the_odometrys_tilt_agrees_with_it() -> None:
    truth, odometry = _lap(pitch_drift_deg_per_node=0.0)
    nodes = _nodes(odometry)
    up = priors(nodes)
    assert up.edges == [] and up.tilt_p90_deg is not None and up.tilt_p90_deg < 0.01
    assert not up.to_dict()["used"]
    assert np.array_equal(solve(nodes, _loops(truth), up), solve(nodes, _loops(truth)))


def test_without_a_loop_the_odometry_is_untouched_whatever_the_ground_says() -> None:
    """The ground's up acts only with loops: where no loop is kept (a look-alike turned away), the
    map is the odometry, as `map` reports no loop."""
    _, odometry = _lap(pitch_drift_deg_per_node=0.5)
    nodes = _nodes(odometry)
    up = priors(nodes)
    assert up.edges, "the ground disagrees with the odometry's tilt"
    assert solve(nodes, [], up).tolist() == np.stack(odometry).tolist()


def test_an_edge_whose_scans_measured_nothing_does_not_free_the_drive_beyond_the_last_loop() -> None:
    """Past the last loop only the up priors and the odometry edges hold the nodes. An edge whose two
    clouds share nothing would leave them free in heading and position (the priors hold tilt only):
    the solve flung them tens of metres. Each edge also holds its motion to the nodes' own spacing
    (:func:`~vcr_odom.loops.verify.odometry_information`), so the rest stays where the odometry put it."""
    truth, odometry = _lap(pitch_drift_deg_per_node=0.5)
    nodes = _nodes(odometry)
    up = priors(nodes)
    loops = [LoopEdge(j, j - 60, invert(truth[j - 60]) @ truth[j], EXACT) for j in (60, 63, 66)]
    poses = np.stack([node.pose for node in nodes])
    unbroken = optimise(poses, [ODOMETRY] * (len(nodes) - 1), loops, up)
    settings = LoopSettings()
    spacing = np.diag([math.radians(settings.node_angle_deg) ** -2] * 3 + [settings.node_spacing_m**-2] * 3)
    blind_clouds = [
        Node(0, 0, np.eye(4), 0.0, np.zeros((0, 3), np.float32)),
        Node(1, 1, make_transform(np.eye(3), [3.0, 0.0, 0.0]), 3.0, np.zeros((0, 3), np.float32)),
    ]
    (measured_nothing,) = odometry_information(blind_clouds, NodeNormals(blind_clouds), settings)
    assert np.allclose(measured_nothing, spacing), "no correspondence: the edge holds its spacing only"
    tail = slice(71, None)
    for blind, worst_m in ((np.zeros((6, 6)), None), (measured_nothing, 0.5)):
        informations = [ODOMETRY] * (len(nodes) - 1)
        informations[70] = blind
        moved = np.abs(optimise(poses, informations, loops, up)[tail, :3, 3] - unbroken[tail, :3, 3]).max()
        if worst_m is None:
            assert moved > 10.0, "the failure this guards against: a free edge lets the tail go"
        else:
            assert moved < worst_m
