"""Issue 23, poses, times and scores: what the probe found scored silently wrong is refused naming the
file (and line), or scored as the files say; tables name their ATE alignment and carry the SE(3) one."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from evo.core import metrics as evo_metrics
from evo.core.trajectory import PosePath3D
from evo.tools import file_interface
from rich.console import Console

from vcr_odom import io
from vcr_odom.cli.main import cli
from vcr_odom.cli.tables import ComparisonRow, comparison_table, report_table
from vcr_odom.errors import DataError
from vcr_odom.geometry import (
    camera_to_lidar_poses,
    lidar_to_camera_poses,
    make_transform,
    project_to_se3,
    rotation_from_euler_zyx,
)
from vcr_odom.metrics import ate_rpe, evaluate

EXIT_ERROR, EXIT_USAGE = 1, 2

# KITTI sequence 00's LiDAR -> camera transform (axes swapped, small offsets): far from the identity,
# so a trajectory converted once and one converted twice score very differently.
KITTI_TR = project_to_se3(
    [
        [4.276802e-04, -9.999672e-01, -8.084491e-03, -1.198459e-02],
        [-7.210626e-03, 8.081198e-03, -9.999413e-01, -5.403984e-02],
        [9.999738e-01, 4.859485e-04, -7.206933e-03, -2.921968e-01],
        [0.0, 0.0, 0.0, 1.0],
    ]
)  # made exactly rigid, as eval's read_tr does, so an exact estimate scores zero


def compose(motions: np.ndarray) -> np.ndarray:
    """Chain relative motions into poses starting at the identity."""
    poses = [np.eye(4)]
    for motion in motions:
        poses.append(poses[-1] @ motion)
    return np.array(poses)


def drive(count: int = 40, seed: int = 5) -> np.ndarray:
    """A LiDAR-frame drive with turns and some pitch and roll, about 1 m a frame."""
    rng = np.random.default_rng(seed)
    motions = [
        make_transform(
            rotation_from_euler_zyx(*rng.normal(0.0, [0.05, 0.01, 0.01])),
            [1.0 + 0.1 * rng.standard_normal(), 0.05 * rng.standard_normal(), 0.02 * rng.standard_normal()],
        )
        for _ in range(count - 1)
    ]
    return compose(np.array(motions))


def invoke(*args: object) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args])


def assert_fails(result: Result, code: int, *named: object) -> None:
    """Exit ``code``, no traceback, and the message names every one of ``named``."""
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    for name in named:
        assert str(name) in result.output, (name, result.output)


def write_estimate(folder: Path, poses: np.ndarray, indices: list[int], poses_frame: str | None) -> Path:
    """An estimate as a run leaves it: trajectory_kitti.txt and frames.json beside it."""
    folder.mkdir(parents=True, exist_ok=True)
    sidecar: dict[str, object] = {"frame_indices": indices}
    if poses_frame is not None:
        sidecar["poses_frame"] = poses_frame
    (folder / "frames.json").write_text(json.dumps(sidecar))
    return io.write_kitti_poses(folder / "trajectory_kitti.txt", poses)


def pose_lines(poses: np.ndarray) -> list[str]:
    return io.format_kitti_poses(poses).splitlines()


def random_scans(folder: Path, count: int) -> Path:
    """``count`` small scans of uniform random points: where the frames' content does not matter."""
    folder.mkdir()
    rng = np.random.default_rng(0)
    for index in range(count):
        rng.uniform(-20, 20, size=(50, 4)).astype(np.float32).tofile(folder / f"{index:06d}.bin")
    return folder


# -- 1. mirrored and non-orthonormal rotations --------------------------------------------------------


def mirrored(block: np.ndarray) -> np.ndarray:
    block = block.copy()
    block[:3, 0] *= -1  # a reflected axis: orthonormal, determinant -1
    return block


def scaled(block: np.ndarray) -> np.ndarray:
    block = block.copy()
    block[:3, :3] *= 1.0004  # 0.04 % scale: R^T R - I is 8e-4, which 7 printed digits never make
    return block


def sheared(block: np.ndarray) -> np.ndarray:
    block = block.copy()
    block[0, 1] += 0.01
    return block


@pytest.mark.parametrize("which", ["--gt", "--est"])
@pytest.mark.parametrize(
    ("broken", "why"),
    [(mirrored, "determinant -1"), (scaled, "not a rotation matrix"), (sheared, "not a rotation matrix")],
    ids=["mirrored", "scaled", "sheared"],
)
def test_a_pose_that_is_not_rigid_is_refused_naming_the_file_and_line(tmp_path, which, broken, why):
    poses = drive(12)
    poses[6] = broken(poses[6])
    lines = pose_lines(poses)
    bad = tmp_path / "bad.txt"
    bad.write_text("\n" + "\n".join(lines) + "\n")  # a blank first line: pose 7 is on line 8
    good = io.write_kitti_poses(tmp_path / "good.txt", drive(12))
    files = {"--gt": good, "--est": good, which: bad}
    report = tmp_path / "eval.json"
    result = invoke("eval", "--gt", files["--gt"], "--est", files["--est"], "--json", report)
    assert_fails(result, EXIT_ERROR, f"{bad}: pose 7 (line 8)", why, "expected a rotation")
    assert not report.exists()


