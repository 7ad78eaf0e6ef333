"""The walls' up in the pose graph: measured in a node's cloud against the scene's own vertical, used
where walls are seen, and holding a drifted tilt where the ground would add a road's grade."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_loops_ground import _lap, _loops, _nodes, _worst_height_error, priors, solve

from vcr_odom.geometry import make_transform, rotation_from_euler_zyx
from vcr_odom.loops.gravity import WallsUp, _walls_reference, walls_up
from vcr_odom.loops.nodes import Node, normal_cloud, voxel_cloud


def walls_of(cloud: np.ndarray, voxel: float = 1.0) -> WallsUp | None:
    """:func:`walls_up` of a node cloud with its normals, as the loop phase estimates them."""
    return walls_up(cloud, np.asarray(normal_cloud(cloud, voxel).normals))


def _street(road_tilt_deg: float, seed: int = 0) -> np.ndarray:
    """A level sensor on a road tilted by ``road_tilt_deg`` about x, between two building fronts
    (normals +-y), their side walls (normals +-x, shorter) and a few trees (points in balls)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-30, 30, size=(8000, 2))
    road = np.column_stack([xy, -1.7 + math.tan(math.radians(road_tilt_deg)) * xy[:, 1]])
    fronts = np.column_stack(
        [rng.uniform(-30, 30, 6000), np.where(rng.random(6000) < 0.5, -9.0, 9.0), rng.uniform(-1.5, 8, 6000)]
    )
    sides = np.column_stack(
        [np.where(rng.random(2000) < 0.5, -12.0, 14.0), rng.uniform(9, 20, 2000), rng.uniform(-1.5, 8, 2000)]
    )
    crowns = rng.choice([-20.0, -5.0, 10.0, 25.0], 1500)
    ball = rng.normal(size=(1500, 3))
    ball = 2.0 * ball / np.linalg.norm(ball, axis=1, keepdims=True)
    trees = np.column_stack([crowns, np.full(1500, -6.0), np.full(1500, 3.0)]) + ball
    return np.concatenate([road, fronts, sides, trees]).astype(np.float32)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(min(1.0, abs(float(a @ b)))))


def test_the_walls_up_is_the_scenes_vertical_whatever_the_roads_grade() -> None:
    for grade in (0.0, 5.0):
        cloud = voxel_cloud(_street(grade), 1.0)
        found = walls_of(cloud)
        assert found is not None
        assert _angle_deg(found.up, np.array([0.0, 0.0, 1.0])) < 0.5, f"road graded {grade} deg"
    pitched = np.deg2rad(4.0)
    turn = rotation_from_euler_zyx(0.0, pitched, 0.0)  # the sensor pitched: its walls lean in its frame
    cloud = voxel_cloud(_street(0.0) @ turn.T.astype(np.float32), 1.0)
    found = walls_of(cloud)
    assert found is not None and _angle_deg(found.up, turn @ np.array([0.0, 0.0, 1.0])) < 0.5


def test_walls_facing_one_way_pin_the_tilt_about_their_own_horizontal_axis_only() -> None:
    rng = np.random.default_rng(2)
    fronts = np.column_stack(
        [rng.uniform(-30, 30, 6000), np.where(rng.random(6000) < 0.5, -9.0, 9.0), rng.uniform(-1.5, 8, 6000)]
    )
    found = walls_of(voxel_cloud(fronts.astype(np.float32), 1.0))
    assert found is not None
    values, vectors = np.linalg.eigh(found.information)
    pinned = vectors[:, 2]
    assert abs(pinned[1]) < 0.02 and abs(pinned @ found.up) < 0.02, (
        "a +-y wall tilts about its horizontal axis"
    )
    assert values[1] < 1e-6 * values[2], "and says nothing of a tilt about its normal"


def test_clutter_and_too_few_points_measure_no_up() -> None:
    rng = np.random.default_rng(3)
    centres = rng.uniform(-30, 30, size=(60, 3)) * [1, 1, 0.1]
    ball = rng.normal(size=(60, 200, 3))
    trees = (centres[:, None, :] + 2.5 * ball / np.linalg.norm(ball, axis=2, keepdims=True)).reshape(-1, 3)
    assert walls_of(voxel_cloud(trees.astype(np.float32), 1.0)) is None, "trees are not walls"
    assert walls_up(np.zeros((0, 3), np.float32), np.zeros((0, 3))) is None


def _walled_nodes(poses: list[np.ndarray], ground_grade_deg: float) -> list[Node]:
    """Nodes of a level lap that saw walls (level, as the lap is) and a ground graded as told."""
    cloud = voxel_cloud(_street(0.0), 1.0)
    graded = np.array(
        [0.0, -math.sin(math.radians(ground_grade_deg)), math.cos(math.radians(ground_grade_deg))]
    )
    return [
        Node(node.position, node.frame_index, node.pose, node.path_m, cloud, ground=graded)
        for node in _nodes(poses)
    ]


