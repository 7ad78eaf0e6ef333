"""Evaluation metrics: devkit drift against kiss-icp's port, hand-computed cases, evo ATE/RPE against numpy."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from reference_geometry import weighted_kabsch
from reference_metrics import KISS_ICP_PI, kiss_icp_equivalent

from vcr_odom.errors import ConfigError, DataError
from vcr_odom.geometry import make_transform, rotation_from_euler_zyx
from vcr_odom.io import read_kitti_poses
from vcr_odom.metrics import (
    DriftResult,
    ate_rpe,
    endpoint_drift,
    evaluate,
    kitti_drift,
    pair_errors,
    relative_motions,
    short_segment_lengths,
    trajectory_pair_errors,
)


def straight_line(num_poses: int, step_m: float = 1.0) -> np.ndarray:
    """Poses along +x, ``step_m`` apart, identity rotation."""
    poses = np.tile(np.eye(4), (num_poses, 1, 1))
    poses[:, 0, 3] = step_m * np.arange(num_poses)
    return poses


def compose(motions: np.ndarray) -> np.ndarray:
    """Trajectory from frame 0 = identity and the given relative motions."""
    poses = [np.eye(4)]
    for motion in motions:
        poses.append(poses[-1] @ motion)
    return np.array(poses)


def curvy_trajectory(num_poses: int = 120, seed: int = 3) -> np.ndarray:
    """A smooth drive with turns and gentle pitch/roll, about 1 m a frame."""
    rng = np.random.default_rng(seed)
    motions = [
        make_transform(
            rotation_from_euler_zyx(*rng.normal(0.0, [0.02, 0.003, 0.003])),
            [1.0 + 0.1 * rng.standard_normal(), 0.02 * rng.standard_normal(), 0.0],
        )
        for _ in range(num_poses - 1)
    ]
    return compose(np.array(motions))


def perturbed(gt: np.ndarray, seed: int) -> np.ndarray:
    """A seeded random walk of small rotation/translation errors accumulated along the trajectory."""
    rng = np.random.default_rng(seed)
    motions = np.linalg.solve(gt[:-1], gt[1:])
    noise = [
        make_transform(rotation_from_euler_zyx(*rng.normal(0.0, 2e-3, 3)), rng.normal(0.0, 0.02, 3))
        for _ in range(len(motions))
    ]
    return compose(motions @ np.array(noise))


def smooth_drive(num_poses: int = 900) -> np.ndarray:
    """About 1 m a frame along a path of gentle S-bends, with slow pitch and roll: ~900 m in all,
    long enough for every KITTI segment length (100..800 m)."""
    i = np.arange(num_poses - 1)
    yaw = 0.03 * np.sin(2 * np.pi * i / 250)
    pitch = 0.002 * np.sin(2 * np.pi * i / 170)
    roll = 0.002 * np.cos(2 * np.pi * i / 130)
    step = 1.0 + 0.2 * np.sin(2 * np.pi * i / 90)
    motions = [
        make_transform(rotation_from_euler_zyx(yaw[k], pitch[k], roll[k]), [step[k], 0.0, 0.0])
        for k in range(num_poses - 1)
    ]
    return compose(np.array(motions))


def biased(gt: np.ndarray, yaw_per_frame_rad: float, scale: float) -> np.ndarray:
    """The same drive with every motion over-scaled and turned a little too far left: systematic drift."""
    motions = np.linalg.solve(gt[:-1], gt[1:])
    motions[:, :3, 3] *= scale
    error = make_transform(rotation_from_euler_zyx(yaw_per_frame_rad, 0.0, 0.0), [0.0, 0.0, 0.0])
    return compose(motions @ error)


# ------------------------------------------------------------------------------------------ KITTI drift


def assert_agrees_with_kiss_icp(est: np.ndarray, gt: np.ndarray) -> DriftResult:
    """Our devkit drift against kiss-icp's C++ port of the same devkit, an independent implementation."""
    from kiss_icp.metrics import sequence_error

    drift = kitti_drift(est, gt)
    kiss_t_percent, kiss_r_deg_per_m = sequence_error(gt, est)

    assert drift.num_segments > 0 and not drift.short_sequence
    ours_t, ours_r = kiss_icp_equivalent(drift)
    # kiss-icp returns float32, hence agreement to float32 precision (~6e-8), well inside 1e-6.
    assert ours_t == pytest.approx(kiss_t_percent, rel=1e-6)
    assert ours_r == pytest.approx(kiss_r_deg_per_m, rel=1e-6)
    # kiss-icp's second figure is deg/m computed with pi = 3.14: pin the conversion to deg/100 m.
    assert drift.r_rel_deg_per_100m == pytest.approx(
        kiss_r_deg_per_m * 100.0 * KISS_ICP_PI / math.pi, rel=1e-6
    )
    # The overall figure is the mean over all segments, i.e. the segment-weighted mean of the lengths.
    counts = np.array([row.num_segments for row in drift.per_length])
    t_rows = np.array([row.t_rel_percent for row in drift.per_length])
    used = counts > 0
    assert counts.sum() == drift.num_segments
    assert drift.t_rel_percent == pytest.approx(np.sum(counts[used] * t_rows[used]) / counts.sum())
    return drift


