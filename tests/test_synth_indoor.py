"""The indoor scene (``--scene indoor``) and the OS0-128 (``--sensor os0``): determinism, a walk that
keeps clear of every wall and object, a loop that comes back and a return that comes back the other
way, scans that see floor, ceiling and walls, the OS0's 90 deg field, and the options it refuses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from click.testing import CliRunner

from vcr_odom.cli.main import cli
from vcr_odom.cli.synth import synth
from vcr_odom.errors import ConfigError
from vcr_odom.evaluation.revisits import true_revisits
from vcr_odom.geometry import invert, rotation_angle, transform_points
from vcr_odom.io import read_kitti_poses
from vcr_odom.synth import IndoorScene, SensorConfig, SynthConfig, SynthSequence, generate_sequence
from vcr_odom.synth.floorplan import CEILING_HEIGHT
from vcr_odom.synth.indoor import LAP_LENGTH
from vcr_odom.synth.sensor import SPINNING_MODELS

INDOOR = {"scene": "indoor", "motion": "handheld", "route": "loop", "frame_period": 0.5}
SMALL_OS0 = SensorConfig.model("os0").with_changes(azimuth_steps=256)
"""The OS0's 128 beams on a coarse azimuth grid: it casts fast."""


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _clearance(sequence: SynthSequence) -> np.ndarray:
    """Distance (m) from the sensor at every pose to the nearest triangle of the scene."""
    positions = sequence.world_poses[:, :3, 3]
    mesh = sequence.scene.mesh_near(positions[:, :2], 5.0)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.triangles.astype(np.uint32))
    )
    return scene.compute_distance(o3d.core.Tensor(positions.astype(np.float32))).numpy()


# -- the floor and the walk (poses and meshes: no ray casting) ---------------------------------------


@pytest.mark.parametrize(("seed", "route"), [(0, "loop"), (1, "return"), (2, "loop"), (3, "return")])
def test_the_walk_keeps_clear_of_walls_and_objects(seed: int, route: str) -> None:
    """Sampled 5 times a second over four minutes (several laps, or out and back): the sensor never
    comes within 0.4 m of anything (designed for 0.6 m); pace and turn rates stay a walker's."""
    sequence = SynthSequence(frames=1200, seed=seed, **{**INDOOR, "route": route, "frame_period": 0.2})
    assert _clearance(sequence).min() >= 0.4
    poses = sequence.world_poses
    speed = np.linalg.norm(np.diff(poses[:, :2, 3], axis=0), axis=1) / 0.2
    turn = np.degrees(rotation_angle(invert(poses[:-1]) @ poses[1:])) / 0.2
    assert speed.max() <= 1.7 and turn.max() <= 100.0  # corners: no look-around while turning one
    height = poses[:, 2, 3]  # the floor is at 0
    assert height.min() >= 1.1 and height.max() <= 1.7


def test_a_loop_comes_back_to_its_start_in_the_same_direction() -> None:
    sequence = SynthSequence(frames=180, seed=5, **INDOOR)  # the team's walk: 90 s at 2 Hz
    pairs = true_revisits(sequence, radius_m=2.0, min_path_m=30.0)
    assert pairs and min(p.target for p in pairs) < 5  # passes near the start again
    lap = sequence.scene.ring.lap().length
    assert LAP_LENGTH[0] <= lap <= LAP_LENGTH[1]
    assert 1.1 <= sequence.length / lap <= 1.35  # about 1.25 laps
    assert np.median([p.heading_deg for p in pairs]) < 45.0


def test_a_return_comes_back_past_its_start_the_other_way() -> None:
    sequence = SynthSequence(frames=180, seed=6, **{**INDOOR, "route": "return"})
    pairs = true_revisits(sequence, radius_m=2.0, min_path_m=30.0)
    assert pairs and min(p.target for p in pairs) < 5
    assert np.median([p.heading_deg for p in pairs]) > 135.0
    assert any(h.turn for h in sequence.scene.plan.halls)


def test_same_seed_same_floor_and_walk_and_the_floor_is_bounded() -> None:
    first = SynthSequence(frames=40, seed=7, **INDOOR)
    again = SynthSequence(frames=40, seed=7, **INDOOR)
    assert first.gt_poses.tobytes() == again.gt_poses.tobytes()
    a, b = (s.scene.mesh_near(s.world_poses[:, :2, 3], 51.0) for s in (first, again))
    assert a.vertices.tobytes() == b.vertices.tobytes() and a.albedo.tobytes() == b.albedo.tobytes()
    other = SynthSequence(frames=40, seed=8, **INDOOR)
    assert not np.allclose(other.gt_poses, first.gt_poses)
    # A walk of hours goes round a ring of at most 250 m: the floor stays the same few chunks.
    long = IndoorScene(7, "loop", travel=20_000.0)
    assert long.ring.lap().length == pytest.approx(LAP_LENGTH[1]) and long.cached_chunks <= 7


