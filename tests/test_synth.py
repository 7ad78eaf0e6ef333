"""Synthetic sequences (``vcr-odom synth``): determinism, KITTI layout, pose frames, scan sanity and a
geometric check of the ground truth that does not trust the generator."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree

from vcr_odom.cli.synth import synth
from vcr_odom.data.base import LidarSequence
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
from vcr_odom.synth import (
    HEIGHT_RANGE,
    KITTI_TR,
    SCENE_STYLES,
    SENSOR_MODELS,
    SensorConfig,
    StreetScene,
    Surface,
    SynthConfig,
    SynthSequence,
    WrittenSequence,
    generate_sequence,
    write_bin,
)

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


# Published beam layouts (top and bottom elevation in degrees, beams, azimuth resolution in degrees):
# written out here rather than read from the presets, so a wrong preset fails.
SENSOR_SPECS = {
    "hdl64": (2.0, -24.8, 64, 0.17),
    "hdl32": (10.67, -30.67, 32, 0.2),
    "vlp16": (15.0, -15.0, 16, 0.2),
    "os128": (22.5, -22.5, 128, 360.0 / 1024),
}


def _small(name: str, **changes: object) -> SensorConfig:
    """A preset with a coarse azimuth grid: the beam layout is what counts, and it casts fast."""
    return SensorConfig.model(name).with_changes(azimuth_steps=256, **changes)


def _elevations_deg(points: np.ndarray) -> np.ndarray:
    xyz = points[:, :3].astype(np.float64)
    return np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))


# Solid-state sensors: tests/test_synth_solid_state.py; the os0 (its upper beams see sky on a street):
# tests/test_synth_indoor.py.
@pytest.mark.parametrize("name", SENSOR_SPECS)
def test_sensor_presets_have_their_published_beam_layout(name: str) -> None:
    top, bottom, beams, resolution = SENSOR_SPECS[name]
    sensor = SensorConfig.model(name)
    assert sensor.name == name and sensor.n_beams == beams
    assert 360.0 / sensor.azimuth_steps == pytest.approx(resolution, abs=0.01)
    directions = sensor.directions()
    assert directions.shape == (sensor.n_rays, 3) == (beams * sensor.azimuth_steps, 3)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
    ray_elevation = np.degrees(np.arcsin(directions[:, 2]))
    assert ray_elevation.max() == pytest.approx(top) and ray_elevation.min() == pytest.approx(bottom)
    # A small frame: every point lies within the field of view, and each beam shows as one ring.
    points = SynthSequence(frames=2, seed=0, sensor=_small(name)).frame(0)
    elevation = _elevations_deg(points)
    assert elevation.min() >= bottom - 1e-3 and elevation.max() <= top + 1e-3
    assert elevation.min() < bottom + 0.1  # the lowest beam hits the ground
    gaps = np.diff(np.sort(elevation))
    assert 1 + int(np.sum(gaps > 0.05)) == beams
    assert np.max(np.linalg.norm(points[:, :3], axis=1)) <= sensor.max_range


def test_only_the_hdl64_staggers_its_lasers_in_azimuth() -> None:
    assert SensorConfig.model("hdl64") == SensorConfig()
    assert np.ptp(SensorConfig().beam_azimuth_offsets) > np.radians(4.0)
    for name in ("hdl32", "vlp16", "os128"):
        assert not np.any(SensorConfig.model(name).beam_azimuth_offsets)


def test_unknown_sensor_model_names_the_option_and_the_choices() -> None:
    with pytest.raises(ConfigError, match="sensor") as error:
        SensorConfig.model("hdl128")
    assert all(name in str(error.value) for name in SENSOR_MODELS)


def test_mounting_height_moves_the_ground_in_the_scan() -> None:
    low = SynthSequence(frames=2, seed=0, sensor=_small("vlp16"))
    high = SynthSequence(frames=2, seed=0, sensor=_small("vlp16"), height=2.05)
    assert high.sensor.height == 2.05 and low.sensor.height == 1.73
    np.testing.assert_allclose(high.world_poses[:, 2, 3] - low.world_poses[:, 2, 3], 0.32, atol=2e-3)
    for sequence in (low, high):
        points = sequence.frame(0)
        near = points[np.linalg.norm(points[:, :2], axis=1) < 12.0]
        ground = near[near[:, 2] < -1.2]
        assert abs(np.median(ground[:, 2]) + sequence.sensor.height) < 0.1


def test_varied_sequences_draw_sensor_height_and_scene_from_the_seed() -> None:
    drawn = [SynthSequence.varied(seed) for seed in range(12)]
    assert all(HEIGHT_RANGE[0] <= s.sensor.height <= HEIGHT_RANGE[1] for s in drawn)
    assert len({s.sensor.name for s in drawn}) > 1 and len({s.scene_style for s in drawn}) > 1
    again = SynthSequence.varied(3)
    assert (again.sensor, again.scene_style, again.speed, again.stops) == (
        drawn[3].sensor, drawn[3].scene_style, drawn[3].speed, drawn[3].stops,
    )  # fmt: skip


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


def test_stops_start_from_rest_and_stand_still_between_frames() -> None:
    sequence = SynthSequence(frames=600, seed=0, stops=True)
    steps = np.linalg.norm(np.diff(sequence.gt_poses[:, :3, 3], axis=0), axis=1)
    assert np.array_equal(sequence.gt_poses[1], sequence.gt_poses[0])  # a standing start
    assert sequence.drive.speeds[0] == 0.0
    standing = steps == 0.0
    moving = np.flatnonzero(~standing)
    assert len(moving) and steps.max() > 0.5  # pulls away and gets going
    later_stops = np.flatnonzero(standing[moving[0] :])
    assert len(later_stops) >= 10, "no stop of a second or more after pulling away"
    # Braking into a stop and pulling away are gradual: at most 2 m/s^2 along the road.
    along = np.diff(sequence.drive.stations)
    assert np.abs(np.diff(along)).max() < 2.0 * 0.1**2 + 1e-6
    assert not np.any(np.diff(SynthSequence(frames=600, seed=0).gt_poses[:, :3, 3], axis=0) == 0.0)


def test_frame_period_spaces_times_and_poses() -> None:
    slow = SynthSequence(frames=6, seed=0, frame_period=0.5)
    fast = SynthSequence(frames=26, seed=0)
    np.testing.assert_allclose(slow.timestamps, np.arange(6) * 0.5)
    np.testing.assert_allclose(
        slow.gt_poses, fast.gt_poses[::5], atol=1e-9
    )  # the same drive, sampled at 2 Hz


def _building_share(scene: StreetScene) -> float:
    mesh = scene.mesh_near(scene.road.xy[300:1000:50], 40.0)
    return float(np.isin(mesh.surface, [Surface.WALL, Surface.GLASS, Surface.ROOF]).mean())


def test_scene_styles_build_different_streets() -> None:
    scenes = {name: StreetScene(0, 1000.0, scene=name) for name in SCENE_STYLES}
    lanes = {name: [p.lanes_left + 1 for p in s.layout.profiles] for name, s in scenes.items()}
    curvature = {name: np.abs(s.road.curvature).max() for name, s in scenes.items()}
    assert all(4 <= n <= 6 for n in lanes["highway"]) and not len(scenes["highway"].layout.crossings)
    assert curvature["highway"] < 1.0 / 400.0 < 1.0 / 25.0 < curvature["oldtown"]
    assert max(lanes["oldtown"]) <= 2 and min(lanes["avenue"]) >= 4
    assert all(p.median > 0.0 for name in ("avenue", "highway") for p in scenes[name].layout.profiles)
    assert _building_share(scenes["highway"]) < 0.5 * _building_share(scenes["oldtown"])
    # "suburban" is the original world.
    default = StreetScene(0, 1000.0)
    assert np.array_equal(default.road.xy, scenes["suburban"].road.xy)
    assert default.layout.profiles == scenes["suburban"].layout.profiles


@pytest.mark.parametrize("scene", SCENE_STYLES[1:])
def test_each_scene_style_gives_a_registrable_scan(scene: str) -> None:
    points = SynthSequence(frames=2, seed=1, scene=scene, sensor=_small("hdl32")).frame(1)
    assert len(points) > 5_000 and np.mean(points[:, 2] > -1.0) > 0.02  # ground and structure


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
    ("kwargs", "word"),
    [
        ({"frames": 1}, "frames"),
        ({"seed": -1}, "seed"),
        ({"speed": 0.0}, "speed"),
        ({"sensor": "hdl128"}, "sensor"),
        ({"scene": "moon"}, "scene"),
        ({"height": 0.0}, "height"),
        ({"frame_period": 0.0}, "frame_period"),
        ({"window": 0}, "window"),
    ],
)
def test_bad_library_options_raise_config_errors(kwargs: dict, word: str) -> None:
    with pytest.raises(ConfigError, match=word):
        SynthSequence(**kwargs)


def test_unknown_sensor_or_scene_lists_the_choices() -> None:
    with pytest.raises(ConfigError, match="sensor: must be one of hdl64, hdl32, vlp16, os128"):
        SynthConfig(sensor="hdl128")
    with pytest.raises(ConfigError, match="scene: must be one of suburban, avenue, highway, oldtown"):
        SynthConfig(scene="moon")


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"min_range": 5.0, "max_range": 5.0}, "min_range must be below max_range; got 5 and 5"),
        ({"min_range": -1.0}, "min_range"),
        ({"beam_blocks": ((2.0, -24.8, 0),)}, "beam_blocks"),
        ({"beam_blocks": ()}, "beam_blocks"),
        ({"azimuth_steps": 0}, "azimuth_steps"),
        ({"dropout": 1.5}, "dropout"),
        ({"height": 0.1}, "height"),
    ],
)
def test_bad_sensor_settings_name_the_field(changes: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=f"SensorConfig: .*{message}"):
        SensorConfig(**changes)
    with pytest.raises(ConfigError, match=message):
        SensorConfig.model("vlp16").with_changes(**changes)


def test_config_round_trips_and_gives_the_same_drive_as_keywords() -> None:
    config = SynthConfig(frames=4, seed=5, sensor="vlp16", height=1.9, scene="oldtown", stops=True)
    assert config.sensor == SensorConfig.model("vlp16") and config.mounted_sensor.height == 1.9
    assert SynthConfig.from_dict(json.loads(json.dumps(config.to_dict()))) == config
    by_config, by_keywords = SynthSequence(config), SynthSequence(**config.to_dict())
    assert by_config.name == by_keywords.name == "synth-seed5-oldtown-vlp16"
    assert by_config.sensor == by_keywords.sensor and by_config.sensor.height == 1.9
    np.testing.assert_array_equal(by_config.gt_poses, by_keywords.gt_poses)
    assert SynthSequence(config, frames=6).frames == 6 and config.frames == 4
    with pytest.raises(TypeError, match="SynthConfig"):
        SynthSequence(40)  # type: ignore[arg-type]


def test_generate_sequence_reports_what_it_wrote(tmp_path: Path) -> None:
    config = SynthConfig(frames=2, seed=0, sensor=_small("vlp16"), height=2.0, frame_period=0.5)
    written = generate_sequence(tmp_path, seq="07", config=config, scene="highway")
    assert isinstance(written, WrittenSequence)
    assert written.seq_dir == tmp_path / "sequences" / "07"
    assert written.poses_file == tmp_path / "poses" / "07.txt" and written.poses_file.is_file()
    assert len(list((written.seq_dir / "velodyne").glob("*.bin"))) == 2
    assert (written.frames, written.sensor, written.height, written.scene) == (2, "vlp16", 2.0, "highway")
    assert written.duration == 0.5 and written.seconds > 0.0
    assert written.length > 1.0
    assert written.length == pytest.approx(SynthSequence(config, scene="highway").length)
    with pytest.raises(ConfigError, match="seq"):
        generate_sequence(tmp_path, seq="../x", frames=2)


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
        (["--sensor", "hdl128"], "--sensor"),
        (["--scene", "moon"], "--scene"),
        (["--height", "-1"], "--height"),
        (["--rate-hz", "0"], "--rate-hz"),
    ],
)
def test_cli_bad_options_name_the_option(tmp_path: Path, args: list[str], option: str) -> None:
    result = CliRunner().invoke(synth, ["--out", str(tmp_path), *args])
    assert result.exit_code == 2
    assert option in result.output


def test_cli_sensor_scene_height_stops_and_rate(tmp_path: Path) -> None:
    args = ["--frames", "3", "--sensor", "vlp16", "--scene", "highway", "--height", "2.0"]
    result = CliRunner().invoke(synth, ["--out", str(tmp_path), *args, "--stops", "--rate-hz", "2"])
    assert result.exit_code == 0, result.output
    assert "vlp16" in result.output and "highway" in result.output
    np.testing.assert_allclose(read_times(tmp_path / "sequences/00/times.txt"), [0.0, 0.5, 1.0])
    poses = read_kitti_poses(tmp_path / "poses/00.txt")
    np.testing.assert_allclose(poses[1], poses[0], atol=1e-12)  # standing start
    points = _read_bin(tmp_path / "sequences/00/velodyne/000000.bin")
    elevation = _elevations_deg(points)
    assert elevation.max() > 10.0 and elevation.min() >= -15.0 - 1e-3


def test_cli_help_documents_the_new_options() -> None:
    result = CliRunner().invoke(synth, ["--help"])
    for option in (
        "--sensor",
        "--height",
        "--scene",
        "--stops / --no-stops",
        "--rate-hz",
        "os128",
        "oldtown",
    ):
        assert option in result.output


def test_cli_requires_out() -> None:
    result = CliRunner().invoke(synth, [])
    assert result.exit_code == 2 and "--out" in result.output
