"""The kiss-icp polish's point-to-plane finish: normals from the frame's own denser cloud, a fit that
lands on the true pose from a start off along every axis, a single plane that leaves what it cannot
measure where it was, a finish too large to be one refused, and the polish finishing point to plane
on raw sparse scans only, not on spinning rings nor grid-thinned keyframes (the first frame decides,
and metrics.json says so)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from vcr_odom.data import open_sequence
from vcr_odom.geometry import invert, make_transform, motion_difference, transform_points
from vcr_odom.odometry.plane_refinement import refine_point_to_plane, registration_normals
from vcr_odom.odometry.polish import KissIcpPolish, polish_kiss_config
from vcr_odom.odometry.polish_voxel import raw_sparse_scan, thinned
from vcr_odom.synth import SensorConfig, SynthSequence


def _grid(spacing: float, extent: tuple[float, float], height: float) -> tuple[np.ndarray, np.ndarray]:
    a, u = np.meshgrid(np.arange(*extent, spacing), np.arange(0.0, height, spacing), indexing="ij")
    return a.ravel(), u.ravel()


def _canyon(spacing: float, rng: np.random.Generator) -> np.ndarray:
    """Facades 6 m to either side, a wall 25 m ahead and the road: every direction is measured."""
    along, up = _grid(spacing, (0.0, 25.0), 8.0)
    left = np.stack([along, np.full(along.size, 6.0), up - 1.5], axis=1)
    right = left * [1.0, -1.0, 1.0]
    across, up2 = _grid(spacing, (-6.0, 6.0), 8.0)
    ahead = np.stack([np.full(across.size, 25.0), across, up2 - 1.5], axis=1)
    road = _road(spacing)
    cloud = np.concatenate([left, right, ahead, road])
    return cloud + rng.normal(scale=0.002, size=cloud.shape)


def _road(spacing: float) -> np.ndarray:
    along, across = _grid(spacing, (0.0, 25.0), 12.0)
    return np.stack([along, across - 6.0, np.full(along.size, -1.5)], axis=1)


def _frame_at(world: np.ndarray, pose: np.ndarray) -> np.ndarray:
    return transform_points(invert(pose), world)


TRUE_POSE = make_transform(Rotation.from_euler("z", 3.0, degrees=True).as_matrix(), [2.0, 0.5, 0.1])


def _start_off(pose: np.ndarray, offset: list[float], degrees: float) -> np.ndarray:
    turn = make_transform(
        Rotation.from_euler("zyx", [degrees, degrees / 2, 0.0], degrees=True).as_matrix(), offset
    )
    return turn @ pose


def test_normals_are_the_planes_own() -> None:
    normal = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
    u = np.cross(normal, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    s, t = np.meshgrid(np.linspace(-3, 3, 40), np.linspace(-3, 3, 40))
    plane = s.reshape(-1, 1) * u + t.reshape(-1, 1) * v + 5.0 * normal
    normals = registration_normals(plane[::7], plane)
    assert np.allclose(np.abs(normals @ normal), 1.0, atol=1e-9)
    assert np.isnan(registration_normals(plane[:2], plane[:2])).all()  # too few for a plane


def test_a_start_off_along_every_axis_finishes_on_the_true_pose() -> None:
    rng = np.random.default_rng(0)
    world_map = _canyon(0.1, rng)
    frame = _frame_at(_canyon(0.15, rng), TRUE_POSE)
    source = frame[::9]  # the registration's sparse points; normals from the denser frame
    start = _start_off(TRUE_POSE, [0.08, -0.05, 0.03], 0.5)
    finished = refine_point_to_plane(start, source, registration_normals(source, frame), world_map, sigma=0.1)
    error_m, error_deg = motion_difference(finished, TRUE_POSE)
    assert error_m < 0.005 and error_deg < 0.05
    assert motion_difference(start, TRUE_POSE)[0] > 0.08  # the premise: the start was off


def test_a_single_plane_leaves_what_it_cannot_measure_where_it_was() -> None:
    road = _road(0.1)
    frame = _frame_at(_road(0.15), TRUE_POSE)
    source = frame[::9]
    start = _start_off(TRUE_POSE, [0.2, 0.1, 0.05], 0.0)
    finished = refine_point_to_plane(start, source, registration_normals(source, frame), road, sigma=0.1)
    assert abs(finished[2, 3] - TRUE_POSE[2, 3]) < 0.005  # across the road: measured
    assert np.allclose(finished[:2, 3], start[:2, 3], atol=0.001)  # along it: kept


def test_a_finish_larger_than_the_gate_keeps_the_point_to_point_fit() -> None:
    rng = np.random.default_rng(1)
    world_map = _canyon(0.1, rng)
    frame = _frame_at(_canyon(0.15, rng), TRUE_POSE)
    source = frame[::9]
    normals = registration_normals(source, frame)
    start = _start_off(TRUE_POSE, [0.08, 0.08, 0.0], 0.0)  # each axis within the gate, the whole not
    assert (
        motion_difference(refine_point_to_plane(start, source, normals, world_map, sigma=0.05), TRUE_POSE)[0]
        < 0.005
    )
    assert np.array_equal(refine_point_to_plane(start, source, normals, world_map, sigma=0.03), start)
    assert np.array_equal(refine_point_to_plane(start, source, normals, world_map[:5], sigma=0.1), start)


def _avia_scan(seed: int) -> np.ndarray:
    """A raw synthetic Livox Avia-like rosette scan of a handheld walk's first frame."""
    sequence = SynthSequence(
        frames=2, seed=seed, scene="oldtown", motion="handheld", sensor=SensorConfig.model("avia")
    )
    return sequence.frame(0)[:, :3].astype(np.float64)


