"""Absolute trajectory error and relative pose error, computed by evo's API rather than re-implemented."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vcr_odom.errors import ConfigError, DataError
from vcr_odom.geometry import project_to_se3
from vcr_odom.jsonsafe import json_safe
from vcr_odom.metrics.checks import check_pair, positive_int

AteAlignment = Literal["origin", "se3", "none"]


@dataclass
class AteRpe:
    """evo's absolute trajectory error (translation) and relative pose error (consecutive pairs)."""

    ate_alignment: str
    ate_trans_rmse_m: float
    ate_trans_mean_m: float
    ate_trans_median_m: float
    ate_trans_max_m: float
    ate_se3_trans_rmse_m: float | None
    """The ATE RMSE after evo's SE(3) Umeyama alignment whatever ``ate_alignment`` is: the figure
    ``evo_ape -a`` and kiss-icp print, so a table can sit beside published numbers (None under 3 poses)."""
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

    est, gt = check_pair(est, gt)
    rpe_delta_frames = positive_int(rpe_delta_frames, "rpe_delta_frames")
    if alignment not in ("origin", "se3", "none"):
        raise ConfigError(f"alignment must be 'origin', 'se3' or 'none', got {alignment!r}")
    if rpe_delta_frames >= len(gt):
        raise ConfigError(f"rpe_delta_frames={rpe_delta_frames} needs more than {len(gt)} poses")

    gt, est = project_to_se3(gt), project_to_se3(est)
    if alignment == "se3" and len(gt) < 3:
        raise DataError(f"SE(3) alignment needs at least 3 poses, got {len(gt)}")
    traj_gt = PosePath3D(poses_se3=list(gt))
    traj_est = PosePath3D(poses_se3=list(est))
    ape_stats = _ape_statistics(est, traj_gt, alignment)
    if ape_stats is None:
        raise DataError(
            "SE(3) alignment is not possible: the ground-truth positions are degenerate (all on one "
            "line or one point), so evo's Umeyama fit has no unique rotation; use --align origin"
        )
    se3_stats = ape_stats if alignment == "se3" else None
    if se3_stats is None and len(gt) >= 3:
        se3_stats = _ape_statistics(est, traj_gt, "se3")

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
        ate_se3_trans_rmse_m=None if se3_stats is None else float(se3_stats["rmse"]),
        rpe_delta_frames=rpe_delta_frames,
        rpe_trans_rmse_m=rpe(evo_metrics.PoseRelation.translation_part),
        rpe_rot_rmse_deg=rpe(evo_metrics.PoseRelation.rotation_angle_deg),
    )


def _ape_statistics(
    est: NDArray[np.float64], traj_gt: Any, alignment: AteAlignment
) -> dict[str, float] | None:
    """evo's APE (translation part) statistics of ``est`` after ``alignment`` onto ``traj_gt``; None
    where evo finds the SE(3) fit degenerate (a straight or stationary ground truth)."""
    from evo.core import metrics as evo_metrics
    from evo.core.geometry import GeometryException
    from evo.core.trajectory import PosePath3D

    aligned = PosePath3D(poses_se3=list(est))
    if alignment == "origin":
        aligned.align_origin(traj_gt)
    elif alignment == "se3":
        try:
            aligned.align(traj_gt, correct_scale=False)
        except GeometryException:
            return None
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((traj_gt, aligned))
    return ape.get_all_statistics()
