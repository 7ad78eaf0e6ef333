"""Scans that are almost one plane are named in the run's output: their motion along the plane cannot be
measured, and nothing else in a run notices (the fit of a sliding match is as good as ever)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scripted_registrar import ScriptedRegistrar

from vcr_odom.odometry import Odometry, build_odometry, run_odometry
from vcr_odom.odometry.degeneracy import SINGLE_PLANE_M, hold_along, plane_thickness, single_plane, weak_axes
from vcr_odom.odometry.guided_kiss import GuidedKissICP, KissFramePreparer
from vcr_odom.odometry.outputs import run_summary
from vcr_odom.odometry.polish import KissIcpPolish
from vcr_odom.registration.kiss import kiss_config
from vcr_odom.synth import SynthSequence


def road(rng: np.random.Generator, count: int = 20000) -> np.ndarray:
    """What a narrow-field sensor sees facing the road: a 30 x 20 m patch, 2 cm of noise."""
    xy = rng.uniform([2.0, -10.0], [32.0, 10.0], size=(count, 2))
    z = -1.7 + rng.normal(scale=0.02, size=count)
    return np.column_stack([xy, z, np.zeros(count)]).astype(np.float32)


def test_a_road_is_one_plane_and_a_street_is_not() -> None:
    rng = np.random.default_rng(1)
    assert plane_thickness(road(rng)) == pytest.approx(0.02, abs=0.005)
    assert single_plane(road(rng)) is not None
    street = SynthSequence(frames=2, seed=3).frame(0)
    assert plane_thickness(street) > 2 * SINGLE_PLANE_M and single_plane(street) is None
    tilted = road(rng)[:, :3] @ np.array([[1, 0, 0], [0, 0.6, -0.8], [0, 0.8, 0.6]], dtype=np.float32)
    assert single_plane(tilted) == pytest.approx(0.02, abs=0.005)  # a wall as much as the road
    assert plane_thickness(np.zeros((5, 4), np.float32)) == float("inf")


class RoadInTheMiddle:
    """A synthetic street whose frames 4-6 see only the road."""

    def __init__(self) -> None:
        self.street = SynthSequence(frames=10, seed=3)
        self.name, self.timestamps, self.gt_poses = "road", self.street.timestamps, self.street.gt_poses
        self.tr_velo_to_cam = None

    def __len__(self) -> int:
        return len(self.street)

    def frame(self, index: int) -> np.ndarray:
        return road(np.random.default_rng(index)) if 4 <= index <= 6 else self.street.frame(index)


@pytest.mark.filterwarnings("ignore")
def test_a_run_names_the_frames_whose_scan_is_one_plane() -> None:
    run = run_odometry(RoadInTheMiddle(), build_odometry("icp10"), range(10))
    assert run.single_plane_frames == [4, 5, 6]
    summary = json.loads(json.dumps(run_summary(run)))
    assert summary["single_plane_frames"] == [4, 5, 6]
    assert all(run.per_frame_info[i]["single_plane_m"] < SINGLE_PLANE_M for i in (4, 5, 6))


def test_the_kitti_sample_has_no_single_plane_frame(kitti_sample_root: Path) -> None:
    from vcr_odom.data import open_sequence

    sequence = open_sequence("00", data_root=kitti_sample_root)
    assert [i for i in range(0, len(sequence), 5) if single_plane(sequence.frame(i)) is not None] == []


def surfaces(rng: np.random.Generator, *, end_walls: bool, count: int = 24000) -> np.ndarray:
    """A footpath 6 m wide between two 3.5 m walls, 60 m long, with the ground (2 cm of noise); with
    ``end_walls`` walls close it 5 m ahead and behind, and the direction along it is measured too."""
    length = 5.0 if end_walls else 30.0
    along = rng.uniform(-length, length, count)
    height = rng.uniform(-1.5, 2.0, count)
    side = np.where(rng.random(count) < 0.5, -3.0, 3.0)
    clouds = [
        np.column_stack([along, side, height]),
        np.column_stack([along, rng.uniform(-3.0, 3.0, count), np.full(count, -1.5)]),
    ]
    if end_walls:
        ends = np.where(rng.random(count) < 0.5, -length, length)
        clouds.append(np.column_stack([ends, rng.uniform(-3.0, 3.0, count), height]))
    xyz = np.concatenate(clouds)
    return xyz + rng.normal(scale=0.02, size=xyz.shape)


def test_a_footpath_between_walls_leaves_the_direction_along_it_unmeasured() -> None:
    rng = np.random.default_rng(4)
    (axis,) = weak_axes(surfaces(rng, end_walls=False), radius=1.0)
    assert abs(axis[0]) == pytest.approx(1.0, abs=0.01)
    assert weak_axes(surfaces(rng, end_walls=True), radius=1.0).shape == (0, 3)
    assert weak_axes(surfaces(rng, end_walls=False)[:10], radius=1.0).shape == (0, 3)  # too few to tell
    assert weak_axes(surfaces(rng, end_walls=False), radius=1.0, share=0.0).shape == (0, 3)  # turned off


def test_a_held_pose_keeps_the_start_along_the_weak_axis_and_its_own_across_it() -> None:
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # the sensor faces world +y
    start, pose = np.eye(4), np.eye(4)
    start[:3, :3] = pose[:3, :3] = turn
    start[:3, 3] = [1.0, 2.0, 0.0]
    pose[:3, 3] = [1.4, 2.9, 0.1]  # 0.9 m along the sensor's x (world y), 0.4 m across, 0.1 up
    held = hold_along(pose, start, np.array([[1.0, 0.0, 0.0]]))
    np.testing.assert_allclose(held[:3, 3], [1.4, 2.0, 0.1], atol=1e-12)
    np.testing.assert_array_equal(held[:3, :3], turn)
    np.testing.assert_array_equal(hold_along(pose, start, np.zeros((0, 3))), pose)


@pytest.mark.parametrize("end_walls", [False, True])
def test_kiss_registration_holds_its_start_only_along_what_the_scan_cannot_measure(end_walls: bool) -> None:
    """The scan again from a start 0.5 m along the path and 0.3 m across it: the path's walls measure
    the 0.3 m (back to 0); along an open path the 0.5 m stays where it started (kiss-icp would move it by
    whatever the path's ends pull); closed by walls ahead and behind, it is measured too."""
    config = kiss_config(voxel_size=0.5)
    scan = surfaces(np.random.default_rng(5), end_walls=end_walls)
    prepare = KissFramePreparer(config)
    guided = GuidedKissICP(config)
    guided.seed(prepare(scan), np.eye(4), np.eye(4))
    start = np.eye(4)
    start[:3, 3] = [0.5, 0.3, 0.0]
    pose, _ = guided.register_frame_with_guess(prepare(scan), start, keep_prediction=False)
    assert abs(pose[1, 3]) < 0.03
    if end_walls:
        assert guided.last_weak_axes == 0 and abs(pose[0, 3]) < 0.03
    else:
        assert guided.last_weak_axes == 1 and pose[0, 3] == pytest.approx(0.5, abs=1e-3)


class FootpathInTheMiddle(RoadInTheMiddle):
    """A synthetic street whose frames 4-6 see an open footpath between two walls."""

    def frame(self, index: int) -> np.ndarray:
        if 4 <= index <= 6:
            xyz = surfaces(np.random.default_rng(index), end_walls=False)
            return np.column_stack([xyz, np.zeros(len(xyz))]).astype(np.float32)
        return self.street.frame(index)


@pytest.mark.filterwarnings("ignore")
def test_a_run_names_the_frames_whose_polish_held_a_direction() -> None:
    sequence = FootpathInTheMiddle()
    method = Odometry(ScriptedRegistrar(sequence.gt_poses), KissIcpPolish())
    run = run_odometry(sequence, method, range(10))
    assert run.weak_axis_frames == [4, 5, 6]
    assert json.loads(json.dumps(run_summary(run)))["weak_axis_frames"] == [4, 5, 6]
    assert all(run.per_frame_info[i]["weak_axes"] == 1 for i in (4, 5, 6))