def test_run_with_mirrored_ground_truth_exits_1_naming_the_line_before_writing_anything(tmp_path):
    poses = drive(6)
    poses[3] = mirrored(poses[3])
    gt = io.write_kitti_poses(tmp_path / "gt.txt", poses)
    scans = random_scans(tmp_path / "scans", 6)
    results = tmp_path / "results"
    result = invoke("run", "--folder", scans, "--poses", gt, "--method", "icp", "--results-dir", results)
    assert_fails(result, EXIT_ERROR, f"{gt}: pose 4 (line 4)", "determinant -1")
    assert not results.exists() or not list(results.iterdir())


def test_printed_kitti_poses_still_read(tmp_path):
    """The 7 digits KITTI prints (and 4 decimals) are within the tolerance: only broken files fail."""
    poses = drive(20)
    kitti = tmp_path / "kitti.txt"
    kitti.write_text("".join(" ".join(f"{v:.6e}" for v in p[:3, :4].ravel()) + "\n" for p in poses))
    four = tmp_path / "four.txt"
    four.write_text("".join(" ".join(f"{v:.4f}" for v in p[:3, :4].ravel()) + "\n" for p in poses))
    for path in (kitti, four):
        np.testing.assert_allclose(io.read_kitti_poses(path), poses, atol=1e-3)


# -- 2. --frames against frames.json ---------------------------------------------------------------


def test_frames_option_that_disagrees_with_frames_json_is_refused_naming_both(tmp_path):
    gt = drive(30)
    gt_path = io.write_kitti_poses(tmp_path / "gt.txt", gt)
    est = write_estimate(tmp_path / "run", gt[5:25], list(range(5, 25)), None)
    report = tmp_path / "eval.json"
    result = invoke("eval", "--gt", gt_path, "--est", est, "--frames", "0:20", "--json", report)
    assert_fails(result, EXIT_USAGE, "--frames 0:20", tmp_path / "run" / "frames.json", "5..24", "0..19")
    assert not report.exists()
    result = invoke("eval", "--gt", gt_path, "--est", est, "--stride", "2", "--json", report)
    assert_fails(result, EXIT_USAGE, "--stride 2", tmp_path / "run" / "frames.json")


def test_frames_option_that_agrees_with_frames_json_is_fine(tmp_path):
    gt = drive(30)
    gt_path = io.write_kitti_poses(tmp_path / "gt.txt", gt)
    est = write_estimate(tmp_path / "run", gt[5:25], list(range(5, 25)), None)
    report = tmp_path / "eval.json"
    result = invoke("eval", "--gt", gt_path, "--est", est, "--frames", "5:25", "--json", report)
    assert result.exit_code == 0, result.output
    scores = json.loads(report.read_text())
    assert scores["num_poses"] == 20 and scores["pairs"]["trans_rmse_m"] < 1e-6


# -- 3. poses_frame in frames.json with --calib ------------------------------------------------------


@pytest.mark.parametrize("poses_frame", ["lidar", "camera"])
def test_calib_converts_only_what_frames_json_says_is_camera_frame(tmp_path, poses_frame):
    """The estimate is exact: whichever frame frames.json says it is in, eval --calib scores it zero.
    A LiDAR-frame estimate converted again (what eval used to do) is a different trajectory."""
    lidar = drive(40)
    camera = lidar_to_camera_poses(lidar, KITTI_TR)
    gt_path = io.write_kitti_poses(tmp_path / "gt.txt", camera)
    calib = io.write_kitti_calib(tmp_path / "calib.txt", {"Tr": KITTI_TR})
    estimate = lidar if poses_frame == "lidar" else camera
    est = write_estimate(tmp_path / "run", estimate, list(range(40)), poses_frame)
    report = tmp_path / "eval.json"
    result = invoke("eval", "--gt", gt_path, "--est", est, "--calib", calib, "--json", report)
    assert result.exit_code == 0, result.output
    scores = json.loads(report.read_text())
    assert scores["pairs"]["trans_rmse_m"] < 1e-6 and scores["pairs"]["rot_rmse_deg"] < 1e-5
    assert scores["ate_rpe"]["ate_trans_rmse_m"] < 1e-6
    twice = evaluate(camera_to_lidar_poses(lidar, KITTI_TR), lidar)
    assert twice.pairs.trans_rmse_m > 0.05  # the bug's figure: the test tells the two apart


