"""The kiss-icp polish's voxel from the first frame's density and reach: spinning 64-beam scans of a
street keep kiss-icp's own, sparse clouds get a finer one that gives the registration a spinning scan's
share of points, a cloud thinned coarser than that keeps kiss-icp's, whose map could not hold more of it
anyway, and a scan of rooms gets a grid in proportion to how far it reaches."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vcr_odom.data import open_sequence
from vcr_odom.errors import ConfigError
from vcr_odom.odometry.polish import KissIcpPolish, polish_kiss_config
from vcr_odom.odometry.polish_voxel import (
    MIN_REACH_VOXEL,
    ROOM_CELLS,
    ROOM_REACH,
    SPACING_FACTOR,
    SPARSE_SOURCE_POINTS,
    STREET_REACH,
    TARGET_SOURCE_POINTS,
    VOXEL_STEP,
    density_voxel,
    reach,
    reach_voxel,
    ring_structured,
    source_points,
)
from vcr_odom.odometry.run import RunSettings, method_for, polish_options
from vcr_odom.synth import SensorConfig, SynthSequence


def _walls(spacing: float, rng: np.random.Generator) -> np.ndarray:
    """A street canyon seen from its middle, sampled on a grid of ``spacing`` with a little jitter: two
    facades 8 m to each side, a wall 40 m ahead, and the road (what a narrow-field keyframe holds)."""
    along = np.arange(0.0, 40.0, spacing)
    up = np.arange(0.0, 10.0, spacing)
    a, u = np.meshgrid(along, up, indexing="ij")
    left = np.stack([a.ravel(), np.full(a.size, 8.0), u.ravel() - 1.7], axis=1)
    right = left * [1.0, -1.0, 1.0]
    across = np.arange(-8.0, 8.0, spacing)
    c, u2 = np.meshgrid(across, up, indexing="ij")
    ahead = np.stack([np.full(c.size, 40.0), c.ravel(), u2.ravel() - 1.7], axis=1)
    c3, a3 = np.meshgrid(across, along, indexing="ij")
    road = np.stack([a3.ravel(), c3.ravel(), np.full(c3.size, -1.7)], axis=1)
    cloud = np.concatenate([left, right, ahead, road])
    return cloud + rng.normal(scale=0.01, size=cloud.shape)


@pytest.mark.filterwarnings("ignore:.*no timestamps")
def test_real_64_beam_scans_keep_kiss_icps_voxel(kitti_sample_root: Path) -> None:
    sequence = open_sequence("00", data_root=kitti_sample_root)
    config = polish_kiss_config()
    for index in range(0, len(sequence), 10):
        points = np.asarray(sequence.frame(index))[:, :3].astype(np.float64)
        assert density_voxel(points, config) == config.mapping.voxel_size, index


def test_a_sparse_cloud_gets_the_largest_voxel_that_gives_the_target_points() -> None:
    cloud = _walls(0.25, np.random.default_rng(0))
    config = polish_kiss_config()
    kiss_voxel = config.mapping.voxel_size
    assert source_points(cloud, kiss_voxel) < TARGET_SOURCE_POINTS  # the premise: sparse at 1 m
    voxel = density_voxel(cloud, config)
    assert voxel < kiss_voxel
    assert source_points(cloud, voxel) >= TARGET_SOURCE_POINTS
    assert source_points(cloud, voxel / VOXEL_STEP) < TARGET_SOURCE_POINTS  # the largest on the ladder
    assert config.mapping.voxel_size == kiss_voxel  # the caller's configuration is not changed


def test_a_cloud_thinned_coarser_than_the_grid_keeps_a_grid_above_its_spacing() -> None:
    cloud = _walls(0.7, np.random.default_rng(1))
    config = polish_kiss_config()
    assert source_points(cloud, config.mapping.voxel_size) < TARGET_SOURCE_POINTS  # sparse at 1 m, yet
    assert VOXEL_STEP * config.mapping.voxel_size < SPACING_FACTOR * 0.7  # no finer grid is allowed
    assert density_voxel(cloud, config) == config.mapping.voxel_size


@pytest.mark.parametrize("adapt", [True, False])
def test_the_polish_fixes_its_voxel_on_the_first_frame(adapt: bool) -> None:
    rng = np.random.default_rng(2)
    sparse = _walls(0.25, rng)
    polish = KissIcpPolish(adapt_voxel=adapt)
    first = polish.prepare(sparse)
    expected = density_voxel(sparse, polish_kiss_config()) if adapt else 1.0
    assert polish.voxel_size == pytest.approx(expected)
    assert len(first.source) == source_points(sparse, expected)
    dense = _walls(0.05, rng)  # a later, denser frame does not move the grid the map is built on
    polish.prepare(dense)
    assert polish.voxel_size == pytest.approx(expected)


def test_a_voxel_given_is_kept_whatever_the_first_frame_says() -> None:
    """``--polish-voxel``: the user's grid for the whole run, built from the run settings."""
    sparse = _walls(0.25, np.random.default_rng(3))
    assert density_voxel(sparse, polish_kiss_config()) != pytest.approx(0.3)
    polish = KissIcpPolish(voxel_size=0.3)
    first = polish.prepare(sparse)
    assert polish.voxel_size == pytest.approx(0.3)
    assert len(first.source) == source_points(sparse, 0.3)

    assert polish_options(RunSettings(method="fpfh", polish_voxel=0.3)) == {"voxel_size": 0.3}
    assert polish_options(RunSettings(method="vcr")) == {}
    with pytest.raises(ConfigError, match="--polish-voxel applies to the kiss-icp polish, and vcr\\+icp"):
        method_for(RunSettings(method="vcr", polish="icp", polish_voxel=0.3))
    with pytest.raises(ConfigError, match="positive"):
        KissIcpPolish(voxel_size=0.0)


