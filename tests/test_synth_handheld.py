"""Handheld walks (``--motion handheld``), keyframes (``--keyframes``) and thinned clouds (``--thin``):
motion limits measured on the poses, keyframe spacing, one point per voxel, determinism, bad options,
and the car's poses unchanged byte for byte."""

from __future__ import annotations

import hashlib
import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from vcr_odom.cli.synth import synth
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import camera_to_lidar_poses, euler_zyx, invert, rotation_angle
from vcr_odom.io import read_kitti_poses, read_times
from vcr_odom.synth import KITTI_TR, SynthConfig, SynthSequence, generate_sequence
from vcr_odom.synth.handheld import HAND_HEIGHT
from vcr_odom.synth.keyframes import thin_voxels

WALK = {"motion": "handheld", "sensor": "vlp16"}
WRITTEN = {**WALK, "frames": 40, "seed": 2, "keyframes": 0.8, "thin": 0.3}
"""A small written walk: about 10 keyframes of a 4 s walk, thinned."""
CLI_WRITTEN = ["--motion", "handheld", "--sensor", "vlp16", "--frames", "40", "--seed", "2"]
CLI_WRITTEN += ["--keyframes", "0.8", "--thin", "0.3"]


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _bins(root: Path) -> list[np.ndarray]:
    files = sorted((root / "sequences" / "00" / "velodyne").glob("*.bin"))
    return [np.fromfile(f, dtype=np.float32).reshape(-1, 4) for f in files]


