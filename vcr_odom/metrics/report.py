"""The full evaluation of one trajectory: what ``vcr-odom eval`` prints and every run's metrics.json holds."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from numpy.typing import ArrayLike

from vcr_odom.errors import ConfigError
from vcr_odom.jsonsafe import json_safe
from vcr_odom.metrics.checks import check_pair, positive_int
from vcr_odom.metrics.drift import KITTI_STEP_FRAMES, DriftResult, EndpointDrift, endpoint_drift, kitti_drift
from vcr_odom.metrics.evo_errors import AteAlignment, AteRpe, ate_rpe
from vcr_odom.metrics.pairs import PairErrors, trajectory_pair_errors


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
    est, gt = check_pair(est, gt)
    stride = positive_int(stride, "stride")
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
