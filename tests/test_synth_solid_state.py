"""Solid-state sensor presets (``avia``, ``mid360``): field of view, coverage, non-repetitive patterns,
point rate and configuration errors; and a fingerprint of the spinning presets' scans, which must not
move (shipped weights and training caches were made from them)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree

from vcr_odom.cli.synth import synth
from vcr_odom.errors import ConfigError
from vcr_odom.synth import SENSOR_MODELS, LidarSimulator, MeshPart, SensorConfig, Surface, SynthSequence
from vcr_odom.synth.mesh import MeshBuilder
from vcr_odom.synth.sensor import SOLID_STATE_MODELS, SPINNING_MODELS

# Published fields of view, written out rather than read from the presets so a wrong preset fails:
# (lowest azimuth, highest azimuth, lowest elevation, highest elevation) in degrees, and points/s.
SOLID_STATE_SPECS = {
    "avia": ((-35.2, 35.2, -38.6, 38.6), 240_000),
    "mid360": ((-180.0, 180.0, -7.0, 52.0), 200_000),
}


def _angles_deg(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (deg) of directions or points ``(n, >=3)``."""
    xyz = directions[:, :3].astype(np.float64)
    return (
        np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0])),
        np.degrees(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1]))),
    )


def _coverage(directions: np.ndarray, bounds: tuple[float, ...], cell: float, radius: float | None) -> float:
    """Share of ``cell``-degree azimuth x elevation cells hit by at least one ray, over the cells of
    ``bounds`` (only those centred within ``radius`` deg of the middle, for a round field of view)."""
    azimuth, elevation = _angles_deg(directions)
    az_edges = np.arange(bounds[0], bounds[1] + 1e-9, cell)
    el_edges = np.arange(bounds[2], bounds[3] + 1e-9, cell)
    hits, _, _ = np.histogram2d(azimuth, elevation, [az_edges, el_edges])
    if radius is None:
        return float(np.mean(hits > 0))
    az_mid, el_mid = (az_edges[:-1] + az_edges[1:]) / 2, (el_edges[:-1] + el_edges[1:]) / 2
    centre = (bounds[2] + bounds[3]) / 2
    inside = np.hypot(az_mid[:, None], el_mid[None, :] - centre) < radius
    return float(np.mean(hits[inside] > 0))


def _room(furnished: bool = True) -> MeshPart:
    """A closed box around the sensor (every ray hits) and, furnished, a tree trunk and a glass box."""
    builder = MeshBuilder()
    x0, x1, y0, y1, z0, z1 = -20.0, 25.0, -15.0, 18.0, -1.8, 9.0
    floor = [[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0]]
    builder.hexahedron(floor + [[x, y, z1] for x, y, _ in floor], Surface.WALL, 0.5)
    if not furnished:
        return builder.build()
    builder.cylinder([6.0, 3.0, -1.8], [0.0, 0.0, 1.0], 0.4, 5.0, Surface.VEGETATION, 0.4)
    block = [[8.0, -6.0, -1.8], [12.0, -6.0, -1.8], [12.0, -3.0, -1.8], [8.0, -3.0, -1.8]]
    builder.hexahedron(block + [[x, y, 0.0] for x, y, _ in block], Surface.GLASS, 0.3)
    return builder.build()


@pytest.fixture(scope="module")
def room() -> MeshPart:
    return _room()


ROOM_POSE = np.eye(4)
ROOM_POSE[:3, 3] = [0.3, -0.2, 0.1]


# -- presets --------------------------------------------------------------------------------------


def test_solid_state_presets_are_listed_after_the_spinning_ones() -> None:
    assert SENSOR_MODELS == SPINNING_MODELS + SOLID_STATE_MODELS
    assert SOLID_STATE_MODELS == ("avia", "mid360")
    assert all(SensorConfig.model(name).spinning for name in SPINNING_MODELS)
    assert [SensorConfig.model(name).pattern for name in SOLID_STATE_MODELS] == ["rosette", "mid360"]
    # Varied drives keep drawing spinning sensors only: the same seeds give the same drives.
    assert {SynthSequence.varied(seed).sensor.name for seed in range(30)} <= set(SPINNING_MODELS)


@pytest.mark.parametrize("name", SOLID_STATE_MODELS)
def test_rays_fill_the_published_field_of_view(name: str) -> None:
    bounds, points_per_second = SOLID_STATE_SPECS[name]
    sensor = SensorConfig.model(name)
    directions = sensor.directions()
    assert directions.shape == (sensor.n_rays, 3) == (round(points_per_second * 0.1), 3)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
    azimuth, elevation = _angles_deg(directions)
    tolerance = 1e-6
    assert bounds[0] - tolerance <= azimuth.min() and azimuth.max() <= bounds[1] + tolerance
    assert bounds[2] - tolerance <= elevation.min() and elevation.max() <= bounds[3] + tolerance
    # One frame reaches every edge of the field of view (within half a degree).
    assert azimuth.min() < bounds[0] + 0.5 and azimuth.max() > bounds[1] - 0.5
    assert elevation.min() < bounds[2] + 0.5 and elevation.max() > bounds[3] - 0.5