def test_a_drifted_tilt_is_held_by_the_walls_where_the_ground_tells_the_grade() -> None:
    truth, odometry = _lap(pitch_drift_deg_per_node=0.5)
    before = _worst_height_error(solve(_nodes(odometry), _loops(truth)), truth)
    nodes = _walled_nodes(odometry, ground_grade_deg=5.0)
    up = priors(nodes)
    assert up.measured_by == "walls" and len(up.edges) == len(odometry) - 1
    assert _worst_height_error(solve(nodes, _loops(truth), up), truth) < before / 4
    assert solve(nodes, [], up).tolist() == np.stack(odometry).tolist(), "no loop: untouched"


def test_the_walls_are_left_out_where_the_odometrys_tilt_agrees_with_them() -> None:
    truth, odometry = _lap(pitch_drift_deg_per_node=0.0)
    nodes = _walled_nodes(odometry, ground_grade_deg=5.0)
    up = priors(nodes)
    assert up.measured_by == "walls" and up.edges == []
    assert up.tilt_p90_deg is not None and up.tilt_p90_deg < 0.5
    assert np.array_equal(solve(nodes, _loops(truth), up), solve(nodes, _loops(truth)))


def test_walls_that_err_node_by_node_are_not_taken_for_a_drift() -> None:
    _, odometry = _lap(pitch_drift_deg_per_node=0.0)
    rng = np.random.default_rng(4)
    street = _street(0.0)
    nodes = []
    for node in _nodes(odometry):
        pitch, roll = rng.normal(0.0, 2.0, 2)  # each node's walls 2 deg off (sd): 4.3 deg at p90
        lean = rotation_from_euler_zyx(0.0, math.radians(pitch), math.radians(roll))
        cloud = voxel_cloud((street @ lean.T).astype(np.float32), 1.0)
        nodes.append(Node(node.position, node.frame_index, node.pose, node.path_m, cloud))
    up = priors(nodes)
    assert up.measured_by == "walls" and up.edges == []
    assert up.tilt_p90_deg is not None and up.tilt_p90_deg < 2.5


def test_a_reference_from_walls_facing_one_way_keeps_the_nodes_own_up_where_they_leave_it_free() -> None:
    """A straight street's fronts pin the roll only; pooled over the first nodes, their pitch is the
    nodes' own (level here), not whichever free direction the normals' noise favours (2 deg off)."""
    rng = np.random.default_rng(2)
    fronts = np.column_stack(
        [rng.uniform(-30, 30, 6000), np.where(rng.random(6000) < 0.5, -9.0, 9.0), rng.uniform(-1.5, 8, 6000)]
    )
    cloud = voxel_cloud(fronts.astype(np.float32), 1.0)
    nodes = [Node(k, k, make_transform(np.eye(3), [3.0 * k, 0.0, 0.0]), 3.0 * k, cloud) for k in range(12)]
    walls = [(k, found) for k, node in enumerate(nodes) if (found := walls_of(node.cloud, node.cloud_voxel))]
    assert len(walls) == len(nodes)
    assert _angle_deg(_walls_reference(nodes, walls), np.array([0.0, 0.0, 1.0])) < 0.2


def _leaning_nodes(lean_deg: float) -> list[Node]:
    """Nodes of a level lap with perfect odometry whose walls lean ``lean_deg`` (roll) past the first
    50 m, as a street seen at a slant errs alike over many nodes."""
    truth, _ = _lap(pitch_drift_deg_per_node=0.0)
    street = _street(0.0)
    level = voxel_cloud(street, 1.0)
    lean = rotation_from_euler_zyx(0.0, 0.0, math.radians(lean_deg))
    leaning = voxel_cloud((street @ lean.T).astype(np.float32), 1.0)
    return [
        Node(node.position, node.frame_index, node.pose, node.path_m, level if node.path_m < 50 else leaning)
        for node in _nodes(truth)
    ]


@pytest.mark.parametrize(("lean", "used"), [(1.5, False), (5.0, True)])
def test_walls_are_taken_for_a_drift_beyond_the_test_of_their_noise(lean: float, used: bool) -> None:
    """The walls disagree with a perfect odometry past the first 50 m: by 1.5 deg, within three of the
    walls' sigmas (1 deg: a slanted view errs that much), they are left out; by 5 deg, used. The tilt
    measured is the lean."""
    up = priors(_leaning_nodes(lean))
    assert up.measured_by == "walls"
    assert up.tilt_p90_deg is not None and lean - 0.1 < up.tilt_p90_deg < lean + 1.0, up.tilt_p90_deg
    assert bool(up.edges) == used, up.tilt_p90_deg
    assert bool(priors(_leaning_nodes(lean), walls_sigma_deg=lean).edges) is False, "a looser test"