def test_an_unknown_poses_frame_is_refused_naming_frames_json(tmp_path):
    gt = drive(10)
    gt_path = io.write_kitti_poses(tmp_path / "gt.txt", gt)
    est = write_estimate(tmp_path / "run", gt, list(range(10)), "velodyne")
    result = invoke("eval", "--gt", gt_path, "--est", est)
    assert_fails(result, EXIT_ERROR, tmp_path / "run" / "frames.json", "'velodyne'", "camera or lidar")


# -- 4 and 5. times in the wrong unit, steps no sensor has, TUM stamps ----------------------------------


@pytest.mark.parametrize(
    ("stamps", "unit"),
    [
        (np.arange(20) * 100.0, "milliseconds"),  # 10 Hz in ms
        (1.7e15 + np.arange(20) * 1e5, "microseconds"),
        (1.7e18 + np.arange(20) * 1e8, "nanoseconds"),
    ],
    ids=["ms", "us", "ns"],
)
def test_times_in_another_unit_are_refused_saying_seconds_are_expected(tmp_path, stamps, unit):
    path = tmp_path / "stamps.txt"
    path.write_text("".join(f"{float(t)!r}\n" for t in stamps))
    with pytest.raises(DataError, match="expected seconds") as error:
        io.read_times(path)
    assert str(error.value).startswith(f"{path}:") and unit in str(error.value)


def test_one_nanosecond_steps_are_refused_naming_the_line(tmp_path):
    path = tmp_path / "stamps.txt"
    path.write_text("".join(f"{float(t)!r}\n" for t in 5.0 + np.arange(10) * 1e-9))
    with pytest.raises(DataError, match=r"cannot be a frame period; expected seconds") as error:
        io.read_times(path)
    assert str(error.value).startswith(f"{path}:2:")
    results = tmp_path / "results"
    scans = random_scans(tmp_path / "scans", 10)
    result = invoke("run", "--folder", scans, "--times", path, "--method", "icp", "--results-dir", results)
    assert_fails(result, EXIT_ERROR, f"{path}:2:", "cannot be a frame period")
    assert not results.exists() or not list(results.iterdir())


def test_sensor_rates_and_keyframes_in_seconds_still_read(tmp_path):
    kitti = 0.0 + np.cumsum(np.full(20, 0.1036))
    for rate, stamps in {
        "kitti": kitti,
        "1hz": np.arange(10.0),
        "epoch": 1.7e9 + np.arange(10) * 0.05,
    }.items():
        path = io.write_times(tmp_path / f"{rate}.txt", stamps)
        np.testing.assert_array_equal(io.read_times(path), stamps)


def test_run_with_millisecond_times_exits_1_before_writing_anything(tmp_path):
    scans = random_scans(tmp_path / "scans", 4)
    times = tmp_path / "ms.txt"
    times.write_text("0\n100\n200\n300\n")
    results = tmp_path / "results"
    result = invoke("run", "--folder", scans, "--times", times, "--method", "icp", "--results-dir", results)
    assert_fails(result, EXIT_ERROR, times, "expected seconds", "milliseconds")
    assert not results.exists() or not list(results.iterdir())


def test_tum_stamps_keep_sub_microsecond_steps_distinct(tmp_path):
    poses = drive(6)
    stamps = 2.0 + np.arange(6) * 2e-7
    path = io.write_tum_trajectory(tmp_path / "fine.tum", poses, stamps)
    read = file_interface.read_tum_trajectory_file(str(path)).timestamps
    assert np.all(np.diff(read) > 0)
    np.testing.assert_allclose(read, stamps, rtol=0, atol=1e-10)
    usual = io.format_tum_trajectory(poses, np.arange(6) * 0.1).splitlines()
    assert usual[1].split()[0] == "0.100000"  # the usual 6 decimals where they suffice


# -- 6. frames.json indices -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("indices", "expected"),
    [
        ([-1, 1, 2, 3], "names frame -1"),
        ([0, 1, 2, 10], "names frame 10"),
        ([0, 1.5, 2, 3], "list of integers"),
        ([0, True, 2, 3], "list of integers"),
        ([0, 2, 1, 3], "strictly increasing"),
    ],
    ids=["negative", "past-the-end", "fraction", "bool", "unordered"],
)
def test_a_frames_json_index_out_of_range_is_refused_naming_the_file(tmp_path, indices, expected):
    gt = drive(10)
    gt_path = io.write_kitti_poses(tmp_path / "gt.txt", gt)
    est = write_estimate(tmp_path / "run", gt[:4], indices, "lidar")
    result = invoke("eval", "--gt", gt_path, "--est", est)
    assert_fails(result, EXIT_ERROR, tmp_path / "run" / "frames.json", expected)


