"""Scans that are almost one plane are named in the run's output: their motion along the plane cannot be
measured, and nothing else in a run notices (the fit of a sliding match is as good as ever)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vcr_odom.odometry import build_odometry, run_odometry
from vcr_odom.odometry.degeneracy import SINGLE_PLANE_M, plane_thickness, single_plane
from vcr_odom.odometry.outputs import run_summary
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
