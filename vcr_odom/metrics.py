"""Trajectory evaluation: KITTI drift, per-pair errors (the paper's tables), ATE/RPE through evo.

Every function takes the estimate first and the ground truth second, as ``(M, 4, 4)`` float64 pose
arrays of the same length (``evaluate(est, gt)``), in whichever frame the caller chose. KITTI's
published drift figures are computed in the *camera* frame: convert LiDAR-frame trajectories with
``geometry.lidar_to_camera_poses`` first when the numbers must sit beside the KITTI leaderboard.

The KITTI drift is our own implementation of the devkit (``evaluate_odometry.cpp``) because
``kiss_icp.metrics.sequence_error`` only returns the two averages at the fixed 100..800 m lengths; it
agrees with that port to float32 precision once its units are converted (:func:`kiss_icp_equivalent`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vcr_odom.errors import ConfigError, DataError
from vcr_odom.geometry import euler_zyx, project_to_se3, rotation_angle
from vcr_odom.jsonsafe import json_safe

#: The devkit's segment lengths (m): the KITTI odometry benchmark's definition.
KITTI_SEGMENT_LENGTHS_M: tuple[float, ...] = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
#: The devkit starts a segment every 10 frames (one second at 10 Hz).
KITTI_STEP_FRAMES = 10
#: kiss-icp's C++ port converts radians to degrees with 180/3.14 (not pi) and reports deg/m.
KISS_ICP_PI = 3.14

AteAlignment = Literal["origin", "se3", "none"]
EULER_AXES = ("yaw", "pitch", "roll")
XYZ_AXES = ("x", "y", "z")


# --------------------------------------------------------------------------------------------- input


def _as_poses(poses: ArrayLike, name: str) -> NDArray[np.float64]:
    """Validate one ``(M, 4, 4)`` pose array; errors name the argument so the CLI can show one line."""
    try:
        array = np.asarray(poses, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise DataError(f"{name}: could not read the poses as a float array ({error})") from error
    if array.ndim != 3 or array.shape[1:] != (4, 4):
        raise DataError(f"{name}: expected an (M, 4, 4) array of poses, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        bad = np.flatnonzero(~np.all(np.isfinite(array), axis=(1, 2)))
        raise DataError(f"{name}: {len(bad)} pose(s) contain NaN or inf (first at index {bad[0]})")
    return array


def _check_pair(
    est: ArrayLike, gt: ArrayLike, minimum: int = 2, what: str = "poses"
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Validate an estimate/ground-truth pair: same length, at least ``minimum`` entries, finite."""
    est_array = _as_poses(est, f"estimated {what}")
    gt_array = _as_poses(gt, f"ground-truth {what}")
    if len(est_array) != len(gt_array):
        raise DataError(
            f"estimate has {len(est_array)} {what} but ground truth has {len(gt_array)}: "
            "they must match one to one"
        )
    if len(gt_array) < minimum:
        raise DataError(f"need at least {minimum} {what} to evaluate, got {len(gt_array)}")
    return est_array, gt_array


def _positive(value: float, option: str) -> float:
    if not (isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value) and value > 0):
        raise ConfigError(f"{option} must be a positive number, got {value!r}")
    return float(value)


def _positive_int(value: int, option: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"{option} must be a positive integer, got {value!r}")
    return int(value)