def test_one_avia_frame_covers_its_round_field_of_view() -> None:
    avia = SensorConfig.model("avia")
    bounds = SOLID_STATE_SPECS["avia"][0]
    assert _coverage(avia.directions(), bounds, cell=2.0, radius=33.0) > 0.9
    # Denser with integration time: a 1-degree grid fills in over half a second.
    assert _coverage(avia.directions(0.0, 0.1), bounds, 1.0, 33.0) < 0.95
    assert _coverage(avia.directions(0.0, 0.5), bounds, 1.0, 33.0) > 0.99


def test_one_mid360_frame_covers_its_band() -> None:
    mid360 = SensorConfig.model("mid360")
    bounds = SOLID_STATE_SPECS["mid360"][0]
    assert _coverage(mid360.directions(), bounds, cell=3.0, radius=None) > 0.95
    assert _coverage(mid360.directions(), bounds, cell=2.0, radius=None) > 0.9
    assert _coverage(mid360.directions(0.0, 0.1), bounds, 1.0, None) < 0.8
    assert _coverage(mid360.directions(0.0, 0.5), bounds, 1.0, None) > 0.99


# -- non-repetitive patterns -------------------------------------------------------------------------


@pytest.mark.parametrize("name", SOLID_STATE_MODELS)
def test_consecutive_frames_share_no_ray(name: str) -> None:
    sensor = SensorConfig.model(name)
    first, second = sensor.directions(0.0), sensor.directions(0.1)
    # The second frame continues the first: together they are the first 0.2 s of scanning.
    both = sensor.directions(0.0, 0.2).reshape(sensor.n_beams, -1, 3)
    halves = both[:, : both.shape[1] // 2], both[:, both.shape[1] // 2 :]
    np.testing.assert_allclose(halves[0].reshape(-1, 3), first, atol=1e-9)
    np.testing.assert_allclose(halves[1].reshape(-1, 3), second, atol=1e-9)
    distance, _ = cKDTree(first).query(second)
    assert distance.min() > 1e-5  # radians: 2 mm at 200 m
    # Any later frame differs too (a pattern that closed after one frame would repeat here).
    for start in (1.0, 17.3):
        distance, _ = cKDTree(first).query(sensor.directions(start))
        assert distance.min() > 1e-5


@pytest.mark.parametrize("name", SOLID_STATE_MODELS)
def test_scans_continue_from_their_time_or_draw_a_random_one(name: str, room: MeshPart) -> None:
    simulator = LidarSimulator(room, SensorConfig.model(name))

    def scan(seed: int, time: float | None) -> np.ndarray:
        return simulator.scan(ROOM_POSE, np.random.default_rng(seed), time)

    np.testing.assert_array_equal(scan(1, None), scan(1, None))
    np.testing.assert_array_equal(scan(1, 0.3), scan(1, 0.3))
    for first, second in ((scan(1, None), scan(2, None)), (scan(1, 0.0), scan(1, 0.1))):
        unit = [p[:, :3] / np.linalg.norm(p[:, :3], axis=1, keepdims=True) for p in (first, second)]
        distance, _ = cKDTree(unit[0]).query(unit[1])
        assert np.median(distance) > 1e-3  # range noise moves a direction by about 1e-3 rad at 20 m


# -- point rate -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", SOLID_STATE_MODELS)
def test_a_closed_box_returns_points_per_second_times_the_period(name: str) -> None:
    sensor = SensorConfig.model(name)
    rays = SOLID_STATE_SPECS[name][1] * 0.1
    box = _room(furnished=False)
    points = LidarSimulator(box, sensor).scan(ROOM_POSE, np.random.default_rng(3))
    assert points.dtype == np.float32 and points.shape[1] == 4
    # Every ray hits a plain wall: only the 2 % dropout loses any (within 5 sigma of a binomial).
    assert sensor.n_rays == rays
    kept = 1.0 - sensor.dropout
    assert abs(len(points) - rays * kept) < 5.0 * np.sqrt(rays * kept * sensor.dropout)
    ranges = np.linalg.norm(points[:, :3], axis=1)
    assert sensor.min_range <= ranges.min() and ranges.max() <= sensor.max_range
    assert points[:, 3].min() >= 0.0 and points[:, 3].max() <= 1.0
    longer = LidarSimulator(box, sensor.with_changes(integration_time=0.25))
    assert len(longer.scan(ROOM_POSE, np.random.default_rng(3))) == pytest.approx(2.5 * len(points), rel=0.01)


# -- the spinning presets do not move -------------------------------------------------------------------

# Measured before the solid-state patterns were added (same code path for every spinning preset):
# points, mean xyz, reflectance sum, and three points (first, middle, last).
SPINNING_FINGERPRINTS = {
    "hdl64": (
        128188, [-0.32469, 0.50289, -1.41061], 48320.1,
        [[-20.3217, -1.2521, 0.711], [6.5173, 10.3594, -1.9013], [-4.1211, -0.005, -1.9042]],
    ),
    "os128": (
        127079, [0.02794, 0.59104, 1.30538], 51564.16,
        [[-20.3302, 0.016, 8.4211], [22.2425, 18.2246, 0.0889], [-4.5821, -0.0245, -1.898]],
    ),
}  # fmt: skip


@pytest.mark.parametrize("name", SPINNING_FINGERPRINTS)
def test_spinning_scans_are_those_of_earlier_versions(name: str, room: MeshPart) -> None:
    count, mean, reflectance, samples = SPINNING_FINGERPRINTS[name]
    simulator = LidarSimulator(room, SensorConfig.model(name))
    points = simulator.scan(ROOM_POSE, np.random.default_rng(11), time=5.0)  # time: no effect
    assert len(points) == count
    np.testing.assert_allclose(points[:, :3].astype(np.float64).mean(0), mean, atol=2e-5)
    assert float(points[:, 3].astype(np.float64).sum()) == pytest.approx(reflectance, abs=1.0)
    np.testing.assert_allclose(points[[0, count // 2, -1], :3], samples, atol=2e-4)


def test_spinning_directions_take_no_scan_time() -> None:
    with pytest.raises(ValueError, match="one revolution"):
        SensorConfig().directions(0.1)
    with pytest.raises(ValueError, match="beam elevations"):
        _ = SensorConfig.model("avia").elevations


# -- configuration errors --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"pattern": "flash"}, "pattern"),
        ({"points_per_second": 0.0}, "points_per_second"),
        ({"points_per_second": 5.0}, "points_per_second"),
        ({"integration_time": 0.0}, "integration_time"),
        ({"integration_time": 2.0}, "integration_time"),
        ({"channels": 0}, "channels"),
        ({"horizontal_fov": 200.0}, "horizontal_fov"),
        ({"horizontal_fov": 0.0}, "horizontal_fov"),
        ({"elevation_fov": (10.0, -10.0)}, "elevation_fov"),
        ({"elevation_fov": (-95.0, 10.0)}, "elevation_fov"),
        ({"channels": 1}, "elevation_fov"),
        ({"min_range": 300.0}, "min_range"),
    ],
)
def test_bad_rosette_settings_name_the_field(changes: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=f"SensorConfig: .*{field}"):
        SensorConfig.model("avia").with_changes(**changes)


@pytest.mark.parametrize(
    ("name", "changes", "field"),
    [
        ("mid360", {"horizontal_fov": 180.0}, "horizontal_fov"),
        ("mid360", {"points_per_second": None}, "points_per_second"),
        ("mid360", {"elevation_fov": None}, "elevation_fov"),
        ("hdl64", {"channels": 6}, "channels"),
        ("vlp16", {"integration_time": 0.1}, "integration_time"),
        ("hdl64", {"pattern": "rosette"}, "points_per_second"),
    ],
)
def test_each_pattern_takes_its_own_fields(name: str, changes: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=f"SensorConfig: .*{field}"):
        SensorConfig.model(name).with_changes(**changes)


# -- end to end -------------------------------------------------------------------------------------------


def test_cli_writes_an_avia_sequence(tmp_path: Path) -> None:
    result = CliRunner().invoke(synth, ["--out", str(tmp_path), "--frames", "2", "--sensor", "avia"])
    assert result.exit_code == 0, result.output
    assert "avia" in result.output
    bins = sorted((tmp_path / "sequences/00/velodyne").glob("*.bin"))
    frames = [np.fromfile(path, dtype=np.float32).reshape(-1, 4) for path in bins]
    assert len(frames) == 2 and all(len(points) > 5_000 for points in frames)
    bounds = SOLID_STATE_SPECS["avia"][0]
    for points in frames:
        azimuth, elevation = _angles_deg(points)
        assert bounds[0] - 1e-3 <= azimuth.min() and azimuth.max() <= bounds[1] + 1e-3
        assert bounds[2] - 1e-3 <= elevation.min() and elevation.max() <= bounds[3] + 1e-3
        ranges = np.linalg.norm(points[:, :3], axis=1)
        assert ranges.min() >= 1.0 and ranges.max() <= 190.0
        ground = points[(ranges < 15.0) & (points[:, 2] < -1.2)]  # the road ahead, 1.73 m down
        assert abs(np.median(ground[:, 2]) + 1.73) < 0.1
    help_text = CliRunner().invoke(synth, ["--help"]).output
    assert "avia" in help_text and "mid360" in help_text
