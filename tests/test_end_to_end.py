"""The product as a user meets it: synthetic data -> run / compare / eval through the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from vcr_odom.cli.main import cli
from vcr_odom.data import KittiSequence
from vcr_odom.geometry import relative, rotation_angle
from vcr_odom.io import read_kitti_poses
from vcr_odom.registration import make_method
from vcr_odom.synth import generate_sequence

FRAMES = 12


@pytest.fixture(scope="module")
def synthetic_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("synthetic")
    generate_sequence(root, seq="00", frames=FRAMES, seed=3)
    return root


def invoke(*args: str) -> str:
    result = CliRunner().invoke(cli, list(args), catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return result.stdout  # warnings and notes go to stderr


def test_icp_recovers_the_written_relative_pose_of_consecutive_synthetic_frames(synthetic_root):
    sequence = KittiSequence(synthetic_root, "00")
    # A 0.3 m voxel (the default is 0.5 m, tuned on real KITTI): the synthetic facades are long flat
    # planes, so the along-road direction rests on poles and cars, which the coarser grid blurs (1-4 cm).
    icp = make_method("icp", voxel_size=0.3)
    gt = sequence.gt_poses
    prepared = [icp.prepare(sequence.frame(i)) for i in range(4)]
    for i in range(3):
        truth = relative(gt[i], gt[i + 1])
        # Start from identity: ~1 m of motion between frames, as a first frame would see.
        estimate = icp.register(prepared[i + 1], prepared[i], np.eye(4)).transform
        error = relative(truth, estimate)
        assert np.linalg.norm(error[:3, 3]) < 0.03, f"pair {i}->{i + 1}: {error[:3, 3]}"
        assert np.degrees(rotation_angle(error)) < 0.1


def test_run_writes_a_complete_result_folder_that_eval_scores_identically(synthetic_root, tmp_path):
    results = tmp_path / "results"
    output = invoke(
        "run",
        "--data-root",
        str(synthetic_root),
        "--seq",
        "00",
        "--method",
        "icp",
        "--results-dir",
        str(results),
    )
    assert "rotation RMSE / MAE [deg]" in output and "t_rel [%]" in output
    folder = (results / "latest").resolve()
    for name in (
        "config.json",
        "trajectory_kitti.txt",
        "trajectory_tum.txt",
        "frames.json",
        "metrics.json",
        "trajectory.png",
    ):
        assert (folder / name).is_file(), name
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["run"]["frames_processed"] == FRAMES
    assert metrics["pairs"]["trans_rmse_m"] < 0.05 and metrics["pairs"]["rot_rmse_deg"] < 0.2
    config = json.loads((folder / "config.json").read_text())
    assert config["config"]["method"] == "icp" and config["git_revision"]

    # The written trajectory is camera-frame (the synthetic data are calibrated) and eval, given the
    # calibration, reproduces the run's own per-pair figures.
    assert json.loads((folder / "frames.json").read_text())["poses_frame"] == "camera"
    assert len(read_kitti_poses(folder / "trajectory_kitti.txt")) == FRAMES
    report_path = tmp_path / "eval.json"
    invoke(
        "eval",
        "--gt",
        str(synthetic_root / "poses" / "00.txt"),
        "--est",
        str(folder / "trajectory_kitti.txt"),
        "--calib",
        str(synthetic_root / "sequences" / "00" / "calib.txt"),
        "--json",
        str(report_path),
        "--plot",
        str(tmp_path / "eval.png"),
    )
    evaluated = json.loads(report_path.read_text())
    assert evaluated["pairs"]["trans_rmse_m"] == pytest.approx(metrics["pairs"]["trans_rmse_m"], rel=1e-6)
    assert evaluated["pairs"]["rot_rmse_deg"] == pytest.approx(
        metrics["pairs"]["rot_rmse_deg"], rel=1e-4, abs=1e-6
    )
    assert (tmp_path / "eval.png").is_file() and (tmp_path / "eval_pair_errors.png").is_file()


def test_eval_without_est_scores_the_latest_run_and_names_it(synthetic_root, tmp_path, monkeypatch):
    # The mission's command lines as typed: `run`, then `eval --gt` with no --est, in one folder.
    monkeypatch.chdir(tmp_path)
    invoke("run", "--data-root", str(synthetic_root), "--seq", "00", "--method", "icp", "--frames", "0:6")
    run_metrics = json.loads((tmp_path / "results" / "latest" / "metrics.json").read_text())
    result = CliRunner().invoke(
        cli, ["eval", "--gt", str(synthetic_root / "poses" / "00.txt"), "--json", "-"], catch_exceptions=False
    )
    assert result.exit_code == 0, result.output
    scored = (tmp_path / "results" / "latest").resolve() / "trajectory_kitti.txt"
    assert f"scoring the latest run: {scored}" in result.stderr
    report = json.loads(result.stdout)
    assert report["pairs"]["trans_rmse_m"] == pytest.approx(run_metrics["pairs"]["trans_rmse_m"], rel=1e-6)


def test_eval_without_est_and_without_a_run_names_what_is_missing(synthetic_root, tmp_path):
    result = CliRunner().invoke(
        cli, ["eval", "--gt", str(synthetic_root / "poses" / "00.txt"), "--results-dir", str(tmp_path)]
    )
    assert result.exit_code == 2
    assert f"--est not given and {tmp_path / 'latest'} does not exist" in result.output


def test_run_method_takes_the_name_plus_polish_spelling_of_compare_and_the_tables(synthetic_root, tmp_path):
    invoke(
        "run", "--data-root", str(synthetic_root), "--method", "icp10+icp", "--frames", "0:4",
        "--results-dir", str(tmp_path),
    )  # fmt: skip
    folder = (tmp_path / "latest").resolve()
    assert folder.name.endswith("_icp10-icp")
    config = json.loads((folder / "config.json").read_text())["config"]
    assert (config["method"], config["polish"]) == ("icp10", "icp")


def test_strided_run_is_matched_to_ground_truth_through_frames_json(synthetic_root, tmp_path):
    results = tmp_path / "results"
    invoke(
        "run",
        "--data-root",
        str(synthetic_root),
        "--method",
        "icp",
        "--stride",
        "2",
        "--frames",
        "2:",
        "--results-dir",
        str(results),
    )
    folder = (results / "latest").resolve()
    assert json.loads((folder / "frames.json").read_text())["frame_indices"] == list(range(2, FRAMES, 2))
    output = invoke(
        "eval",
        "--gt",
        str(synthetic_root / "poses" / "00.txt"),
        "--est",
        str(folder / "trajectory_kitti.txt"),
        "--json",
        "-",
    )
    assert json.loads(output)["num_poses"] == len(range(2, FRAMES, 2))


def test_compare_prints_every_method_and_overlays_them(synthetic_root, tmp_path):
    output = invoke(
        "compare",
        "--data-root",
        str(synthetic_root),
        "-b",
        "icp10",
        "-b",
        "kiss-icp",
        "-b",
        "fpfh+icp",
        "--frames",
        ":6",
        "--results-dir",
        str(tmp_path),
    )
    assert "icp10" in output and "kiss-icp" in output and "fpfh+icp" in output and "success" in output
    assert "rot RMSE / MAE [deg]" in output and "r_rel [deg/100m]" in output  # units survive rich markup
    folder = (tmp_path / "latest").resolve()
    summary = json.loads((folder / "compare.json").read_text())
    assert set(summary) == {"icp10", "kiss-icp", "fpfh+icp"}
    assert (folder / "trajectories.png").is_file()
    assert all((folder / method / "trajectory_kitti.txt").is_file() for method in summary)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "--data-root", "{root}", "--seq", "42"], "sequences found: 00"),
        (["run", "--data-root", "{root}", "--stride", "100"], "at least 2"),
        (["run", "--data-root", "{root}", "--method", "nope"], "unknown method 'nope'"),
        (["run", "--data-root", "{root}", "--method", "vcr+nope"], "unknown polish 'nope'"),
        (["run", "--data-root", "{root}", "--method", "vcr+none", "--polish", "icp"], "disagree"),
        (["run", "--data-root", "{root}", "--vcr-passes", "0"], "--vcr-passes"),
        (["eval", "--gt", "{root}/poses/00.txt", "--est", "{short}"], "has 3 poses"),
    ],
)
def test_bad_input_is_one_clear_error(synthetic_root, tmp_path, args, message):
    short = tmp_path / "short.txt"
    short.write_text("".join("1 0 0 0 0 1 0 0 0 0 1 0\n" for _ in range(3)))
    filled = [a.format(root=synthetic_root, short=short) for a in args]
    result = CliRunner().invoke(
        cli, [*filled, "--results-dir", str(tmp_path)] if filled[0] == "run" else filled
    )
    assert result.exit_code != 0
    assert message in result.output
    assert "Traceback" not in result.output


def test_compare_both_protocols_prints_the_pairs_table_without_kiss_icp(synthetic_root, tmp_path):
    output = invoke(
        "compare",
        "--data-root",
        str(synthetic_root),
        "--protocol",
        "both",
        "-b",
        "icp10",
        "-b",
        "fpfh",
        "-b",
        "kiss-icp",
        "--frames",
        ":4",
        "--results-dir",
        str(tmp_path),
    )
    assert "odometry" in output and "same-scan pairs (paper Table III): 4 pairs of 1024 points" in output
    assert "consecutive pairs (frames 1 apart): 3 pairs of 1024 points" in output
    assert "left out of the pairs protocol: kiss-icp" in output
    report = json.loads(((tmp_path / "latest").resolve() / "pairs.json").read_text())
    assert set(report) == {"same-scan", "consecutive"}
    pairs = report["same-scan"]
    assert set(pairs) == {"icp10", "fpfh"}
    # The random ±30° / ±5 m moves are what a global method recovers and ICP from identity does not.
    assert pairs["fpfh"]["errors"]["success_rate"] > pairs["icp10"]["errors"]["success_rate"]
    # Consecutive frames are < 1.5 m apart: ICP from identity succeeds there.
    assert report["consecutive"]["icp10"]["errors"]["success_rate"] == 1.0


def test_the_pairs_protocol_feeds_vcr_the_point_count_it_runs_on(synthetic_root, tmp_path):
    """With --vcr-points the pair clouds have that many points (fewer would reach the network padded
    with repeated points); without it, the weights' own N."""
    import torch

    from vcr_odom.model.config import VcrConfig
    from vcr_odom.model.network import VCRNet
    from vcr_odom.model.weights import save_weights

    torch.manual_seed(0)
    small = VcrConfig(
        num_points=128, k=8, point_dim=16, graph_dim=16, spatial_dim=16, feature_dim=32, ff_dim=32
    )
    weights = save_weights(tmp_path / "small.safetensors", VCRNet(small), small)
    common = ["compare", "--data-root", str(synthetic_root), "--protocol", "pairs", "--pairs", "same-scan"]
    common += ["-b", "vcr", "--weights", str(weights), "--device", "cpu", "--frames", ":2"]
    assert "2 pairs of 128 points" in invoke(*common, "--results-dir", str(tmp_path / "own"))
    chosen = invoke(*common, "--vcr-points", "96", "--results-dir", str(tmp_path / "chosen"))
    assert "2 pairs of 96 points" in chosen


