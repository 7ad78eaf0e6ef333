"""Synthetic routes that come back (``vcr-odom synth --route``): the revisits each route is built for
exist in the ground truth (checked with the library's revisit lister), a revisited place is the same
geometry every time, repeated blocks repeat exactly, and the default route is the original street."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree

from vcr_odom.cli.synth import synth
from vcr_odom.data.kitti import KittiSequence
from vcr_odom.errors import ConfigError
from vcr_odom.evaluation.revisits import true_revisits
from vcr_odom.geometry import transform_points
from vcr_odom.synth import SENSOR_MODELS, LidarSimulator, MeshPart, Surface, SynthConfig, SynthSequence
from vcr_odom.synth.courtyard import wall_samples
from vcr_odom.synth.layout import StreetLayout
from vcr_odom.synth.road import ROAD_STEP


def _distance_to(mesh: MeshPart, points: np.ndarray) -> np.ndarray:
    """Distance (m) from each point to the nearest triangle of ``mesh``."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.triangles.astype(np.uint32))
    )
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def _near(points: np.ndarray, metres: float = 40.0) -> np.ndarray:
    return points[np.linalg.norm(points[:, :3], axis=1) < metres, :3]


# -- the default is the open street -------------------------------------------------------------


def test_default_route_is_the_street_byte_for_byte() -> None:
    default = SynthSequence(frames=3, seed=0, sensor="vlp16")
    street = SynthSequence(frames=3, seed=0, sensor="vlp16", route="street")
    assert default.name == street.name == "synth-seed0-vlp16"
    assert default.gt_poses.tobytes() == street.gt_poses.tobytes()
    assert default.frame(2).tobytes() == street.frame(2).tobytes()
    poses = np.round(SynthSequence(frames=50, seed=3).gt_poses, 6)  # test_synth_handheld pins it too
    assert hashlib.sha256(poses.tobytes()).hexdigest() == (
        "ecc357fe9f5202e63ca86b5d4d1ece70242c71c07d01709dd43fc8f316d10bf8"
    )


# -- loop -----------------------------------------------------------------------------------------


def test_loop_is_driven_past_its_start_in_the_same_direction() -> None:
    sequence = SynthSequence(frames=600, seed=1, route="loop")
    laps = sequence.length / sequence.scene.road.length
    assert 1.1 < laps < 1.4  # sized to the drive: about 1.25 laps
    pairs = true_revisits(sequence)
    assert pairs and max(p.heading_deg for p in pairs) < 45.0  # same direction, same lane
    assert min(p.distance_m for p in pairs) < 0.5
    assert min(p.target for p in pairs) < 10  # the first frames' place is passed again


def test_a_short_walk_goes_round_a_short_loop() -> None:
    """A minute's walk (600 frames at 10 Hz, ~70 m) comes back to its start, as the campus loops
    people record with a handheld scanner do; a car's loop is a city block (250 m) at least."""
    walk = SynthSequence(frames=600, seed=881, route="loop", motion="handheld", sensor="avia")
    assert walk.scene.road.length < 70.0
    pairs = true_revisits(walk)
    assert pairs and min(p.distance_m for p in pairs) < 0.5 and min(p.target for p in pairs) < 30
    car = SynthSequence(frames=60, seed=881, route="loop")
    assert car.scene.road.length >= 250.0


def test_a_short_walk_goes_round_a_building_in_a_courtyard() -> None:
    """A short walked loop circles a building on a footpath a couple of metres from its walls, with
    buildings facing it across a lawn, as on a campus: the walk stays clear of every wall, and the
    walls are what its frames see (a street bent into a 55 m loop had nothing inside it)."""
    walk = SynthSequence(frames=600, seed=881, route="loop", motion="handheld", sensor="avia")
    courtyard = walk.scene.layout.features.courtyard
    assert courtyard is not None and courtyard.outer
    world = walk.world_poses
    inner = cKDTree(wall_samples(courtyard.inner))
    outer = cKDTree(np.concatenate([wall_samples(facade, closed=False) for facade in courtyard.outer]))
    to_inner, to_outer = inner.query(world[:, :2, 3])[0], outer.query(world[:, :2, 3])[0]
    assert to_inner.min() > 1.5 and to_inner.max() < 8.0  # a couple of metres from the walls
    assert to_outer.min() > 6.0  # across a lawn
    on_walls = []  # share of each frame's points on the courtyard's walls
    for i in range(0, len(world), 30):
        plan = transform_points(world[i], _near(walk.frame(i), 40.0))[:, :2]
        on_walls.append(np.mean(np.minimum(inner.query(plan)[0], outer.query(plan)[0]) < 0.5))
    assert np.mean(np.array(on_walls) >= 0.05) >= 0.8, np.round(on_walls, 2)
    # a car's loop keeps its street: no courtyard
    assert SynthSequence(frames=60, seed=881, route="loop").scene.layout.features.courtyard is None


