"""Synthetic sequences (``vcr-odom synth``): determinism, KITTI layout, pose frames, scan sanity and a
geometric check of the ground truth that does not trust the generator."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree

from vcr_odom.cli.synth import synth
from vcr_odom.data.base import LidarSequence
from vcr_odom.data.synth import KITTI_TR, SensorConfig, SynthSequence, generate_sequence, write_bin
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import (
    camera_to_lidar_poses,
    euler_zyx,
    invert,
    make_transform,
    rotation_from_euler_zyx,
    transform_points,
)
from vcr_odom.io import read_kitti_calib, read_kitti_poses, read_times

FRAMES = 3


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One small sequence in the KITTI layout (seed 0)."""
    root = tmp_path_factory.mktemp("synth_a")
    generate_sequence(root, seq="00", frames=FRAMES, seed=0)
    return root


@pytest.fixture(scope="module")
def sequence() -> SynthSequence:
    return SynthSequence(frames=FRAMES, seed=0)


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _read_bin(path: Path) -> np.ndarray:
    return np.fromfile(path, dtype=np.float32).reshape(-1, 4)


# -- determinism ----------------------------------------------------------------------------------


def test_same_seed_gives_byte_identical_files(written: Path, tmp_path: Path) -> None:
    generate_sequence(tmp_path, seq="00", frames=FRAMES, seed=0)
    first, second = _files(written), _files(tmp_path)
    assert sorted(first) == sorted(second)
    for name, content in first.items():
        assert second[name] == content, f"{name} differs between two runs with the same seed"


def test_different_seed_gives_different_scene_and_drive(written: Path, tmp_path: Path) -> None:
    generate_sequence(tmp_path, seq="00", frames=FRAMES, seed=1)
    for index in range(FRAMES):
        name = f"sequences/00/velodyne/{index:06d}.bin"
        assert (written / name).read_bytes() != (tmp_path / name).read_bytes()
    assert (written / "poses/00.txt").read_bytes() != (tmp_path / "poses/00.txt").read_bytes()


def test_frames_do_not_depend_on_what_was_generated_before(sequence: SynthSequence) -> None:
    """Window size, sequence length and access order change nothing: a short run is a prefix."""
    longer = SynthSequence(frames=40, seed=0, window=2)
    for index in reversed(range(FRAMES)):
        assert np.array_equal(longer.frame(index), sequence.frame(index))
    assert np.array_equal(longer.gt_poses[:FRAMES], sequence.gt_poses)


# -- KITTI layout -----------------------------------------------------------------------------------


def test_layout_is_kitti_odometry(written: Path) -> None:
    seq_dir = written / "sequences" / "00"
    bins = sorted((seq_dir / "velodyne").iterdir())
    assert [p.name for p in bins] == [f"{i:06d}.bin" for i in range(FRAMES)]
    assert all(p.stat().st_size % 16 == 0 and p.stat().st_size > 0 for p in bins)
    np.testing.assert_allclose(read_times(seq_dir / "times.txt"), np.arange(FRAMES) * 0.1)
    calib = read_kitti_calib(seq_dir / "calib.txt")
    assert all(calib[key].shape == (12,) for key in ("P0", "P1", "P2", "P3"))
    np.testing.assert_allclose(calib["Tr"], KITTI_TR, atol=1e-11)
    # Tr maps LiDAR forward (x) to camera forward (z) and LiDAR up (z) to camera down (-y).
    np.testing.assert_allclose(calib["Tr"][:3, :3] @ [1, 0, 0], [0, 0, 1], atol=0.02)
    np.testing.assert_allclose(calib["Tr"][:3, :3] @ [0, 0, 1], [0, -1, 0], atol=0.02)
    poses = read_kitti_poses(written / "poses" / "00.txt")
    assert poses.shape == (FRAMES, 4, 4)
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-12)
    assert not list(written.rglob("*.tmp"))