def test_run_saves_a_map_of_the_registered_scans(synthetic_root, tmp_path):
    import open3d as o3d

    map_path = tmp_path / "map.ply"
    output = invoke(
        "run",
        "--data-root",
        str(synthetic_root),
        "--method",
        "icp",
        "--frames",
        ":4",
        "--save-map",
        str(map_path),
        "--results-dir",
        str(tmp_path / "results"),
    )
    assert "map of" in output
    cloud = o3d.io.read_point_cloud(str(map_path))
    assert len(cloud.points) > 1000
    # The map is in the frame-0 LiDAR frame: the street surrounds the start, within the sensor's reach.
    extent = np.asarray(cloud.points).max(axis=0) - np.asarray(cloud.points).min(axis=0)
    assert 20.0 < extent[0] < 200.0 and 20.0 < extent[1] < 200.0


def test_demo_runs_vcr_with_the_shipped_weights(tmp_path):
    """`make demo`'s command: no dataset, no --weights; the shipped default weights are found. Its
    2 Hz, ~9 m-per-scan drive is where kiss-icp alone loses the track and the default holds it."""
    output = invoke("demo", "--frames", "40", "--results-dir", str(tmp_path))
    for method in ("icp10", "kiss-icp", "vcr+none", "vcr+icp", "vcr+kiss-icp"):
        assert method in output
    assert ((tmp_path / "latest").resolve() / "trajectories.png").is_file()
    report = json.loads(((tmp_path / "latest").resolve() / "compare.json").read_text())
    end_point = {name: row["endpoint_drift"]["trans_error_percent"] for name, row in report.items()}
    assert end_point["kiss-icp"] > 20.0 and end_point["vcr+kiss-icp"] < 2.0
    assert report["vcr+kiss-icp"]["pairs"]["success_rate"] == 1.0
    # The network alone, with nothing to rescue it (the polishes also start from the motion prior):
    # a broken network fails here even where the polished rows pass.
    alone = report["vcr+none"]
    assert alone["run"]["flagged_frames"] == []
    assert alone["pairs"]["success_rate"] > 0.9 and end_point["vcr+none"] < 15.0