def _grid_thinned(points: np.ndarray, cell: float) -> np.ndarray:
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    return np.asarray(cloud.voxel_down_sample(cell).points)


def test_a_cloud_thinned_on_a_grid_is_told_from_a_raw_scan() -> None:
    raw = _avia_scan(2)
    assert not thinned(raw)
    assert thinned(_grid_thinned(raw, 0.2))
    assert thinned(_canyon(0.3, np.random.default_rng(5)))  # a regular grid, jittered


@pytest.mark.filterwarnings("ignore:.*no timestamps")
def test_the_polish_finishes_point_to_plane_on_raw_sparse_scans_only(kitti_sample_root: Path) -> None:
    raw = _avia_scan(1)
    assert raw_sparse_scan(raw, polish_kiss_config())
    polish = KissIcpPolish()
    polish.prepare(raw)
    assert polish.point_to_plane and polish.kiss.point_to_plane
    kitti_frame = np.asarray(open_sequence("00", data_root=kitti_sample_root).frame(0))[:, :3]
    polish.prepare(kitti_frame)
    assert polish.point_to_plane  # the first frame decided, as it does for the voxel

    for first in (kitti_frame, _grid_thinned(raw, 0.2)):  # spinning rings; a keyframe cloud
        other = KissIcpPolish()
        other.prepare(first)
        assert not other.point_to_plane and not other.kiss.point_to_plane

    given_voxel = KissIcpPolish(voxel_size=0.3)  # decided on kiss-icp's own voxel, not the one given
    given_voxel.prepare(raw)
    assert given_voxel.point_to_plane
    for forced, first in ((False, raw), (True, kitti_frame)):  # the option wins over the first frame
        chosen = KissIcpPolish(point_to_plane=forced)
        chosen.prepare(first)
        assert chosen.point_to_plane is forced and chosen.kiss.point_to_plane is forced
    surfaces = KissIcpPolish(engine="vgicp")  # its fit pairs surfaces: no finish unless asked for
    surfaces.prepare(raw)
    assert not surfaces.point_to_plane and not surfaces.kiss.point_to_plane
    asked = KissIcpPolish(engine="vgicp", point_to_plane=True)
    asked.prepare(raw)
    assert asked.point_to_plane and asked.kiss.point_to_plane


@pytest.mark.filterwarnings("ignore:.*no timestamps")
def test_a_runs_metrics_say_whether_the_polish_finished_point_to_plane(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    from vcr_odom.data.selection import FrameSelection
    from vcr_odom.odometry.run import RunSettings, polish_options, run_sequence

    selection = FrameSelection(data_root=small_synthetic_root, seq="00")
    outcome = run_sequence(
        RunSettings(selection=selection, method="icp10", polish="kiss-icp", results_dir=tmp_path)
    )
    first = np.asarray(open_sequence("00", data_root=small_synthetic_root).frame(0))[:, :3]
    expected = raw_sparse_scan(first.astype(np.float64), polish_kiss_config())
    metrics = json.loads((outcome.folder / "metrics.json").read_text())
    assert metrics["run"]["polish_point_to_plane"] is expected
    for choice in ("on", "off"):  # --point-to-plane: the user's choice wins over the first frame
        forced = run_sequence(
            RunSettings(
                selection=selection,
                method="icp10",
                polish="kiss-icp",
                results_dir=tmp_path,
                point_to_plane=choice,
            )
        )
        forced_metrics = json.loads((forced.folder / "metrics.json").read_text())
        assert forced_metrics["run"]["polish_point_to_plane"] is (choice == "on")
    assert polish_options(RunSettings(method="vcr", point_to_plane="off")) == {"point_to_plane": False}
    assert polish_options(RunSettings(method="vcr")) == {}


@pytest.mark.filterwarnings("ignore:.*no timestamps")
def test_compare_hands_the_polish_options_to_the_rows_with_a_kiss_icp_polish_only(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    from click.testing import CliRunner

    from vcr_odom.cli.main import cli

    args = ["compare", "--data-root", small_synthetic_root, "-b", "icp10+kiss-icp", "-b", "kiss-icp"]
    args += ["--frames", ":4", "--point-to-plane", "on", "--polish-voxel", "0.6", "--results-dir", tmp_path]
    result = CliRunner().invoke(cli, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    folder = (tmp_path / "latest").resolve()
    polished = json.loads((folder / "icp10+kiss-icp" / "metrics.json").read_text())["run"]
    assert polished["polish_point_to_plane"] is True and polished["polish_voxel_m"] == 0.6
    baseline = json.loads((folder / "kiss-icp" / "metrics.json").read_text())["run"]
    assert baseline["polish_point_to_plane"] is None and baseline["polish_voxel_m"] is None
    config = json.loads((folder / "config.json").read_text())["config"]
    assert config["point_to_plane"] == "on" and config["polish_voxel"] == 0.6


def test_compare_called_from_python_refuses_polish_options_no_row_can_take(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    from vcr_odom.data.selection import FrameSelection
    from vcr_odom.errors import ConfigError
    from vcr_odom.evaluation.compare import CompareSettings, run_comparison

    settings = CompareSettings(
        selection=FrameSelection(data_root=small_synthetic_root, seq="00"),
        methods=("icp10", "kiss-icp"),
        point_to_plane="on",
        results_dir=tmp_path / "results",
    )
    with pytest.raises(ConfigError, match="--point-to-plane applies to the kiss-icp polish"):
        run_comparison(settings)
    assert not (tmp_path / "results").exists()