def _rings(
    beams: int, rng: np.random.Generator, radius: float = 15.0, span: float = 360.0, step: float = 0.2
) -> np.ndarray:
    """A spinning scan of a round room of ``radius`` m: ``beams`` rings over +-15 deg, ``span`` deg of
    azimuth sampled every ``step`` deg."""
    elevation = np.radians(np.linspace(-15.0, 15.0, beams))
    azimuth = np.radians(np.arange(0.0, span, step))
    e, a = np.meshgrid(elevation, azimuth, indexing="ij")
    directions = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)
    horizontal = np.hypot(directions[:, 0], directions[:, 1])
    distance = radius + rng.normal(scale=0.01, size=len(directions))
    return directions * distance[:, None] / horizontal[:, None]


def test_a_sparse_spinning_scan_of_a_street_keeps_kiss_icps_voxel() -> None:
    rings = _rings(16, np.random.default_rng(3), radius=40.0, span=90.0)  # a quarter: sparse at 40 m
    config = polish_kiss_config()
    assert reach(rings) >= STREET_REACH
    assert source_points(rings, config.mapping.voxel_size) < SPARSE_SOURCE_POINTS  # sparse, yet rings
    assert ring_structured(rings)
    assert not ring_structured(_walls(0.25, np.random.default_rng(4)))
    assert density_voxel(rings, config) == config.mapping.voxel_size


def test_a_dense_scan_of_a_room_gets_a_grid_of_its_reach() -> None:
    """Rings reaching 10 m: kiss-icp's voxel would leave a corridor a cell or two wide. (A spinning
    scan's rings take no density ladder, however few cells they fill.)"""
    rings = _rings(64, np.random.default_rng(5), radius=10.0)
    config = polish_kiss_config()
    assert ring_structured(rings)
    expected = reach(rings) / ROOM_CELLS
    assert 10.0 <= reach(rings) <= 10.4 and density_voxel(rings, config) == pytest.approx(expected)


def test_the_reach_voxel_keeps_kiss_icps_on_streets_and_shrinks_smoothly_indoors() -> None:
    """Shells of points at one range: the grid never jumps as the reach crosses the room and street
    bounds, kiss-icp's beyond a street's reach, reach / ROOM_CELLS within a room's, never below the floor."""
    directions = np.random.default_rng(6).normal(size=(2000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    reaches = np.arange(1.0, 60.0, 0.05)
    voxels = np.array([reach_voxel(directions * r, 1.0) for r in reaches])
    assert np.all(np.diff(voxels) >= 0.0) and np.abs(np.diff(voxels)).max() < 0.01
    assert np.all(voxels[reaches >= STREET_REACH] == 1.0)
    room = (reaches <= ROOM_REACH) & (reaches / ROOM_CELLS >= MIN_REACH_VOXEL)
    np.testing.assert_allclose(voxels[room], reaches[room] / ROOM_CELLS, rtol=1e-6)
    assert voxels.min() == MIN_REACH_VOXEL
    assert reach_voxel(directions * 10.0, 0.5) == pytest.approx(10.0 / ROOM_CELLS)  # another kiss voxel
    assert reach_voxel(directions * 40.0, 0.5) == 0.5  # is never exceeded


def test_the_synthetic_indoor_walks_first_scan_gets_a_fine_grid() -> None:
    """An OS0 scan of the synthetic floor (corridors 1.6-2.6 m wide): a grid of about 0.2 m, where
    kiss-icp's 1 m one overestimated the walk's length by 13 %."""
    sensor = SensorConfig.model("os0").with_changes(azimuth_steps=256)
    sequence = SynthSequence(
        frames=2, seed=901, scene="indoor", motion="handheld", route="loop", frame_period=0.5, sensor=sensor
    )
    points = sequence.frame(0)[:, :3].astype(np.float64)
    assert ring_structured(points)
    assert 0.1 <= density_voxel(points, polish_kiss_config()) <= 0.3


@pytest.mark.filterwarnings("ignore:.*no timestamps")
def test_a_runs_metrics_name_the_polish_voxel_it_chose(small_synthetic_root: Path, tmp_path: Path) -> None:
    """The grid a run's map was built on is in its metrics.json (it differs by sensor: a user comparing
    two runs must be able to see it), and it is the one the first frame chooses."""
    import json

    from vcr_odom.data.selection import FrameSelection
    from vcr_odom.odometry.run import RunSettings, run_sequence

    selection = FrameSelection(data_root=small_synthetic_root, seq="00")
    outcome = run_sequence(
        RunSettings(selection=selection, method="icp10", polish="kiss-icp", results_dir=tmp_path)
    )
    metrics = json.loads((outcome.folder / "metrics.json").read_text())
    first = open_sequence("00", data_root=small_synthetic_root).frame(0)
    expected = KissIcpPolish()
    expected.prepare(first)
    assert metrics["run"]["polish_voxel_m"] == pytest.approx(expected.voxel_size)
    unpolished = run_sequence(RunSettings(selection=selection, method="icp10", results_dir=tmp_path))
    assert json.loads((unpolished.folder / "metrics.json").read_text())["run"]["polish_voxel_m"] is None