def test_camera_poses_convert_back_to_the_lidar_poses(written: Path, sequence: SynthSequence) -> None:
    tr = read_kitti_calib(written / "sequences/00/calib.txt")["Tr"]
    camera = read_kitti_poses(written / "poses" / "00.txt")
    np.testing.assert_allclose(camera_to_lidar_poses(camera, tr), sequence.gt_poses, atol=1e-7)
    np.testing.assert_allclose(sequence.gt_poses[0], np.eye(4), atol=1e-12)
    assert np.linalg.norm(sequence.gt_poses[-1][:3, 3]) > 1.0  # the car moves


def test_in_memory_frames_equal_the_written_files(written: Path, sequence: SynthSequence) -> None:
    assert isinstance(sequence, LidarSequence)
    assert len(sequence) == FRAMES and sequence.timestamps[1] == pytest.approx(0.1)
    points, pose = sequence.frame_and_pose(1)
    assert np.array_equal(points, _read_bin(written / "sequences/00/velodyne/000001.bin"))
    np.testing.assert_array_equal(pose, sequence.gt_poses[1])


# -- scans --------------------------------------------------------------------------------------------


def test_point_cloud_is_kitti_like(sequence: SynthSequence) -> None:
    sensor = SensorConfig()
    points = sequence.frame(0)
    assert points.dtype == np.float32 and points.ndim == 2 and points.shape[1] == 4
    assert 40_000 < len(points) <= sensor.n_rays
    assert np.all(np.isfinite(points))
    ranges = np.linalg.norm(points[:, :3].astype(np.float64), axis=1)
    assert ranges.min() >= sensor.min_range and ranges.max() <= sensor.max_range
    elevation = np.degrees(np.arcsin(points[:, 2] / ranges))
    assert elevation.min() >= -24.8 - 1e-3 and elevation.max() <= 2.0 + 1e-3
    assert points[:, 3].min() >= 0.0 and points[:, 3].max() <= 1.0
    assert 0.1 < np.median(points[:, 3]) < 0.5  # KITTI's median reflectance is about 0.3
    # Ground about 1.73 m below the sensor, and plenty of structure above it.
    ground = points[(ranges < 8.0) & (points[:, 2] < -1.2)]
    assert abs(np.median(ground[:, 2]) + sensor.height) < 0.1
    assert np.mean(points[:, 2] > -1.0) > 0.05


def test_sensor_has_64_beams_from_plus_2_to_minus_24_8_degrees() -> None:
    sensor = SensorConfig()
    elevations = np.degrees(sensor.elevations)
    assert len(elevations) == 64
    assert elevations.max() == pytest.approx(2.0) and elevations.min() == pytest.approx(-24.8)
    assert 360.0 / sensor.azimuth_steps == pytest.approx(0.17, abs=0.01)
    directions = sensor.directions()
    assert directions.shape == (sensor.n_rays, 3)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)


def _median_gap(tree: cKDTree, pose: np.ndarray, points: np.ndarray) -> float:
    distance, _ = tree.query(transform_points(pose, points))
    return float(np.median(distance))


def test_consecutive_frames_overlap_under_their_poses() -> None:
    """Independent of the generator: frames t and t+1 moved into the world with their ground-truth poses
    must lie on the same surfaces, across a ray-casting window boundary too, and a wrong pose must not."""
    sequence = SynthSequence(frames=4, seed=2, window=2)
    poses = sequence.gt_poses
    target, source = sequence.frame(1), sequence.frame(2)  # frames from two different windows
    tree = cKDTree(transform_points(poses[1], target))
    structure = source[(source[:, 2] > -1.3) & (np.linalg.norm(source[:, :3], axis=1) < 40.0)]
    assert len(structure) > 5_000
    true_gap = _median_gap(tree, poses[2], structure)
    assert true_gap < 0.06
    for wrong in (
        make_transform(np.eye(3), [0.0, 0.3, 0.0]),
        make_transform(np.eye(3), [0.3, 0.0, 0.0]),
        make_transform(rotation_from_euler_zyx(np.radians(1.0), 0.0, 0.0), [0.0, 0.0, 0.0]),
    ):
        assert true_gap < 0.8 * _median_gap(tree, poses[2] @ wrong, structure)
    assert true_gap < 0.1