@pytest.mark.parametrize("method", ["vcr", "icp10", "kiss-icp"])
def test_build_odometry_is_what_run_runs(synthetic_root, tmp_path, method):
    """`run --method NAME` and `build_odometry(NAME)` in Python: the same method (its default polish and
    pass count included), hence the same trajectory."""
    from vcr_odom.data.selection import FrameSelection
    from vcr_odom.geometry import lidar_to_camera_poses
    from vcr_odom.odometry import build_odometry, run_odometry

    invoke(
        "run",
        "--data-root",
        str(synthetic_root),
        "--method",
        method,
        "--frames",
        ":6",
        "--results-dir",
        str(tmp_path),
    )
    written = read_kitti_poses((tmp_path / "latest").resolve() / "trajectory_kitti.txt")
    sequence = FrameSelection(data_root=synthetic_root, frames=":6").open()
    odometry = build_odometry(method)
    run = run_odometry(sequence, odometry, range(6))
    assert (
        odometry.name
        == json.loads(((tmp_path / "latest").resolve() / "metrics.json").read_text())["run"]["method"]
    )
    np.testing.assert_allclose(lidar_to_camera_poses(run.poses, sequence.tr_velo_to_cam), written, atol=1e-6)


def test_consult_decides_how_often_the_network_runs(synthetic_root, tmp_path):
    """On a steady synthetic drive the default asks VCR-Net on the first pair only; --consult
    every-frame on every pair; metrics.json counts it."""
    counts = {}
    for consult in ("on-doubt", "every-frame"):
        folder = tmp_path / consult
        invoke(
            "run",
            "--data-root",
            str(synthetic_root),
            "--frames",
            ":6",
            "--consult",
            consult,
            "--results-dir",
            str(folder),
        )
        counts[consult] = json.loads(((folder / "latest").resolve() / "metrics.json").read_text())["run"]
    assert counts["on-doubt"]["global_registration"] == {"first pair": 1, "not needed": 4}
    assert counts["every-frame"]["global_registration"] == {}
    assert counts["on-doubt"]["method"] == counts["every-frame"]["method"] == "vcr+kiss-icp"