def _rates(sequence: SynthSequence) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal speed (m/s) and angular rate (deg/s) between consecutive frames."""
    poses = sequence.world_poses
    speed = np.linalg.norm(np.diff(poses[:, :2, 3], axis=0), axis=1) / sequence.frame_period
    turn = np.degrees(rotation_angle(invert(poses[:-1]) @ poses[1:])) / sequence.frame_period
    return speed, turn


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("handheld")
    generate_sequence(root, **WRITTEN)
    return root


# -- the walk (poses only: no ray casting) --------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_walk_keeps_walking_pace_and_turns_at_most_90_deg_per_s(seed: int) -> None:
    walk = SynthSequence(frames=600, seed=seed, **WALK)
    speed, turn = _rates(walk)
    assert 1.0 <= np.median(speed) <= 1.6
    assert speed.max() <= 1.7, "faster than a walk (or a jump)"
    assert turn.max() <= 90.0 + 1.0
    assert turn.max() >= 30.0, "no look-around turn in a minute of walking"
    assert HAND_HEIGHT[0] <= walk.sensor.height <= HAND_HEIGHT[1]


def test_walk_pauses_now_and_then() -> None:
    speeds = np.concatenate([_rates(SynthSequence(frames=900, seed=s, **WALK))[0] for s in range(3)])
    assert (speeds < 0.05).sum() >= 10, "no pause in four and a half minutes of walking"


def test_walk_tilts_bobs_and_looks_around() -> None:
    walk = SynthSequence(frames=1500, seed=1, frame_period=0.05, **WALK)
    yaw, pitch, roll = np.degrees(euler_zyx(walk.world_poses)).T
    assert max(np.abs(pitch).max(), np.abs(roll).max()) >= 6.0
    assert np.abs(pitch).max() <= 15.0 and np.abs(roll).max() <= 15.0
    assert np.abs(pitch).std() > 1.0 and np.abs(roll).std() > 1.0, "tilts should vary over the walk"
    heading = np.unwrap(np.arctan2(*np.diff(walk.world_poses[:, :2, 3], axis=0).T[::-1]))
    looking = np.degrees(np.abs(np.unwrap(np.radians(yaw[1:])) - heading))
    assert np.percentile(looking[np.isfinite(looking)], 99) >= 30.0, "never looked aside"
    ground = walk.scene.layout.ground_height(walk.world_poses[:, :2, 3])
    above = walk.world_poses[:, 2, 3] - ground
    bob = above - np.convolve(above, np.ones(21) / 21, mode="same")  # 1 s mean: steps are ~0.5 s
    assert 0.01 <= np.abs(bob[20:-20]).max() <= 0.06


def test_walk_is_smooth() -> None:
    walk = SynthSequence(frames=600, seed=3, frame_period=0.02, **WALK)
    velocity = np.diff(walk.world_poses[:, :3, 3], axis=0) / walk.frame_period
    acceleration = np.linalg.norm(np.diff(velocity, axis=0), axis=1) / walk.frame_period
    assert acceleration.max() < 5.0, "a jump in the walker's position"


def test_same_seed_gives_the_same_walk_and_a_longer_walk_starts_the_same() -> None:
    first = SynthSequence(frames=200, seed=5, **WALK).gt_poses
    assert first.tobytes() == SynthSequence(frames=200, seed=5, **WALK).gt_poses.tobytes()
    np.testing.assert_allclose(SynthSequence(frames=400, seed=5, **WALK).gt_poses[:200], first, atol=1e-9)
    assert not np.allclose(SynthSequence(frames=200, seed=6, **WALK).gt_poses, first)


def test_car_poses_are_unchanged_to_the_micrometre() -> None:
    """The poses shipped weights and training caches were made from, hashed at 1e-6 (m, and rotation
    entries). The raw bytes of seed 3 differ on a fresh environment (numpy 2.4.6, scipy 1.17.1) from
    the hash taken earlier, with the code that made them unchanged since (checked back to before the
    routes); floating-point summation order is the likely cause, not traced. A change to the drive
    moves millimetres or more, which this still catches."""
    expected = {
        "ecc357fe9f5202e63ca86b5d4d1ece70242c71c07d01709dd43fc8f316d10bf8": {"seed": 3},
        "c01756138cd0e6b7676b33c8be362edbba26f2056a41121fb9de35feb30d0542": {
            "seed": 4,
            "scene": "oldtown",
            "stops": True,
            "sensor": "os128",
        },
    }
    for digest, options in expected.items():
        poses = np.round(SynthSequence(frames=50, **options).gt_poses, 6)
        assert hashlib.sha256(poses.tobytes()).hexdigest() == digest, options


# -- keyframes ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("options", "distance", "angle"),
    [({**WALK, "frames": 400}, 1.0, 10.0), ({"frames": 300, "seed": 1}, 5.0, 4.0)],
)
def test_keyframes_are_spaced_by_the_option_and_no_more(options: dict, distance: float, angle: float) -> None:
    full = SynthSequence(**options)
    kept = SynthSequence(**options, keyframes=distance, keyframe_angle=angle)
    index = kept.kept
    assert index[0] == 0 and len(kept) == len(index) and 3 <= len(index) < full.frames
    world = full.world_poses

    def apart(a: int, b: int) -> tuple[float, float]:
        moved = float(np.linalg.norm(world[b, :3, 3] - world[a, :3, 3]))
        return moved, math.degrees(rotation_angle(world[a, :3, :3].T @ world[b, :3, :3]))

    for previous, current in itertools.pairwise(index):
        moved, turned = apart(previous, current)
        assert moved >= distance or turned >= angle
        moved, turned = apart(previous, current - 1)  # one frame earlier was not yet far enough
        assert current - 1 == previous or (moved < distance and turned < angle)
    moved, turned = apart(index[-1], full.frames - 1)
    assert (moved < distance and turned < angle) or index[-1] == full.frames - 1
    np.testing.assert_array_equal(kept.timestamps, index * full.frame_period)
    np.testing.assert_allclose(kept.gt_poses, full.gt_poses[index], atol=1e-12)


def test_written_keyframes_have_consistent_times_poses_and_clouds(written: Path) -> None:
    sequence = SynthSequence(**WRITTEN)
    clouds = _bins(written)
    times = read_times(written / "sequences" / "00" / "times.txt")
    poses = camera_to_lidar_poses(read_kitti_poses(written / "poses" / "00.txt"), KITTI_TR)
    assert len(clouds) == len(times) == len(poses) == len(sequence) >= 4
    np.testing.assert_allclose(times, sequence.kept * sequence.frame_period, atol=1e-6)
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-6)
    np.testing.assert_allclose(poses, sequence.gt_poses, atol=1e-5)
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    turns = np.degrees(rotation_angle(invert(poses[:-1]) @ poses[1:]))
    assert np.all((steps >= 0.8 - 1e-4) | (turns >= 10.0 - 1e-3))
    assert not list(written.glob("sequences/.*")), "a staging folder was left behind"


# -- thinning -------------------------------------------------------------------------------------


def test_thinned_clouds_keep_one_measured_point_per_voxel(written: Path) -> None:
    raw = SynthSequence(**{**WRITTEN, "thin": None}).frame(1)
    thinned = _bins(written)[1]
    cells = np.floor(raw[:, :3].astype(np.float64) / 0.3)
    assert len(thinned) == len(np.unique(cells, axis=0)), "one point per occupied voxel"
    thin_cells = np.floor(thinned[:, :3].astype(np.float64) / 0.3)
    assert len(np.unique(thin_cells, axis=0)) == len(thinned), "two points in one voxel"
    raw_rows = {row.tobytes() for row in raw}
    assert all(row.tobytes() in raw_rows for row in thinned), "a point (or reflectance) was invented"
    assert 0.2 * len(raw) < len(thinned) < 0.6 * len(raw)


def test_thin_voxels_picks_the_point_nearest_the_voxel_centroid() -> None:
    points = np.array(
        [[0.1, 0.1, 0.1, 0.2], [0.5, 0.5, 0.5, 0.9], [0.9, 0.9, 0.9, 0.4], [1.5, 0.2, 0.2, 0.7]],
        dtype=np.float32,
    )
    np.testing.assert_array_equal(thin_voxels(points, 1.0), points[[1, 3]])
    assert len(thin_voxels(points[:0], 1.0)) == 0


# -- determinism and options ----------------------------------------------------------------------


def test_same_seed_writes_byte_identical_keyframes(written: Path, tmp_path: Path) -> None:
    result = CliRunner().invoke(
        synth,
        ["--out", str(tmp_path), *CLI_WRITTEN],
    )
    assert result.exit_code == 0, result.output
    assert "keyframes of 40" in result.output and "Walk:" in result.output
    assert _files(tmp_path) == _files(written)


@pytest.mark.parametrize(
    ("options", "word"),
    [
        ({"motion": "bicycle"}, "motion"),
        ({"keyframes": 0.0}, "keyframes"),
        ({"keyframes": -1.0}, "keyframes"),
        ({"keyframe_angle": 0.0}, "keyframe_angle"),
        ({"thin": 0.0}, "thin"),
        ({"thin": 50.0}, "thin"),
        ({"motion": "handheld", "speed": 5.0}, "speed: applies to motion 'car' only"),
        ({"motion": "handheld", "stops": True}, "stops: applies to motion 'car' only"),
    ],
)
def test_bad_options_name_the_option(options: dict, word: str) -> None:
    with pytest.raises(ConfigError, match=word):
        SynthConfig(**options)


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["--motion", "bicycle"], "--motion"),
        (["--keyframes", "0"], "--keyframes"),
        (["--keyframe-angle", "-5"], "--keyframe-angle"),
        (["--thin", "0"], "--thin"),
    ],
)
def test_cli_bad_options_name_the_option(tmp_path: Path, args: list[str], option: str) -> None:
    result = CliRunner().invoke(synth, ["--out", str(tmp_path), *args])
    assert result.exit_code == 2 and option in result.output