def _relative(pose_a: NDArray[np.float64], pose_b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``inv(a) @ b`` with the general matrix inverse, as the devkit and kiss-icp compute it.

    KITTI pose files are printed to 7 digits, so their rotations are orthonormal only to ~2e-7; the
    closed-form ``geometry.invert`` (a transpose) then leaves up to 0.04 deg of spurious rotation in
    ``inv(a) @ a``, whereas the general inverse leaves ~1e-6 deg.
    """
    return np.linalg.solve(pose_a, pose_b)


# ------------------------------------------------------------------------------------------ KITTI drift


def trajectory_distances(poses: ArrayLike) -> NDArray[np.float64]:
    """Cumulative path length (m) at each pose, summed exactly as the devkit does (left to right)."""
    poses = np.asarray(poses, dtype=np.float64)
    delta = poses[1:, :3, 3] - poses[:-1, :3, 3]
    steps = np.sqrt(delta[:, 0] * delta[:, 0] + delta[:, 1] * delta[:, 1] + delta[:, 2] * delta[:, 2])
    return np.concatenate([[0.0], np.cumsum(steps)])


def short_segment_lengths(path_length_m: float, count: int = 8) -> tuple[float, ...]:
    """Segment lengths for a path too short for 100 m segments: ``unit * (1..count)``.

    ``unit`` is the largest 1-2-5 number with ``count * unit <= path length`` (a 50 m path gets
    5, 10, ..., 40 m; a 99 m path 10, ..., 80 m), so the table keeps the devkit's shape (eight
    lengths, the longest at most the path) at a smaller scale, with round numbers a reader can trust.
    """
    if not path_length_m > 0:
        return ()
    target = path_length_m / count
    exponent = math.floor(math.log10(target))
    unit = 0.0
    for power in (exponent - 1, exponent):
        for mantissa in (1.0, 2.0, 5.0):
            candidate = mantissa * 10.0**power
            if candidate <= target * (1 + 1e-12):
                unit = candidate
    return tuple(round(unit * k, 10) for k in range(1, count + 1))


@dataclass
class DriftAtLength:
    """Devkit drift of the segments of one length."""

    length_m: float
    num_segments: int
    t_rel_percent: float  # NaN when the path has no segment of this length
    r_rel_deg_per_100m: float


@dataclass
class DriftResult:
    """KITTI devkit drift: mean over *all* segments of all lengths, as the devkit and kiss-icp average."""

    t_rel_percent: float
    r_rel_deg_per_100m: float
    num_segments: int
    segment_lengths_m: tuple[float, ...]
    step_frames: int
    path_length_m: float
    short_sequence: bool
    label: str
    per_length: list[DriftAtLength] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return json_safe(asdict(self))


def kitti_drift(
    est: ArrayLike,
    gt: ArrayLike,
    *,
    segment_lengths_m: Sequence[float] | None = None,
    step_frames: int = KITTI_STEP_FRAMES,
) -> DriftResult:
    """KITTI devkit relative drift, with the per-length breakdown the devkit plots.

    For every start frame (every ``step_frames``) and length L, the segment ends at the first frame
    whose ground-truth path distance exceeds start + L; its error is
    ``E = inv(inv(est_s) est_e) @ inv(gt_s) gt_e``, ``t_err = |t_E| / L`` and
    ``r_err = acos(clip((trace(R_E) - 1) / 2)) / L`` (dividing by the nominal L, as the devkit does, so
    a straight-line scale error of 1 % with 1 m steps reads 1 % * (L + 1) / L).

    ``segment_lengths_m=None`` uses 100..800 m, or, when the path is too short for a single 100 m
    segment, :func:`short_segment_lengths`, flagged ``short_sequence`` and named in ``label``.
    """
    est, gt = _check_pair(est, gt)
    step_frames = _positive_int(step_frames, "step_frames")
    dist = trajectory_distances(gt)
    path_length_m = float(dist[-1])

    short = False
    if segment_lengths_m is None:
        lengths = KITTI_SEGMENT_LENGTHS_M
        # The devkit needs dist > start + L, so no 100 m segment exists unless the path exceeds 100 m.
        if not path_length_m > KITTI_SEGMENT_LENGTHS_M[0]:
            lengths = short_segment_lengths(path_length_m)
            short = True
    else:
        lengths = tuple(_positive(length, "segment_lengths_m") for length in segment_lengths_m)
        if not lengths:
            raise ConfigError("segment_lengths_m must name at least one length")

    first = np.arange(0, len(gt), step_frames)
    t_errs: list[NDArray[np.float64]] = []
    r_errs: list[NDArray[np.float64]] = []
    per_length: list[DriftAtLength] = []
    for length in lengths:
        # searchsorted 'right' = the first index whose distance is strictly greater (the devkit's test).
        last = np.searchsorted(dist, dist[first] + length, side="right")
        valid = last < len(gt)
        starts, ends = first[valid], last[valid]
        delta_gt = _relative(gt[starts], gt[ends])
        delta_est = _relative(est[starts], est[ends])
        error = _relative(delta_est, delta_gt)
        t_err = np.linalg.norm(error[:, :3, 3], axis=1) / length
        r_err = np.atleast_1d(rotation_angle(error)) / length if len(error) else np.zeros(0)
        t_errs.append(t_err)
        r_errs.append(r_err)
        per_length.append(
            DriftAtLength(
                length_m=float(length),
                num_segments=len(t_err),
                t_rel_percent=float(100.0 * t_err.mean()) if len(t_err) else math.nan,
                r_rel_deg_per_100m=float(np.degrees(r_err.mean()) * 100.0) if len(r_err) else math.nan,
            )
        )
    all_t = np.concatenate(t_errs) if t_errs else np.zeros(0)
    all_r = np.concatenate(r_errs) if r_errs else np.zeros(0)
    count = len(all_t)

    lengths_text = ", ".join(f"{length:g}" for length in lengths)
    if short:
        label = (
            f"short sequence ({path_length_m:.1f} m path, under the KITTI 100 m minimum): "
            f"drift over segments of {lengths_text} m, not comparable with KITTI figures"
        )
    elif segment_lengths_m is None:
        label = "KITTI devkit drift over segments of 100-800 m"
    else:
        label = f"devkit-style drift over segments of {lengths_text} m"
    if count == 0:
        label += f" (no segment fits the {path_length_m:.1f} m path)"

    return DriftResult(
        t_rel_percent=float(100.0 * all_t.mean()) if count else math.nan,
        r_rel_deg_per_100m=float(np.degrees(all_r.mean()) * 100.0) if count else math.nan,
        num_segments=count,
        segment_lengths_m=tuple(float(length) for length in lengths),
        step_frames=step_frames,
        path_length_m=path_length_m,
        short_sequence=short,
        label=label,
        per_length=per_length,
    )


def kiss_icp_equivalent(drift: DriftResult) -> tuple[float, float]:
    """Our drift in the units ``kiss_icp.metrics.sequence_error`` returns: (%, "deg/m" with pi = 3.14).

    kiss-icp's port averages rad/m and multiplies by 180 / 3.14 without the factor 100, so its second
    number is deg/m, about 0.05 % high. Only meaningful with the default 100..800 m lengths.
    """
    r_rad_per_m = math.radians(drift.r_rel_deg_per_100m) / 100.0
    return drift.t_rel_percent, r_rad_per_m * 180.0 / KISS_ICP_PI


@dataclass
class EndpointDrift:
    """Error of the final pose relative to the first: the figure every sequence length gets."""

    trans_error_m: float
    trans_error_percent: float  # of the ground-truth path length; NaN for a path of length 0
    rot_error_deg: float
    path_length_m: float

    def to_dict(self) -> dict[str, Any]:
        return json_safe(asdict(self))


def endpoint_drift(est: ArrayLike, gt: ArrayLike) -> EndpointDrift:
    """Devkit-style error of the whole run, first frame to last: ``|t_E|`` in m and % of path, angle(R_E).

    ``|t_E|`` equals the distance between the estimated and true final positions seen from frame 0.
    """
    est, gt = _check_pair(est, gt)
    error = _relative(_relative(est[0], est[-1]), _relative(gt[0], gt[-1]))
    trans_m = float(np.linalg.norm(error[:3, 3]))
    path_length_m = float(trajectory_distances(gt)[-1])
    return EndpointDrift(
        trans_error_m=trans_m,
        trans_error_percent=100.0 * trans_m / path_length_m if path_length_m > 0 else math.nan,
        rot_error_deg=math.degrees(rotation_angle(error)),
        path_length_m=path_length_m,
    )


# ------------------------------------------------------------------------------------- per-pair errors


def relative_motions(poses: ArrayLike, stride: int = 1) -> NDArray[np.float64]:
    """Relative transforms ``inv(P_i) P_{i+stride}`` for every i (overlapping pairs), ``(M - stride, 4, 4)``."""
    poses = _as_poses(poses, "poses")
    stride = _positive_int(stride, "stride")
    if len(poses) <= stride:
        raise DataError(f"need more than stride={stride} poses to form pairs, got {len(poses)}")
    return _relative(poses[:-stride], poses[stride:])


def _rmse(values: NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def _mae(values: NDArray[np.float64]) -> float:
    return float(np.mean(np.abs(values)))


@dataclass
class DcpErrors:
    """The paper's (DCP-style) Table III figures: Euler z-y-x angle errors and per-component translation.

    Pooled figures are over all pairs and all three axes; the per-axis dictionaries break them down.
    """

    euler_mse_deg2: float
    euler_rmse_deg: float
    euler_mae_deg: float
    euler_rmse_deg_per_axis: dict[str, float]
    euler_mae_deg_per_axis: dict[str, float]
    trans_mse_m2: float
    trans_rmse_m: float
    trans_mae_m: float
    trans_rmse_m_per_axis: dict[str, float]
    trans_mae_m_per_axis: dict[str, float]


@dataclass
class PairErrors:
    """Per-pair relative-motion errors: geodesic rotation (deg), translation distance (m), success rate."""

    num_pairs: int
    stride: int
    rot_rmse_deg: float
    rot_mae_deg: float
    trans_rmse_m: float
    trans_mae_m: float
    success_rate: float  # fraction of pairs under both thresholds
    success_rot_threshold_deg: float
    success_trans_threshold_m: float
    dcp: DcpErrors
    # Per-pair arrays for plotting (left out of to_dict unless asked for).
    rot_errors_deg: NDArray[np.float64] = field(repr=False)
    trans_errors_m: NDArray[np.float64] = field(repr=False)
    euler_errors_deg: NDArray[np.float64] = field(repr=False)  # (N, 3) yaw, pitch, roll
    trans_component_errors_m: NDArray[np.float64] = field(repr=False)  # (N, 3) x, y, z
    success: NDArray[np.bool_] = field(repr=False)

    _ARRAYS = ("rot_errors_deg", "trans_errors_m", "euler_errors_deg", "trans_component_errors_m", "success")

    def to_dict(self, include_arrays: bool = False) -> dict[str, Any]:
        result = {
            key: value for key, value in self.__dict__.items() if key not in self._ARRAYS and key != "dcp"
        }
        result["dcp"] = asdict(self.dcp)
        if include_arrays:
            result.update({key: getattr(self, key) for key in self._ARRAYS})
        return json_safe(result)


def pair_errors(
    est_relative: ArrayLike,
    gt_relative: ArrayLike,
    *,
    rot_threshold_deg: float = 2.0,
    trans_threshold_m: float = 0.5,
    stride: int = 1,
) -> PairErrors:
    """Errors of N estimated relative transforms against the true ones (``(N, 4, 4)`` each).

    Rotation error is the geodesic angle of ``inv(R_gt) R_est``; translation error is
    ``|t_est - t_gt|``. A pair succeeds when both are strictly under the thresholds (2 deg, 0.5 m by
    default, the issues' convention). Euler errors are differences of z-y-x angles wrapped to
    [-180, 180) so that a yaw near +-180 deg does not count as a 360 deg error. ``stride`` is
    recorded only, to label the result.
    """
    est, gt = _check_pair(est_relative, gt_relative, minimum=1, what="relative transforms")
    rot_threshold_deg = _positive(rot_threshold_deg, "rot_threshold_deg")
    trans_threshold_m = _positive(trans_threshold_m, "trans_threshold_m")
    stride = _positive_int(stride, "stride")

    rot_deg = np.degrees(np.atleast_1d(rotation_angle(np.linalg.solve(gt[:, :3, :3], est[:, :3, :3]))))
    trans_components = est[:, :3, 3] - gt[:, :3, 3]
    trans_m = np.linalg.norm(trans_components, axis=1)
    euler_deg = np.degrees(euler_zyx(est) - euler_zyx(gt))
    euler_deg = (euler_deg + 180.0) % 360.0 - 180.0
    success = (rot_deg < rot_threshold_deg) & (trans_m < trans_threshold_m)

    dcp = DcpErrors(
        euler_mse_deg2=float(np.mean(np.square(euler_deg))),
        euler_rmse_deg=_rmse(euler_deg),
        euler_mae_deg=_mae(euler_deg),
        euler_rmse_deg_per_axis={axis: _rmse(euler_deg[:, k]) for k, axis in enumerate(EULER_AXES)},
        euler_mae_deg_per_axis={axis: _mae(euler_deg[:, k]) for k, axis in enumerate(EULER_AXES)},
        trans_mse_m2=float(np.mean(np.square(trans_components))),
        trans_rmse_m=_rmse(trans_components),
        trans_mae_m=_mae(trans_components),
        trans_rmse_m_per_axis={axis: _rmse(trans_components[:, k]) for k, axis in enumerate(XYZ_AXES)},
        trans_mae_m_per_axis={axis: _mae(trans_components[:, k]) for k, axis in enumerate(XYZ_AXES)},
    )
    return PairErrors(
        num_pairs=len(est),
        stride=stride,
        rot_rmse_deg=_rmse(rot_deg),
        rot_mae_deg=_mae(rot_deg),
        trans_rmse_m=_rmse(trans_m),
        trans_mae_m=_mae(trans_m),
        success_rate=float(np.mean(success)),
        success_rot_threshold_deg=rot_threshold_deg,
        success_trans_threshold_m=trans_threshold_m,
        dcp=dcp,
        rot_errors_deg=rot_deg,
        trans_errors_m=trans_m,
        euler_errors_deg=euler_deg,
        trans_component_errors_m=trans_components,
        success=success,
    )


def trajectory_pair_errors(
    est: ArrayLike,
    gt: ArrayLike,
    *,
    stride: int = 1,
    rot_threshold_deg: float = 2.0,
    trans_threshold_m: float = 0.5,
) -> PairErrors:
    """:func:`pair_errors` on the pairs (i, i + stride) of two trajectories."""
    est, gt = _check_pair(est, gt)
    return pair_errors(
        relative_motions(est, stride),
        relative_motions(gt, stride),
        rot_threshold_deg=rot_threshold_deg,
        trans_threshold_m=trans_threshold_m,
        stride=stride,
    )


# ------------------------------------------------------------------------------------- ATE/RPE via evo


@dataclass
class AteRpe:
    """evo's absolute trajectory error (translation) and relative pose error (consecutive pairs)."""

    ate_alignment: str
    ate_trans_rmse_m: float
    ate_trans_mean_m: float
    ate_trans_median_m: float
    ate_trans_max_m: float
    rpe_delta_frames: int
    rpe_trans_rmse_m: float
    rpe_rot_rmse_deg: float

    def to_dict(self) -> dict[str, Any]:
        return json_safe(asdict(self))


def ate_rpe(
    est: ArrayLike,
    gt: ArrayLike,
    *,
    alignment: AteAlignment = "origin",
    rpe_delta_frames: int = 1,
) -> AteRpe:
    """ATE and RPE computed by evo's API (not re-implemented).

    ``alignment``: ``"origin"`` (default) re-anchors the estimate so that its first pose equals the
    ground truth's (evo's ``align_origin``): the KITTI odometry convention, where both start at the
    identity, so the ATE includes the drift that heading errors early in the run cause. ``"se3"``
    applies evo's Umeyama alignment (no scale; what ``evo_ape --align`` and kiss-icp's ATE do), which
    hides a constant offset and reports the shape error. ``"none"`` compares the poses as given.
    """
    from evo.core import metrics as evo_metrics  # deferred: evo is only needed here
    from evo.core.trajectory import PosePath3D

    est, gt = _check_pair(est, gt)
    rpe_delta_frames = _positive_int(rpe_delta_frames, "rpe_delta_frames")
    if alignment not in ("origin", "se3", "none"):
        raise ConfigError(f"alignment must be 'origin', 'se3' or 'none', got {alignment!r}")
    if rpe_delta_frames >= len(gt):
        raise ConfigError(f"rpe_delta_frames={rpe_delta_frames} needs more than {len(gt)} poses")

    gt, est = project_to_se3(gt), project_to_se3(est)
    traj_gt = PosePath3D(poses_se3=list(gt))
    traj_est = PosePath3D(poses_se3=list(est))
    traj_est_aligned = PosePath3D(poses_se3=list(est))
    if alignment == "origin":
        traj_est_aligned.align_origin(traj_gt)
    elif alignment == "se3":
        if len(gt) < 3:
            raise DataError(f"SE(3) alignment needs at least 3 poses, got {len(gt)}")
        traj_est_aligned.align(traj_gt, correct_scale=False)

    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((traj_gt, traj_est_aligned))
    ape_stats = ape.get_all_statistics()

    def rpe(relation: Any) -> float:
        metric = evo_metrics.RPE(
            relation, delta=rpe_delta_frames, delta_unit=evo_metrics.Unit.frames, all_pairs=False
        )
        metric.process_data((traj_gt, traj_est))
        return float(metric.get_statistic(evo_metrics.StatisticsType.rmse))

    return AteRpe(
        ate_alignment=alignment,
        ate_trans_rmse_m=float(ape_stats["rmse"]),
        ate_trans_mean_m=float(ape_stats["mean"]),
        ate_trans_median_m=float(ape_stats["median"]),
        ate_trans_max_m=float(ape_stats["max"]),
        rpe_delta_frames=rpe_delta_frames,
        rpe_trans_rmse_m=rpe(evo_metrics.PoseRelation.translation_part),
        rpe_rot_rmse_deg=rpe(evo_metrics.PoseRelation.rotation_angle_deg),
    )


# -------------------------------------------------------------------------------------------- report


@dataclass
class EvaluationReport:
    """Everything ``vcr-odom eval`` prints and writes to metrics.json."""

    num_poses: int
    path_length_m: float
    drift: DriftResult
    endpoint: EndpointDrift
    pairs: PairErrors
    ate_rpe: AteRpe

    def to_dict(self, include_arrays: bool = False) -> dict[str, Any]:
        """JSON-safe nested dict (units in the key names; figures that do not exist are None)."""
        return {
            "num_poses": int(self.num_poses),
            "path_length_m": json_safe(self.path_length_m),
            "drift": self.drift.to_dict(),
            "endpoint_drift": self.endpoint.to_dict(),
            "pairs": self.pairs.to_dict(include_arrays=include_arrays),
            "ate_rpe": self.ate_rpe.to_dict(),
        }


def evaluate(
    est: ArrayLike,
    gt: ArrayLike,
    *,
    stride: int = 1,
    segment_lengths_m: Sequence[float] | None = None,
    step_frames: int = KITTI_STEP_FRAMES,
    ate_alignment: AteAlignment = "origin",
    rpe_delta_frames: int = 1,
    rot_threshold_deg: float = 2.0,
    trans_threshold_m: float = 0.5,
) -> EvaluationReport:
    """All the figures for one estimated trajectory against ground truth (same length, same frame).

    ``stride`` sets the pairs (i, i + stride) of the per-pair errors; drift, ATE and RPE use every pose.
    """
    est, gt = _check_pair(est, gt)
    stride = _positive_int(stride, "stride")
    if stride >= len(gt):
        raise ConfigError(f"stride={stride} needs more than {len(gt)} poses")
    drift = kitti_drift(est, gt, segment_lengths_m=segment_lengths_m, step_frames=step_frames)
    return EvaluationReport(
        num_poses=len(gt),
        path_length_m=drift.path_length_m,
        drift=drift,
        endpoint=endpoint_drift(est, gt),
        pairs=trajectory_pair_errors(
            est,
            gt,
            stride=stride,
            rot_threshold_deg=rot_threshold_deg,
            trans_threshold_m=trans_threshold_m,
        ),
        ate_rpe=ate_rpe(est, gt, alignment=ate_alignment, rpe_delta_frames=rpe_delta_frames),
    )
