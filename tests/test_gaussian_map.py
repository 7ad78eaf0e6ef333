"""The polish's vgicp engine: small_gicp's Gaussian voxel map registers a frame started a metre and
five degrees off onto its true pose, a run with it follows a synthetic drive's ground truth as closely
as kiss-icp's own engine, the result says which engine ran, and an unknown engine is named."""

from __future__ import annotations

import json
from pathlib import Path
from typing import get_args

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vcr_odom.data import open_sequence
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import invert, make_transform, motion_difference, transform_points
from vcr_odom.odometry.gaussian_map import GaussianMap
from vcr_odom.odometry.guided_kiss import ENGINES, PolishEngine
from vcr_odom.odometry.polish import KissIcpPolish


def _street(rng: np.random.Generator) -> np.ndarray:
    """Facades on both sides with doorways, a wall ahead and the road: every direction is measured."""
    along, up = np.meshgrid(np.arange(0.0, 30.0, 0.15), np.arange(0.0, 8.0, 0.15), indexing="ij")
    along, up = along.ravel(), up.ravel()
    doors = (np.floor(along / 3.0) % 2 == 0) | (up > 2.5)
    left = np.stack([along, np.full(along.size, 6.0) + 0.8 * ~doors, up - 1.5], axis=1)
    right = np.stack([along, np.full(along.size, -6.0), up - 1.5], axis=1)
    across, up2 = np.meshgrid(np.arange(-6.0, 6.0, 0.15), np.arange(0.0, 8.0, 0.15), indexing="ij")
    ahead = np.stack([np.full(across.size, 30.0), across.ravel(), up2.ravel() - 1.5], axis=1)
    a, b = np.meshgrid(np.arange(0.0, 30.0, 0.2), np.arange(-6.0, 6.0, 0.2), indexing="ij")
    road = np.stack([a.ravel(), b.ravel(), np.full(a.size, -1.5)], axis=1)
    cloud = np.concatenate([left, right, ahead, road])
    return cloud + rng.normal(scale=0.003, size=cloud.shape)


def test_a_frame_started_a_metre_off_lands_on_its_true_pose() -> None:
    world = _street(np.random.default_rng(0))
    true_pose = make_transform(Rotation.from_euler("z", 4.0, degrees=True).as_matrix(), [1.5, 0.3, 0.05])
    gaussian_map = GaussianMap(voxel_size=1.0, threads=1)
    gaussian_map.insert(world, np.eye(4))
    frame = transform_points(invert(true_pose), world)[::3]
    start = make_transform(Rotation.from_euler("zy", [5.0, 1.0], degrees=True).as_matrix(), [0.9, -0.5, 0.2])
    start = start @ true_pose
    assert motion_difference(start, true_pose)[0] > 0.9
    moved_m, turned_deg = motion_difference(gaussian_map.align(frame, start), true_pose)
    assert moved_m < 0.01 and turned_deg < 0.1
    assert np.array_equal(GaussianMap(voxel_size=1.0).align(frame, start), start)  # nothing to measure
    assert np.array_equal(gaussian_map.align(frame[:3], start), start)


@pytest.mark.filterwarnings("ignore:.*no timestamps")
def test_a_run_with_the_vgicp_engine_follows_the_ground_truth(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    from vcr_odom.data.selection import FrameSelection
    from vcr_odom.odometry.run import RunSettings, run_sequence

    selection = FrameSelection(data_root=small_synthetic_root, seq="00")
    truth = open_sequence("00", data_root=small_synthetic_root).gt_poses
    errors = {}
    for engine in ("kiss-icp", "vgicp"):
        settings = RunSettings(
            selection=selection, method="icp10", polish="kiss-icp", polish_engine=engine, results_dir=tmp_path
        )
        outcome = run_sequence(settings)
        assert json.loads((outcome.folder / "config.json").read_text())["config"]["polish_engine"] == engine
        poses = outcome.run.poses
        errors[engine] = max(
            motion_difference(invert(truth[0]) @ truth[i], poses[i])[0] for i in range(len(poses))
        )
    assert errors["vgicp"] < 0.06
    assert errors["vgicp"] < errors["kiss-icp"] + 0.01


def test_an_unknown_engine_is_named_with_the_choices() -> None:
    with pytest.raises(ConfigError, match=r"'gicp'.*kiss-icp, vgicp"):
        KissIcpPolish(engine="gicp")  # type: ignore[arg-type]
    assert set(get_args(PolishEngine)) == set(ENGINES)  # the settings' choices are the engines