def test_a_revisited_place_is_the_same_geometry() -> None:
    """The scene is a function of the seed and route, not of time: the world built for a later window
    casts the same scan, and the later frame lies on the geometry around the earlier one."""
    sequence = SynthSequence(frames=400, seed=1, route="loop", sensor="vlp16", window=50)
    pair = min(true_revisits(sequence), key=lambda p: p.distance_m)
    i, j = pair.target, pair.source
    assert j // 50 != i // 50
    world = sequence.world_poses
    early = sequence._simulator(i // 50).scan(world[i], np.random.default_rng(7))
    late = sequence._simulator(j // 50).scan(world[i], np.random.default_rng(7))
    assert early.tobytes() == late.tobytes()
    around_i = sequence.scene.mesh_near(world[i : i + 1, :2, 3], 60.0)
    gap = _distance_to(around_i, transform_points(world[j], _near(sequence.frame(j))))
    assert np.median(gap) < 0.02 and np.percentile(gap, 90) < 0.08


# -- figure eight ---------------------------------------------------------------------------------


def _inside_lanes(layout: StreetLayout, station: float, xy: np.ndarray) -> np.ndarray:
    """Whether points lie within the lanes of the stretch of road around ``station``."""
    index = np.arange(len(layout.road.xy))
    branch = index[np.abs(index * ROAD_STEP - station) < 80.0]
    _, nearest = cKDTree(layout.road.xy[branch]).query(xy)
    sample = branch[nearest]
    heading = layout.road.heading[sample]
    rel = xy - layout.road.xy[sample]
    signed = np.cos(heading) * rel[:, 1] - np.sin(heading) * rel[:, 0]
    profile = layout.profile_at(station)
    edge = np.where(signed > 0, profile.lane_edge(1), profile.lane_edge(0))
    return np.abs(signed) < edge - 0.1


def test_figure8_crosses_itself_and_keeps_the_crossing_clear() -> None:
    sequence = SynthSequence(frames=600, seed=2, route="figure8")
    scene = sequence.scene
    (first, _), (second, _) = scene.layout.junctions
    crossing = scene.road.sample([first])[0][0]
    assert np.linalg.norm(scene.road.sample([second])[0][0] - crossing) < 1.0
    turned = [p for p in true_revisits(sequence) if p.heading_deg > 80.0]
    assert turned and all(p.heading_deg < 120.0 for p in turned)
    places = sequence.world_poses[[p.source for p in turned], :2, 3]
    assert np.linalg.norm(places - crossing, axis=1).max() < 10.0
    blocks = [key for key in scene.chunks_near(crossing, 40.0) if key[0] == 0]
    mesh = MeshPart.concatenate([scene.chunk(key) for key in blocks])
    solid = mesh.surface != Surface.PAINT
    centroids = mesh.vertices[mesh.triangles[solid]].mean(axis=1)[:, :2]
    centroids = centroids[np.linalg.norm(centroids - crossing, axis=1) < 40.0]
    assert len(centroids) > 1000
    for station in (first, second):
        assert not _inside_lanes(scene.layout, station, centroids).any()


# -- out and back ---------------------------------------------------------------------------------


def test_return_comes_back_the_other_way_a_lane_apart() -> None:
    sequence = SynthSequence(frames=600, seed=1, route="return")
    pairs = true_revisits(sequence)
    headings = np.array([p.heading_deg for p in pairs])
    distances = np.array([p.distance_m for p in pairs])
    assert len(pairs) > 100 and np.median(headings) > 175.0
    assert 2.5 < np.median(distances) < 5.0  # the other lane, a few metres to the side
    start = sequence.world_poses[0, :2, 3]
    late = sequence.world_poses[len(sequence) // 2 :, :2, 3]
    assert np.linalg.norm(late - start, axis=1).min() < 5.0  # back past the start


# -- repeated blocks ------------------------------------------------------------------------------


def test_blocks_repeat_exactly_and_are_never_revisited() -> None:
    sequence = SynthSequence(frames=400, seed=1, route="blocks", sensor="vlp16")
    scene = sequence.scene
    period = scene._repeated.period
    assert 30.0 <= period <= 60.0
    assert not true_revisits(sequence)
    shift = np.array([period, 0.0, 0.0])
    np.testing.assert_allclose(scene.chunk((0, 5, 0)).vertices + shift, scene.chunk((0, 6, 0)).vertices)
    # The same spot one block on casts the same scan.
    here = sequence.world_poses[100].copy()
    there = here.copy()
    there[:3, 3] += shift
    simulator = LidarSimulator(scene.mesh_near(np.stack([here, there])[:, :2, 3], 101.0), sequence.sensor)
    first = simulator.scan(here, np.random.default_rng(1))
    second = simulator.scan(there, np.random.default_rng(1))
    assert len(first) == len(second) > 10_000
    np.testing.assert_allclose(first[:, :3], second[:, :3], atol=1e-3)
    # A frame about one block on, moved back by B, lies on the geometry around the earlier frame.
    world = sequence.world_poses
    later = int(np.argmin(np.abs(world[:, 0, 3] - world[100, 0, 3] - period)))
    around = scene.mesh_near(world[100:101, :2, 3], 60.0)
    gap = _distance_to(around, transform_points(world[later], _near(sequence.frame(later))) - shift)
    assert np.median(gap) < 0.02 and np.percentile(gap, 90) < 0.08


# -- every sensor, the walker, the CLI -------------------------------------------------------------


SENSOR_ROUTES = ["loop", "figure8", "return", "blocks", "loop", "figure8", "return"]
"""A route for each of SENSOR_MODELS, in its order."""


@pytest.mark.parametrize(("sensor", "route"), list(zip(SENSOR_MODELS, SENSOR_ROUTES, strict=True)))
def test_every_sensor_scans_the_routes(sensor: str, route: str) -> None:
    sequence = SynthSequence(frames=400, seed=4, route=route, sensor=sensor)
    pairs = true_revisits(sequence)
    frame = pairs[0].source if pairs else 200  # where it comes back: a crossing, the way back
    points = sequence.frame(frame)
    assert points.dtype == np.float32 and np.isfinite(points).all()
    assert len(points) > 2_000


@pytest.mark.parametrize("route", ["loop", "figure8", "return", "blocks"])
def test_a_walker_follows_every_route_on_the_carriageway(route: str) -> None:
    frames = {"loop": 2600, "figure8": 2600, "return": 1300, "blocks": 300}[route]
    sequence = SynthSequence(frames=frames, seed=3, route=route, motion="handheld")
    world = sequence.world_poses
    distance, edges, _ = sequence.scene.layout.lateral(world[:, :2, 3])
    assert (distance < edges[:, 0]).all()  # within some road's lanes, clear of the roadside
    assert bool(true_revisits(sequence)) == (route != "blocks")


def test_cli_writes_a_loop_that_reads_back(tmp_path: Path) -> None:
    args = ["--out", str(tmp_path), "--seq", "07", "--route", "loop", "--frames", "4", "--sensor", "vlp16"]
    result = CliRunner().invoke(synth, args)
    assert result.exit_code == 0, result.output
    assert "route loop" in result.output
    read = KittiSequence(tmp_path, "07")
    assert len(read) == 4
    np.testing.assert_allclose(read.gt_poses, SynthSequence(frames=4, route="loop").gt_poses, atol=1e-6)


def test_bad_route_is_an_error_naming_the_option(tmp_path: Path) -> None:
    result = CliRunner().invoke(synth, ["--out", str(tmp_path), "--route", "spiral"])
    assert result.exit_code == 2 and "--route" in result.output
    with pytest.raises(ConfigError, match="route"):
        SynthConfig(route="spiral")
