"""What a run leaves in its result folder: trajectory files, a summary, periodic checkpoints.

The trajectory files (``trajectory_kitti.txt``, ``trajectory_tum.txt``) and ``frames.json`` are one
unit with the result marker (:func:`vcr_odom.results.result_unit`): a checkpoint publishes all three
with a ``partial`` marker, the end of a run all three with the scores and the final marker, so the
three always describe the same frames, whenever the run stops.
"""

from __future__ import annotations

import re
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
from vcr_odom.odometry.frame_loop import OdometryRun
from vcr_odom.results import Status, result_unit, write_json, write_marker

CHECKPOINT_EVERY_FRAMES = 50
"""How often a running trajectory is re-published, so that even a killed run leaves a usable file."""

TRAJECTORY_FILES = ("trajectory_kitti.txt", "trajectory_tum.txt", "frames.json")
"""The files that always describe the same frames (and the marker's ``frames_done``)."""

Extras = Callable[[Path], str | None]
"""Writes more files (scores, a plot) into a unit's folder before its marker; returns why the unit is
only ``partial`` (a file it could not write, the others kept), or None."""


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


def save_trajectory(
    folder: Path,
    run: OdometryRun,
    sequence: LidarSequence,
    *,
    frames_selected: int | None = None,
    status: Status = "complete",
    reason: str = "",
    extras: Extras | None = None,
) -> SavedTrajectory:
    """Publish KITTI (camera frame when calibrated, so it compares with official files) and TUM
    trajectories, the frame ids, whatever ``extras`` writes, and the marker, as one unit."""
    tr = sequence.tr_velo_to_cam
    poses = run.poses if tr is None or len(run.poses) == 0 else lidar_to_camera_poses(run.poses, tr)
    frame = "lidar" if tr is None else "camera"
    selected = len(run.frame_indices) if frames_selected is None else frames_selected
    with result_unit(folder) as unit:
        write_kitti_poses(unit / "trajectory_kitti.txt", poses)
        write_tum_trajectory(unit / "trajectory_tum.txt", poses, run.timestamps)
        write_json(unit / "frames.json", {"frame_indices": run.frame_indices, "poses_frame": frame})
        missing = extras(unit) if extras is not None else None
        if missing:
            status, reason = "partial", "; ".join(filter(None, (reason, missing)))
        write_marker(unit, status, len(run.frame_indices), selected, reason, method=run.method)
    return SavedTrajectory(kitti=folder / TRAJECTORY_FILES[0], tum=folder / TRAJECTORY_FILES[1], frame=frame)


class Checkpoints:
    """The per-frame callback of a run: keeps each pose as it comes and re-publishes the trajectory so
    far as a ``partial`` unit every ``every`` frames (default :data:`CHECKPOINT_EVERY_FRAMES`); :meth:`save` publishes it on demand (Ctrl-C, an
    error). ``on_saved`` is called after each publication (to move ``latest``)."""

    def __init__(
        self,
        folder: Path,
        sequence: LidarSequence,
        frames_selected: int,
        method: str = "partial",
        every: int | None = None,
        on_saved: Callable[[], Any] | None = None,
    ) -> None:
        self.folder = folder
        self.sequence = sequence
        self.frames_selected = frames_selected
        self.method = method
        self.every = max(int(CHECKPOINT_EVERY_FRAMES if every is None else every), 1)
        self.on_saved = on_saved
        self.poses: list[Transform] = []
        self.indices: list[int] = []

    @property
    def frames_done(self) -> int:
        return len(self.indices)

    def __call__(self, index: int, pose: Transform) -> None:
        self.poses.append(np.asarray(pose, dtype=np.float64))
        self.indices.append(index)
        if len(self.poses) % self.every == 0:
            self.save(
                f"checkpoint after {len(self.poses)} of {self.frames_selected} frames; the run was "
                "still going (if nothing newer replaced this, it was stopped or killed)"
            )

    def save(self, reason: str) -> bool:
        """Publish the frames so far as a ``partial`` unit; False (nothing written) when there are none."""
        if not self.poses:
            return False
        partial = OdometryRun(
            method=self.method,
            frame_indices=list(self.indices),
            poses=np.stack(self.poses),
            timestamps=np.asarray(self.sequence.timestamps)[self.indices],
            stage_seconds={},
            wall_seconds=0.0,
            interrupted=True,
        )
        save_trajectory(
            self.folder,
            partial,
            self.sequence,
            frames_selected=self.frames_selected,
            status="partial",
            reason=reason,
        )
        if self.on_saved is not None:
            self.on_saved()
        return True


def run_summary(run: OdometryRun) -> dict[str, Any]:
    """The ``run`` block of metrics.json: what was processed, what was flagged, how fast, and for a
    SLAM method (``slam``) its loop closures."""
    slam = {"slam": run.slam} if run.slam else {}
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
        "single_plane_frames": run.single_plane_frames,
        "weak_axis_frames": run.weak_axis_frames,
        "polish_starts": polish_starts(run),
        "polish_voxel_m": run.per_frame_info[0].get("polish_voxel_m") if run.per_frame_info else None,
        "polish_point_to_plane": (
            run.per_frame_info[0].get("polish_point_to_plane") if run.per_frame_info else None
        ),
        "polish_engine": run.per_frame_info[0].get("polish_engine") if run.per_frame_info else None,
        "global_registration": global_consultations(run),
        "wall_seconds": run.wall_seconds,
        "frames_per_second": run.frames_per_second,
        "stage_seconds": run.stage_seconds,
        **slam,
    }


def global_consultations(run: OdometryRun) -> dict[str, int]:
    """With ``consult="on-doubt"``: why the global registration ran (or ``not needed``), per frame count,
    by kind of reason (``poor fit``, ``far from the prior``, ...): the figures of each reason are per frame."""
    return dict(Counter(reason_kind(info["global"]) for info in run.per_frame_info if info.get("global")))


def reason_kind(reason: str) -> str:
    """``"poor fit 0.51 (median 0.63)"`` -> ``"poor fit"``; ``"far from the prior: 0.6 m, 3 deg"`` ->
    ``"far from the prior"``; ``"most recent pairs in doubt (11 of 20)"`` -> ``"most recent pairs in
    doubt"``; a reason without figures is its own kind."""
    head = reason.split(":")[0]
    return re.sub(r"\s+\(?[-\d.].*$", "", head).strip() or reason


def polish_starts(run: OdometryRun) -> dict[str, int]:
    """How often each start won the polish: whether the global estimate or the motion prior carried a run."""
    return dict(Counter(info["polish_start"] for info in run.per_frame_info if info.get("polish_start")))