# -- scans -------------------------------------------------------------------------------------------


def test_same_seed_gives_byte_identical_files(tmp_path: Path) -> None:
    options = {**INDOOR, "frames": 3, "seed": 3, "sensor": SMALL_OS0}
    generate_sequence(tmp_path / "a", **options)
    generate_sequence(tmp_path / "b", **options)
    first, second = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert sorted(first) == sorted(second) and len(first) >= 6
    assert all(second[name] == content for name, content in first.items())


def test_scans_see_floor_ceiling_and_walls() -> None:
    sequence = SynthSequence(frames=2, seed=4, **INDOOR, sensor=SMALL_OS0)
    points = sequence.frame(1)
    assert len(points) > 0.9 * SMALL_OS0.n_rays  # a closed building: nearly every ray returns
    world = transform_points(sequence.world_poses[1], points[:, :3].astype(np.float64))
    sensor_z = sequence.world_poses[1, 2, 3]
    floor = np.abs(world[:, 2]) < 0.1
    ceiling = (world[:, 2] > sensor_z + 0.5) & (world[:, 2] <= CEILING_HEIGHT[1] + 0.7)
    walls = (world[:, 2] > 0.3) & (world[:, 2] < 2.0)
    assert floor.mean() > 0.1 and ceiling.mean() > 0.1 and walls.mean() > 0.2
    ranges = np.linalg.norm(points[:, :3], axis=1)
    assert ranges.min() >= 0.3 and ranges.max() <= 50.0


def test_os0_has_128_beams_over_90_degrees_and_all_of_them_return_indoors() -> None:
    sensor = SensorConfig.model("os0")
    assert sensor.name == "os0" and sensor.n_beams == 128 and sensor.azimuth_steps == 1024
    assert (sensor.min_range, sensor.max_range) == (0.3, 50.0) and "os0" in SPINNING_MODELS
    elevation = np.degrees(sensor.elevations)
    assert elevation.max() == pytest.approx(45.0) and elevation.min() == pytest.approx(-45.0)
    np.testing.assert_allclose(np.diff(elevation), -90.0 / 127)
    assert sensor.range_noise == SensorConfig.model("os128").range_noise  # the OS1-128's noise
    points = SynthSequence(frames=2, seed=1, **INDOOR, sensor=SMALL_OS0).frame(0)
    seen = np.degrees(np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1])))
    assert seen.min() < -44.5 and seen.max() > 44.5
    assert 1 + int(np.sum(np.diff(np.sort(seen)) > 0.05)) == 128  # every beam shows as a ring


def test_varied_drives_never_draw_the_indoor_scene_or_the_os0() -> None:
    drawn = [SynthSequence.varied(seed, frames=2) for seed in range(40)]
    assert all(s.scene_style != "indoor" and s.sensor.name != "os0" for s in drawn)


# -- options -----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"scene": "indoor"}, "motion: the indoor scene is walked, not driven: use motion 'handheld'"),
        ({"scene": "indoor", "motion": "car", "route": "loop"}, "--motion handheld"),
        (
            {"scene": "indoor", "motion": "handheld"},
            "route: the indoor scene is walked on route 'loop' or 'return'",
        ),
        ({"scene": "indoor", "motion": "handheld", "route": "figure8"}, "got 'figure8'"),
        ({"scene": "indoor", "motion": "handheld", "route": "blocks"}, "--route loop"),
        ({**INDOOR, "height": 2.0}, "height: at most 1.8 m in the indoor scene"),
    ],
)
def test_the_indoor_scene_refuses_what_it_cannot_do(options: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        SynthConfig(**options)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--scene", "indoor"], "--motion handheld"),
        (["--scene", "indoor", "--motion", "handheld"], "--route loop"),
        (["--scene", "indoor", "--motion", "handheld", "--route", "street"], "got 'street'"),
    ],
)
def test_cli_errors_name_the_option_and_what_it_expects(
    tmp_path: Path, args: list[str], message: str
) -> None:
    result = CliRunner().invoke(cli, ["synth", "--out", str(tmp_path), *args])
    assert result.exit_code == 2 and message in result.output
    assert not (tmp_path / "sequences").exists()


def test_cli_writes_an_indoor_walk(tmp_path: Path) -> None:
    args = ["--scene", "indoor", "--motion", "handheld", "--route", "return", "--sensor", "os0"]
    result = CliRunner().invoke(synth, ["--out", str(tmp_path), *args, "--frames", "2", "--rate-hz", "2"])
    assert result.exit_code == 0, result.output
    assert "indoor scene, route return" in result.output and "os0" in result.output
    assert len(read_kitti_poses(tmp_path / "poses/00.txt")) == 2
    help_text = CliRunner().invoke(synth, ["--help"]).output
    assert "indoor" in help_text and "os0" in help_text