# -- 7. absurd positions -------------------------------------------------------------------------


@pytest.mark.parametrize(("value", "expected"), [("1e200", "from the origin"), ("nan", "NaN or inf")])
def test_an_absurd_position_is_refused_at_reading_naming_the_file_and_line(tmp_path, value, expected):
    poses = drive(10)
    lines = pose_lines(poses)
    fields = lines[3].split()
    fields[3] = value
    lines[3] = " ".join(fields)
    bad = tmp_path / "far.txt"
    bad.write_text("\n".join(lines) + "\n")
    good = io.write_kitti_poses(tmp_path / "good.txt", poses)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no numpy overflow on the way
        result = invoke("eval", "--gt", bad, "--est", good)
    assert_fails(result, EXIT_ERROR, f"{bad}: pose 4 (line 4)", expected)
    assert "overflow" not in result.output


# -- 8. the ATE alignment, named, with the SE(3) figure evo_ape -a prints -----------------------------


def evo_se3_ate(est: np.ndarray, gt: np.ndarray) -> float:
    """What ``evo_ape kitti gt est -a`` prints as rmse, through evo's own API."""
    reference = PosePath3D(poses_se3=list(gt))
    aligned = PosePath3D(poses_se3=list(est))
    aligned.align(reference, correct_scale=False)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((reference, aligned))
    return float(ape.get_statistic(evo_metrics.StatisticsType.rmse))


def drifting_estimate(gt: np.ndarray) -> np.ndarray:
    """The ground truth with a 1 deg heading error at the start: origin and SE(3) ATE differ a lot."""
    turn = make_transform(rotation_from_euler_zyx(math.radians(1.0), 0.0, 0.0), [0.0, 0.0, 0.0])
    return np.concatenate([gt[:1], gt[:1] @ turn @ np.linalg.inv(gt[:1]) @ gt[1:]])


def render(table) -> str:
    console = Console(record=True, width=400)
    console.print(table)
    return console.export_text()


def test_compare_table_names_its_alignment_and_carries_evos_se3_ate():
    gt = drive(60)
    est = drifting_estimate(gt)
    report = evaluate(est, gt)
    se3 = evo_se3_ate(est, gt)
    assert report.ate_rpe.ate_se3_trans_rmse_m == pytest.approx(se3, rel=1e-9)
    assert se3 < 0.7 * report.ate_rpe.ate_trans_rmse_m  # two different figures, as in the probe
    text = render(comparison_table([ComparisonRow("icp", True, report, 10.0)], "t"))
    assert "ATE origin / SE(3) [m]" in text and "evo_ape -a" in text and "first poses aligned" in text
    assert f"{report.ate_rpe.ate_trans_rmse_m:.3f} / {se3:.3f}" in text
    text = render(report_table(report))
    assert "first poses aligned" in text and "SE(3)-aligned, as evo_ape -a" in text
    assert f"{se3:.3f}" in text
    assert report.to_dict()["ate_rpe"]["ate_se3_trans_rmse_m"] == pytest.approx(se3, rel=1e-9)


def test_eval_json_and_table_carry_the_se3_ate_of_evo_ape(tmp_path):
    gt = drive(30)
    est = drifting_estimate(gt)
    gt_path = io.write_kitti_poses(tmp_path / "gt.txt", gt)
    est_path = io.write_kitti_poses(tmp_path / "est.txt", est)
    report = tmp_path / "eval.json"
    result = invoke("eval", "--gt", gt_path, "--est", est_path, "--json", report)
    assert result.exit_code == 0, result.output
    assert "SE(3)-aligned" in result.output
    evo_gt = np.stack(file_interface.read_kitti_poses_file(str(gt_path)).poses_se3)
    evo_est = np.stack(file_interface.read_kitti_poses_file(str(est_path)).poses_se3)
    expected = evo_se3_ate(evo_est, evo_gt)
    assert json.loads(report.read_text())["ate_rpe"]["ate_se3_trans_rmse_m"] == pytest.approx(
        expected, rel=1e-6
    )


def test_a_straight_drive_has_no_se3_figure_rather_than_a_traceback():
    gt = np.tile(np.eye(4), (20, 1, 1))
    gt[:, 0, 3] = np.arange(20.0)
    report = evaluate(gt.copy(), gt)
    assert report.ate_rpe.ate_se3_trans_rmse_m is None
    assert "0.000 / –" in render(comparison_table([ComparisonRow("icp", True, report, 1.0)], "t"))
    with pytest.raises(DataError, match="SE\\(3\\) alignment is not possible"):
        ate_rpe(gt.copy(), gt, alignment="se3")