@pytest.mark.parametrize("perturbation", ["random walk", "scale and yaw bias"])
def test_drift_agrees_with_kiss_icp_on_a_synthetic_drive(perturbation: str) -> None:
    gt = smooth_drive()
    est = perturbed(gt, seed=4) if perturbation == "random walk" else biased(gt, 2e-4, 1.01)
    drift = assert_agrees_with_kiss_icp(est, gt)
    assert drift.segment_lengths_m == (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
    assert all(row.num_segments > 0 for row in drift.per_length)  # the path is long enough for 800 m


@pytest.mark.parametrize(("sequence", "seed"), [("00", 0), ("04", 1), ("07", 2), ("10", 3)])
def test_drift_agrees_with_kiss_icp_on_kitti(kitti_gt_poses_dir: Path, sequence: str, seed: int) -> None:
    gt = read_kitti_poses(kitti_gt_poses_dir / "poses" / f"{sequence}.txt")
    assert_agrees_with_kiss_icp(perturbed(gt, seed), gt)


def test_sequence_00_is_kitti_length(kitti_gt_poses_dir: Path) -> None:
    gt = read_kitti_poses(kitti_gt_poses_dir / "poses" / "00.txt")
    drift = kitti_drift(gt, gt)
    assert len(gt) == 4541
    assert 3700 < drift.path_length_m < 3760
    assert [row.length_m for row in drift.per_length] == [100.0 * k for k in range(1, 9)]
    assert all(row.num_segments > 0 for row in drift.per_length)


def test_scaled_straight_line_drift_is_one_percent() -> None:
    # 200 m line; the devkit divides |t_E| by the nominal length while the segment ends at the first
    # frame *beyond* start + L: with 1 m steps every 100 m segment is 101 m long.
    gt = straight_line(201)
    est = gt.copy()
    est[:, :3, 3] *= 1.01
    drift = kitti_drift(est, gt)
    assert drift.segment_lengths_m == (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
    assert drift.num_segments == 10  # starts 0, 10, ..., 90; no 200 m segment fits a 200 m path
    assert (
        drift.per_length[1].num_segments == 0
        and drift.per_length[1].t_rel_percent != drift.per_length[1].t_rel_percent
    )
    assert drift.t_rel_percent == pytest.approx(1.0 * 101 / 100, rel=1e-12)
    assert drift.r_rel_deg_per_100m == pytest.approx(0.0, abs=1e-9)

    # Steps a hair over 1 m: every segment is exactly 100 frames, so the drift is 1 %.
    gt = straight_line(201, step_m=1.0 + 1e-9)
    est = gt.copy()
    est[:, :3, 3] *= 1.01
    drift = kitti_drift(est, gt)
    assert drift.t_rel_percent == pytest.approx(1.0, rel=1e-8)
    assert drift.r_rel_deg_per_100m == pytest.approx(0.0, abs=1e-9)


def test_constant_yaw_bias_drift() -> None:
    bias_rad = math.radians(0.01)  # 0.01 deg a metre = 1 deg / 100 m
    step = make_transform(np.eye(3), [1.0 + 1e-9, 0.0, 0.0])
    gt = compose(np.repeat(step[None], 400, axis=0))
    turning = make_transform(rotation_from_euler_zyx(bias_rad, 0.0, 0.0), [1.0 + 1e-9, 0.0, 0.0])
    est = compose(np.repeat(turning[None], 400, axis=0))
    drift = kitti_drift(est, gt)
    # Steps a hair over 1 m: a segment of L m from frame s ends at frame s + L, which must exist (<= 400).
    expected = [len(range(0, 401 - int(length), 10)) for length in drift.segment_lengths_m]
    assert [row.num_segments for row in drift.per_length] == expected == [31, 21, 11, 1, 0, 0, 0, 0]
    for row in drift.per_length:
        if row.num_segments:
            assert row.r_rel_deg_per_100m == pytest.approx(1.0, rel=1e-6)
    assert drift.r_rel_deg_per_100m == pytest.approx(1.0, rel=1e-6)


def test_custom_lengths_and_step() -> None:
    gt = straight_line(61)
    est = gt.copy()
    est[:, :3, 3] *= 1.02
    drift = kitti_drift(est, gt, segment_lengths_m=[9, 19], step_frames=5)
    assert not drift.short_sequence and drift.segment_lengths_m == (9.0, 19.0)
    assert [row.num_segments for row in drift.per_length] == [11, 9]  # starts 0..50 and 0..40
    assert drift.per_length[0].t_rel_percent == pytest.approx(2.0 * 10 / 9)
    assert drift.per_length[1].t_rel_percent == pytest.approx(2.0 * 20 / 19)


# -------------------------------------------------------------------------- short sequences, end point


def test_short_segment_lengths_rule() -> None:
    assert short_segment_lengths(50.0) == (5, 10, 15, 20, 25, 30, 35, 40)
    assert short_segment_lengths(99.0) == (10, 20, 30, 40, 50, 60, 70, 80)
    assert short_segment_lengths(100.0) == (10, 20, 30, 40, 50, 60, 70, 80)
    assert short_segment_lengths(12.0)[:2] == (1, 2)
    assert short_segment_lengths(3.0)[0] == pytest.approx(0.2)
    assert short_segment_lengths(0.0) == ()


def test_short_sequence_gets_labelled_short_segments_and_endpoint_drift() -> None:
    gt = straight_line(51)  # a 50 m path, too short for a single 100 m segment
    est = gt.copy()
    est[:, :3, 3] *= 1.01
    report = evaluate(est, gt)
    drift = report.drift
    assert drift.short_sequence
    assert "short sequence" in drift.label and "not comparable" in drift.label
    assert drift.segment_lengths_m == (5, 10, 15, 20, 25, 30, 35, 40)
    # Exactly 1 m steps: a segment of L m from frame s ends at frame s + L + 1, which must exist (<= 50).
    expected = [len(range(0, 50 - int(length), 10)) for length in drift.segment_lengths_m]
    assert [row.num_segments for row in drift.per_length] == expected
    assert drift.num_segments == sum(expected) == 24
    for row in drift.per_length:
        assert row.t_rel_percent == pytest.approx(1.0 * (row.length_m + 1) / row.length_m)
    end = report.endpoint
    assert end.path_length_m == pytest.approx(50.0)
    assert end.trans_error_m == pytest.approx(0.5)
    assert end.trans_error_percent == pytest.approx(1.0)
    assert end.rot_error_deg == pytest.approx(0.0, abs=1e-9)
    data = report.to_dict()
    assert data["drift"]["short_sequence"] is True
    assert data["drift"]["segment_lengths_m"] == [5, 10, 15, 20, 25, 30, 35, 40]


def test_long_sequence_not_short_and_endpoint_always_present() -> None:
    gt = straight_line(151)
    report = evaluate(gt, gt)
    assert not report.drift.short_sequence
    assert report.drift.label.startswith("KITTI devkit drift")
    assert report.endpoint.trans_error_m == 0.0


def test_endpoint_rotation() -> None:
    gt = curvy_trajectory(30)
    est = gt.copy()
    est[-1] = est[-1] @ make_transform(rotation_from_euler_zyx(0.0, math.radians(3.0), 0.0), [0, 0, 0])
    end = endpoint_drift(est, gt)
    assert end.rot_error_deg == pytest.approx(3.0)
    assert end.trans_error_m == pytest.approx(0.0, abs=1e-12)


def test_stationary_sequence_has_no_segments_and_no_percent() -> None:
    gt = np.tile(np.eye(4), (20, 1, 1))
    report = evaluate(gt, gt)
    assert report.drift.num_segments == 0
    assert math.isnan(report.drift.t_rel_percent)
    data = report.to_dict()
    assert data["drift"]["t_rel_percent"] is None
    assert data["endpoint_drift"]["trans_error_percent"] is None
    json.dumps(data, allow_nan=False)


# ------------------------------------------------------------------------------------- per-pair errors


def yaw_pairs(count: int, seed: int = 0) -> np.ndarray:
    """Relative transforms with pure-yaw rotations and random translations."""
    rng = np.random.default_rng(seed)
    return np.array(
        [
            make_transform(rotation_from_euler_zyx(rng.uniform(-0.3, 0.3), 0.0, 0.0), rng.normal(0, 1, 3))
            for _ in range(count)
        ]
    )


def test_pair_errors_constant_rotation_and_offset() -> None:
    gt = yaw_pairs(10)
    est = gt.copy()
    est[:, :3, :3] = gt[:, :3, :3] @ rotation_from_euler_zyx(math.radians(1.0), 0.0, 0.0)
    est[:, 0, 3] += 0.1
    result = pair_errors(est, gt)
    assert result.num_pairs == 10
    assert result.rot_rmse_deg == pytest.approx(1.0) and result.rot_mae_deg == pytest.approx(1.0)
    assert result.trans_rmse_m == pytest.approx(0.1) and result.trans_mae_m == pytest.approx(0.1)
    assert result.success_rate == 1.0
    dcp = result.dcp
    # Only yaw is wrong: pooled over the three axes, 1 deg in one of three.
    assert dcp.euler_rmse_deg_per_axis["yaw"] == pytest.approx(1.0)
    assert dcp.euler_rmse_deg_per_axis["pitch"] == pytest.approx(0.0, abs=1e-9)
    assert dcp.euler_mae_deg_per_axis["roll"] == pytest.approx(0.0, abs=1e-9)
    assert dcp.euler_mse_deg2 == pytest.approx(1.0 / 3.0)
    assert dcp.euler_rmse_deg == pytest.approx(math.sqrt(1.0 / 3.0))
    assert dcp.euler_mae_deg == pytest.approx(1.0 / 3.0)
    assert dcp.trans_mse_m2 == pytest.approx(0.01 / 3.0)
    assert dcp.trans_rmse_m == pytest.approx(0.1 / math.sqrt(3.0))
    assert dcp.trans_mae_m == pytest.approx(0.1 / 3.0)
    assert dcp.trans_rmse_m_per_axis == pytest.approx({"x": 0.1, "y": 0.0, "z": 0.0})


def test_pair_errors_mixed_rmse_vs_mae_and_success() -> None:
    gt = yaw_pairs(2, seed=1)
    est = gt.copy()
    est[0, :3, :3] = gt[0, :3, :3] @ rotation_from_euler_zyx(0.0, math.radians(1.0), 0.0)
    est[1, :3, :3] = gt[1, :3, :3] @ rotation_from_euler_zyx(0.0, 0.0, math.radians(3.0))
    est[0, :3, 3] += [0.0, 0.1, 0.0]
    est[1, :3, 3] += [0.0, 0.0, -0.3]
    result = pair_errors(est, gt)
    np.testing.assert_allclose(result.rot_errors_deg, [1.0, 3.0])
    np.testing.assert_allclose(result.trans_errors_m, [0.1, 0.3])
    assert result.rot_rmse_deg == pytest.approx(math.sqrt(5.0))
    assert result.rot_mae_deg == pytest.approx(2.0)
    assert result.trans_rmse_m == pytest.approx(math.sqrt(0.05))
    assert result.trans_mae_m == pytest.approx(0.2)
    assert result.success.tolist() == [True, False]
    assert result.success_rate == 0.5
    loose = pair_errors(est, gt, rot_threshold_deg=5.0, trans_threshold_m=0.5)
    assert loose.success_rate == 1.0
    strict = pair_errors(est, gt, rot_threshold_deg=5.0, trans_threshold_m=0.2)
    assert strict.success_rate == 0.5


def test_euler_only_yaw_wrong_with_general_rotations() -> None:
    rng = np.random.default_rng(5)
    delta_rad = math.radians(0.7)
    gt, est = [], []
    for _ in range(8):
        yaw, pitch, roll = rng.uniform(-0.5, 0.5, 3)
        t = rng.normal(0, 1, 3)
        gt.append(make_transform(rotation_from_euler_zyx(yaw, pitch, roll), t))
        est.append(make_transform(rotation_from_euler_zyx(yaw + delta_rad, pitch, roll), t))
    result = pair_errors(np.array(est), np.array(gt))
    np.testing.assert_allclose(result.euler_errors_deg[:, 0], 0.7)
    np.testing.assert_allclose(result.euler_errors_deg[:, 1:], 0.0, atol=1e-9)
    # Rz(yaw) Ry Rx vs Rz(yaw + d) Ry Rx differ by a rotation of angle d.
    assert result.rot_rmse_deg == pytest.approx(0.7)
    assert result.trans_rmse_m == 0.0


def test_euler_error_wraps_around_180() -> None:
    gt = make_transform(rotation_from_euler_zyx(math.radians(179.5), 0.0, 0.0), [0, 0, 0])[None]
    est = make_transform(rotation_from_euler_zyx(math.radians(-179.5), 0.0, 0.0), [0, 0, 0])[None]
    result = pair_errors(est, gt)
    assert abs(result.euler_errors_deg[0, 0]) == pytest.approx(1.0)
    assert result.rot_rmse_deg == pytest.approx(1.0)


def test_relative_motions_and_stride() -> None:
    gt = curvy_trajectory(20)
    motions = relative_motions(gt, stride=3)
    assert motions.shape == (17, 4, 4)
    np.testing.assert_allclose(gt[0] @ motions[0], gt[3], atol=1e-12)
    est = gt.copy()
    est[10:, 1, 3] += 0.2  # one jump between frames 9 and 10
    result = trajectory_pair_errors(est, gt, stride=3)
    assert result.stride == 3 and result.num_pairs == 17
    # Pairs (7,10), (8,11), (9,12) straddle the jump.
    assert int(np.sum(result.trans_errors_m > 1e-9)) == 3


def test_identical_trajectories_give_zeros_everywhere() -> None:
    gt = curvy_trajectory(150)
    report = evaluate(gt.copy(), gt, stride=2)
    assert report.pairs.success_rate == 1.0
    errors = [
        report.drift.t_rel_percent,
        report.drift.r_rel_deg_per_100m,
        report.endpoint.trans_error_m,
        report.endpoint.rot_error_deg,
        report.pairs.rot_rmse_deg,
        report.pairs.rot_mae_deg,
        report.pairs.trans_rmse_m,
        report.pairs.trans_mae_m,
        report.pairs.dcp.euler_rmse_deg,
        report.pairs.dcp.trans_rmse_m,
        report.ate_rpe.ate_trans_rmse_m,
        report.ate_rpe.rpe_trans_rmse_m,
        report.ate_rpe.rpe_rot_rmse_deg,
    ]
    np.testing.assert_allclose(errors, 0.0, atol=1e-5)
    assert report.drift.num_segments > 0


def test_identical_kitti_ground_truth_has_no_spurious_rotation(kitti_gt_poses_dir: Path) -> None:
    # KITTI's 7-digit pose files are orthonormal only to ~2e-7: a transpose-as-inverse would leave
    # up to 0.04 deg of rotation error between a trajectory and itself.
    gt = read_kitti_poses(kitti_gt_poses_dir / "poses" / "04.txt")
    report = evaluate(gt, gt)
    assert report.pairs.rot_errors_deg.max() < 1e-4
    assert report.drift.r_rel_deg_per_100m < 1e-4
    assert report.ate_rpe.rpe_rot_rmse_deg < 1e-3


# ------------------------------------------------------------------------------------- ATE/RPE via evo


def test_ate_rpe_lateral_offset_by_hand() -> None:
    gt = curvy_trajectory(50)
    est = gt.copy()
    est[1:, 1, 3] += 1.0  # 1 m lateral (world y) offset on every pose after frame 0
    result = ate_rpe(est, gt, alignment="origin")
    count = len(gt)
    assert result.ate_trans_rmse_m == pytest.approx(math.sqrt((count - 1) / count))
    assert result.ate_trans_mean_m == pytest.approx((count - 1) / count)
    assert result.ate_trans_max_m == pytest.approx(1.0)
    assert result.ate_trans_median_m == pytest.approx(1.0)
    # Only the step 0 -> 1 is wrong, by 1 m: RPE over the 49 consecutive pairs.
    assert result.rpe_trans_rmse_m == pytest.approx(math.sqrt(1.0 / (count - 1)))
    assert result.rpe_rot_rmse_deg == pytest.approx(0.0, abs=1e-6)
    assert ate_rpe(est, gt, alignment="none").ate_trans_rmse_m == pytest.approx(result.ate_trans_rmse_m)
    # Umeyama without scale is the least-squares rigid fit of the positions (scipy's, here).
    fit = weighted_kabsch(est[:, :3, 3], gt[:, :3, 3])
    aligned = est[:, :3, 3] @ fit[:3, :3].T + fit[:3, 3]
    expected = math.sqrt(np.mean(np.sum((aligned - gt[:, :3, 3]) ** 2, axis=1)))
    se3 = ate_rpe(est, gt, alignment="se3").ate_trans_rmse_m
    assert se3 == pytest.approx(expected, rel=1e-6)
    assert se3 < result.ate_trans_rmse_m


def test_ate_alignment_modes() -> None:
    gt = curvy_trajectory(40)
    world = make_transform(rotation_from_euler_zyx(0.4, 0.1, -0.2), [5.0, -3.0, 1.0])
    est = world[None] @ gt  # the same trajectory in another world frame
    assert ate_rpe(est, gt, alignment="origin").ate_trans_rmse_m == pytest.approx(0.0, abs=1e-6)
    assert ate_rpe(est, gt, alignment="se3").ate_trans_rmse_m == pytest.approx(0.0, abs=1e-6)
    offsets = est[:, :3, 3] - gt[:, :3, 3]
    assert ate_rpe(est, gt, alignment="none").ate_trans_rmse_m == pytest.approx(
        math.sqrt(np.mean(np.sum(offsets**2, axis=1)))
    )
    # RPE is independent of the world frame.
    assert ate_rpe(est, gt, alignment="none").rpe_trans_rmse_m == pytest.approx(0.0, abs=1e-6)


# ------------------------------------------------------------------------------- report and bad input


def test_report_to_dict_is_json_safe_with_units_in_keys() -> None:
    gt = curvy_trajectory(140)
    est = perturbed(gt, seed=9)
    report = evaluate(est, gt)
    data = report.to_dict()
    text = json.dumps(data, allow_nan=False)
    assert set(data) == {"num_poses", "path_length_m", "drift", "endpoint_drift", "pairs", "ate_rpe"}
    for key in ("t_rel_percent", "r_rel_deg_per_100m", "num_segments", "segment_lengths_m", "label"):
        assert key in data["drift"]
    for key in ("rot_rmse_deg", "rot_mae_deg", "trans_rmse_m", "trans_mae_m", "success_rate", "dcp"):
        assert key in data["pairs"]
    for key in ("ate_trans_rmse_m", "rpe_trans_rmse_m", "rpe_rot_rmse_deg", "ate_alignment"):
        assert key in data["ate_rpe"]
    assert "rot_errors_deg" not in text
    with_arrays = report.to_dict(include_arrays=True)
    assert len(with_arrays["pairs"]["rot_errors_deg"]) == len(gt) - 1
    json.dumps(with_arrays, allow_nan=False)


def test_mismatched_lengths_name_both() -> None:
    gt = straight_line(5)
    with pytest.raises(DataError, match=r"estimate has 4 poses but ground truth has 5"):
        evaluate(gt[:4], gt)
    with pytest.raises(DataError, match=r"3 .* 2"):
        pair_errors(yaw_pairs(3), yaw_pairs(2))


@pytest.mark.parametrize(
    ("est", "gt", "pattern"),
    [
        (np.eye(4)[None], np.eye(4)[None], "at least 2"),
        (np.zeros((3, 3, 3)), np.zeros((3, 3, 3)), r"\(M, 4, 4\)"),
        (np.full((3, 4, 4), np.nan), straight_line(3), "NaN or inf"),
        (straight_line(3), np.where(straight_line(3) == 1.0, np.inf, straight_line(3)), "NaN or inf"),
        (straight_line(3) @ np.diag([1.0, 1.0, -1.0, 1.0]), straight_line(3), "not a rotation"),
        (straight_line(3), straight_line(3) @ np.diag([2.0, 2.0, 2.0, 1.0]), "not a rotation"),
    ],
)
def test_bad_input_is_a_data_error(est: np.ndarray, gt: np.ndarray, pattern: str) -> None:
    with pytest.raises(DataError, match=pattern):
        evaluate(est, gt)


def test_bad_options_are_config_errors() -> None:
    gt = straight_line(10)
    with pytest.raises(ConfigError, match="stride"):
        evaluate(gt, gt, stride=0)
    with pytest.raises(ConfigError, match="stride"):
        evaluate(gt, gt, stride=10)
    with pytest.raises(ConfigError, match="step_frames"):
        kitti_drift(gt, gt, step_frames=0)
    with pytest.raises(ConfigError, match="segment_lengths_m"):
        kitti_drift(gt, gt, segment_lengths_m=[10, -1])
    with pytest.raises(ConfigError, match="rot_threshold_deg"):
        pair_errors(gt, gt, rot_threshold_deg=0)
    with pytest.raises(ConfigError, match="alignment"):
        ate_rpe(gt, gt, alignment="sim3")  # type: ignore[arg-type]