# -- drive -------------------------------------------------------------------------------------------


def test_long_drive_is_smooth_with_turns_hills_and_speed_changes() -> None:
    sequence = SynthSequence(frames=1200, seed=0)
    poses = sequence.gt_poses
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    assert steps.min() > 0.4 and steps.max() < 1.6  # 4..16 m/s at 10 Hz
    assert steps.max() - steps.min() > 0.3  # the speed changes
    assert sequence.length > 1000.0
    relative = invert(poses[:-1]) @ poses[1:]
    yaw, pitch, roll = euler_zyx(relative).T
    assert np.degrees(np.abs(yaw)).max() < 6.0 and np.degrees(np.abs(yaw)).sum() > 90.0  # turns
    # Camber and road ripples tilt the car a little from frame to frame, as in KITTI's ground truth
    # (sequences 00/05/07: median 0.06-0.11 deg per frame, at most about 1.3 deg).
    assert np.median(np.degrees(np.abs(pitch))) < 0.2 and np.degrees(np.abs(pitch)).max() < 2.0
    assert np.median(np.degrees(np.abs(roll))) < 0.2 and np.degrees(np.abs(roll)).max() < 2.0
    world = sequence.world_poses
    heights = world[:, 2, 3]
    assert heights.max() - heights.min() > 2.0  # hills
    assert np.degrees(np.abs(euler_zyx(world)[:, 1])).max() < 8.0
    rotations = world[:, :3, :3]
    np.testing.assert_allclose(
        rotations @ np.swapaxes(rotations, 1, 2), np.broadcast_to(np.eye(3), rotations.shape), atol=1e-12
    )


def test_last_frame_of_a_long_sequence_builds_only_its_neighbourhood() -> None:
    sequence = SynthSequence(frames=1000, seed=1)
    points = sequence.frame(999)
    assert len(points) > 40_000
    assert sequence.scene.cached_chunks < 150  # a window's worth of chunks, not the whole drive


# -- writing and options -------------------------------------------------------------------------


def test_interrupted_write_leaves_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def interrupted(*_args: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_bin(tmp_path / "000000.bin", np.zeros((10, 4), np.float32))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("kwargs", "word"), [({"frames": 1}, "frames"), ({"seed": -1}, "seed"), ({"speed": 0.0}, "speed")]
)
def test_bad_library_options_raise_config_errors(kwargs: dict, word: str) -> None:
    with pytest.raises(ConfigError, match=word):
        SynthSequence(**kwargs)


def test_cli_writes_a_sequence_and_drops_stale_frames(written: Path, tmp_path: Path) -> None:
    out = tmp_path / "data"
    shutil.copytree(written, out)
    result = CliRunner().invoke(synth, ["--out", str(out), "--frames", "2", "--seed", "0"])
    assert result.exit_code == 0, result.output
    assert "Drive:" in result.output and " m " in result.output
    bins = sorted((out / "sequences/00/velodyne").glob("*.bin"))
    assert [p.name for p in bins] == ["000000.bin", "000001.bin"]
    assert bins[1].read_bytes() == (written / "sequences/00/velodyne/000001.bin").read_bytes()
    assert len(read_kitti_poses(out / "poses/00.txt")) == 2


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["--frames", "1"], "--frames"),
        (["--seed", "-3"], "--seed"),
        (["--speed", "0"], "--speed"),
        (["--seq", "../x"], "--seq"),
    ],
)
def test_cli_bad_options_name_the_option(tmp_path: Path, args: list[str], option: str) -> None:
    result = CliRunner().invoke(synth, ["--out", str(tmp_path), *args])
    assert result.exit_code == 2
    assert option in result.output


def test_cli_requires_out() -> None:
    result = CliRunner().invoke(synth, [])
    assert result.exit_code == 2 and "--out" in result.output
