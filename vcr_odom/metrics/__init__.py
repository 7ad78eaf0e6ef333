"""Trajectory evaluation: KITTI drift, per-pair errors (the paper's tables), ATE/RPE through evo.

Every function takes the estimate first and the ground truth second, as ``(M, 4, 4)`` float64 pose
arrays of the same length (``evaluate(est, gt)``), in whichever frame the caller chose. KITTI's
published drift figures are computed in the *camera* frame: convert LiDAR-frame trajectories with
``geometry.lidar_to_camera_poses`` first when the numbers must sit beside the KITTI leaderboard.

One module per job: :mod:`.drift` (the devkit's segment drift and the end-point error),
:mod:`.pairs` (relative-motion errors), :mod:`.evo_errors` (ATE/RPE), :mod:`.report` (all of them
for one trajectory), and :mod:`.checks` (input validation they share).
"""

from vcr_odom.metrics.drift import (
    KITTI_SEGMENT_LENGTHS_M,
    KITTI_STEP_FRAMES,
    DriftAtLength,
    DriftResult,
    EndpointDrift,
    endpoint_drift,
    kitti_drift,
    short_segment_lengths,
    trajectory_distances,
)
from vcr_odom.metrics.evo_errors import AteAlignment, AteRpe, ate_rpe
from vcr_odom.metrics.pairs import (
    DcpErrors,
    PairErrors,
    pair_errors,
    relative_motions,
    trajectory_pair_errors,
)
from vcr_odom.metrics.report import EvaluationReport, evaluate

__all__ = [
    "KITTI_SEGMENT_LENGTHS_M",
    "KITTI_STEP_FRAMES",
    "AteAlignment",
    "AteRpe",
    "DcpErrors",
    "DriftAtLength",
    "DriftResult",
    "EndpointDrift",
    "EvaluationReport",
    "PairErrors",
    "ate_rpe",
    "endpoint_drift",
    "evaluate",
    "kitti_drift",
    "pair_errors",
    "relative_motions",
    "short_segment_lengths",
    "trajectory_distances",
    "trajectory_pair_errors",
]