def test_2hz_keyframes_as_a_folder_match_the_kitti_layout_with_or_without_times(tmp_path):
    """nuScenes-like keyframes: 2 Hz, 1.5-4.5 m between scans. Run as a plain folder with --times,
    with the times.txt found beside the scans, and with no times at all (10 Hz assumed: the motions
    look implausible and are only flagged), the default gives the end-point drift of the KITTI-layout
    run within 0.1 %."""
    import shutil

    root = tmp_path / "kitti"
    generate_sequence(root, seq="00", frames=24, seed=5, frame_period=0.5, speed=6.0)
    folder = tmp_path / "scans"
    shutil.copytree(root / "sequences" / "00" / "velodyne", folder)
    times = root / "sequences" / "00" / "times.txt"
    poses, calib = root / "poses" / "00.txt", root / "sequences" / "00" / "calib.txt"

    def end_point(*args: str) -> tuple[float, list[int]]:
        results = tmp_path / f"results{len(list(tmp_path.glob('results*')))}"
        invoke("run", *args, "--results-dir", str(results))
        metrics = json.loads(((results / "latest").resolve() / "metrics.json").read_text())
        return metrics["endpoint_drift"]["trans_error_percent"], metrics["run"]["flagged_frames"]

    reference, flagged = end_point("--data-root", str(root), "--seq", "00")
    assert flagged == [] and reference < 2.0
    folder_args = ("--folder", str(folder), "--poses", str(poses), "--calib", str(calib))
    with_times, _ = end_point(*folder_args, "--times", str(times))
    assumed, flagged_assumed = end_point(*folder_args)
    shutil.copy2(times, folder / "times.txt")
    beside, _ = end_point(*folder_args)
    assert abs(with_times - reference) < 0.1 and abs(beside - reference) < 0.1
    assert abs(assumed - reference) < 0.1 and flagged_assumed  # flagged, not replaced
