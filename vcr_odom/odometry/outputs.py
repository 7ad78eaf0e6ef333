"""What a run leaves in its result folder: trajectory files, a summary, periodic checkpoints."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import LidarSequence
from vcr_odom.geometry import Transform, lidar_to_camera_poses, normalise_to_first
from vcr_odom.io import write_kitti_poses, write_tum_trajectory
from vcr_odom.odometry.loop import OdometryRun
from vcr_odom.results import write_json

CHECKPOINT_EVERY_FRAMES = 50
"""How often a running trajectory is re-written, so that even a killed run leaves a usable file."""


@dataclass
class SavedTrajectory:
    kitti: Path
    tum: Path
    frame: str


def ground_truth_for(sequence: LidarSequence, frame_indices: Sequence[int]) -> NDArray[np.float64] | None:
    """Ground truth of the selected frames, re-anchored so the first selected frame is the identity."""
    gt = sequence.gt_poses
    if gt is None:
        return None
    return normalise_to_first(gt[list(frame_indices)])


def save_trajectory(folder: Path, run: OdometryRun, sequence: LidarSequence) -> SavedTrajectory:
    """KITTI (camera frame when calibrated, so it compares with official files) and TUM, plus frame ids."""
    tr = sequence.tr_velo_to_cam
    poses = run.poses if tr is None else lidar_to_camera_poses(run.poses, tr)
    frame = "lidar" if tr is None else "camera"
    kitti = write_kitti_poses(folder / "trajectory_kitti.txt", poses)
    tum = write_tum_trajectory(folder / "trajectory_tum.txt", poses, run.timestamps)
    write_json(folder / "frames.json", {"frame_indices": run.frame_indices, "poses_frame": frame})
    return SavedTrajectory(kitti=kitti, tum=tum, frame=frame)


def checkpointing(folder: Path, sequence: LidarSequence) -> Callable[[int, Transform], None]:
    """A per-frame callback that re-writes the partial trajectory every few frames (atomically)."""
    poses: list[Transform] = []
    indices: list[int] = []
    timestamps = sequence.timestamps

    def on_frame(index: int, pose: Transform) -> None:
        poses.append(pose)
        indices.append(index)
        if len(poses) % CHECKPOINT_EVERY_FRAMES == 0:
            partial = OdometryRun(
                method="partial",
                frame_indices=list(indices),
                poses=np.stack(poses),
                timestamps=timestamps[indices],
                stage_seconds={},
                wall_seconds=0.0,
                interrupted=True,
            )
            save_trajectory(folder, partial, sequence)

    return on_frame


def run_summary(run: OdometryRun) -> dict[str, Any]:
    """The ``run`` block of metrics.json: what was processed, what was flagged, how fast."""
    return {
        "method": run.method,
        "frames_processed": len(run.frame_indices),
        "first_frame": run.frame_indices[0] if run.frame_indices else None,
        "last_frame": run.frame_indices[-1] if run.frame_indices else None,
        "interrupted": run.interrupted,
        "flagged_frames": run.flagged_frames,
        "flagged_reasons": {
            index: info["reason"]
            for index, info in zip(run.frame_indices, run.per_frame_info, strict=False)
            if info.get("flagged")
        },
        "polish_starts": polish_starts(run),
        "global_registration": global_consultations(run),
        "wall_seconds": run.wall_seconds,
        "frames_per_second": run.frames_per_second,
        "stage_seconds": run.stage_seconds,
    }


def global_consultations(run: OdometryRun) -> dict[str, int]:
    """With ``consult="on-doubt"``: why the global registration ran (or ``not needed``), per frame count."""
    return dict(Counter(info["global"] for info in run.per_frame_info if info.get("global")))


def polish_starts(run: OdometryRun) -> dict[str, int]:
    """How often each start won the polish: whether the global estimate or the motion prior carried a run."""
    return dict(Counter(info["polish_start"] for info in run.per_frame_info if info.get("polish_start")))
