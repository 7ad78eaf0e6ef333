"""What ``run`` and ``compare`` share: build a method by name, run it, score it, save its result folder.

The CLI only parses options and prints; everything a notebook user would call lives here.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import LidarSequence, Points
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import Transform, lidar_to_camera_poses, normalise_to_first
from vcr_odom.io import write_kitti_poses, write_tum_trajectory
from vcr_odom.mapping import VoxelMap
from vcr_odom.metrics import EvaluationReport, evaluate
from vcr_odom.odometry import InitialGuess, OdometryRun, PairwiseOdometry, run_odometry
from vcr_odom.plots import plot_trajectories
from vcr_odom.refine import RefinedOdometry, check_refine
from vcr_odom.registration import METHOD_NAMES, make_polished_method
from vcr_odom.registration.base import BatchRegistrar, Registrar, SequentialOdometry
from vcr_odom.results import write_json

CHECKPOINT_EVERY_FRAMES = 50
"""How often a running trajectory is re-written, so that even a killed run leaves a usable file."""


def parse_method_spec(spec: str) -> tuple[str, str]:
    """``"vcr+icp"`` -> ``("vcr", "icp")``: a method name with an optional ``+<refine>`` polish."""
    name, _, refine = spec.strip().lower().partition("+")
    if name not in METHOD_NAMES:
        raise ConfigError(f"unknown method {name!r} in {spec!r}; valid methods: {', '.join(METHOD_NAMES)}")
    return name, check_refine(refine or "none")


def build_odometry(
    method_spec: str, initial_guess: InitialGuess = InitialGuess.CONSTANT_VELOCITY, **options: Any
) -> SequentialOdometry:
    """A method by its CLI name (``name`` or ``name+refine``), wrapped for the frame loop when pairwise."""
    name, refine = parse_method_spec(method_spec)
    method = make_polished_method(name, refine != "none", **options)
    if isinstance(method, SequentialOdometry):
        if refine != "none":
            raise ConfigError(
                f"{name} is a sequential odometry with its own registration: it takes no +{refine}"
            )
        return method
    if not isinstance(method, Registrar):
        raise TypeError(f"make_method({name!r}) returned {type(method).__name__}, not a registration method")
    if refine != "none" or isinstance(method, BatchRegistrar):
        # A global method takes no guess, so RefinedOdometry("none") is PairwiseOdometry plus batching.
        return RefinedOdometry(method, refine)
    return PairwiseOdometry(method, initial_guess)


def ground_truth_for(sequence: LidarSequence, frame_indices: Sequence[int]) -> NDArray[np.float64] | None:
    """Ground truth of the selected frames, re-anchored so the first selected frame is the identity."""
    gt = sequence.gt_poses
    if gt is None:
        return None
    return normalise_to_first(gt[list(frame_indices)])


@dataclass
class SavedTrajectory:
    kitti: Path
    tum: Path
    frame: str


def save_trajectory(folder: Path, run: OdometryRun, sequence: LidarSequence) -> SavedTrajectory:
    """KITTI (camera frame when calibrated, so it compares with official files) and TUM, plus frame ids."""
    tr = sequence.tr_velo_to_cam
    poses = run.poses if tr is None else lidar_to_camera_poses(run.poses, tr)
    frame = "lidar" if tr is None else "camera"
    kitti = write_kitti_poses(folder / "trajectory_kitti.txt", poses)
    tum = write_tum_trajectory(folder / "trajectory_tum.txt", poses, run.timestamps)
    write_json(folder / "frames.json", {"frame_indices": run.frame_indices, "poses_frame": frame})
    return SavedTrajectory(kitti=kitti, tum=tum, frame=frame)


def checkpointing(folder: Path, sequence: LidarSequence) -> Callable[..., None]:
    """An ``on_frame`` callback that re-writes the partial trajectory every few frames (atomically)."""
    poses: list[Transform] = []
    indices: list[int] = []
    timestamps = sequence.timestamps

    def on_frame(index: int, pose: Transform, *_: Any) -> None:
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


def run_and_save(
    sequence: LidarSequence,
    method: SequentialOdometry,
    frame_indices: Sequence[int],
    folder: Path,
    *,
    progress: Callable[..., None] | None = None,
    plot_title: str = "",
    voxel_map: VoxelMap | None = None,
) -> tuple[OdometryRun, EvaluationReport | None]:
    """Run one method, write its trajectory, metrics and plot into ``folder``.

    With ``voxel_map`` each registered scan is added to it as it comes (the frame is not read twice);
    the plot then shows the trajectory over a top-down view of the map.
    """
    checkpoint = checkpointing(folder, sequence)

    def on_frame(index: int, pose: Transform, points: Points) -> None:
        checkpoint(index, pose)
        if voxel_map is not None:
            voxel_map.add(points, pose)
        if progress is not None:
            progress(index, pose)

    run = run_odometry(sequence, method, frame_indices, on_frame=on_frame)
    if len(run.poses) == 0:
        return run, None
    save_trajectory(folder, run, sequence)
    gt = ground_truth_for(sequence, run.frame_indices)
    report = evaluate(run.poses, gt) if gt is not None and len(run.poses) >= 2 else None
    summary = run_summary(run)
    if report is not None:
        write_json(folder / "metrics.json", {"run": summary, **report.to_dict()})
    else:
        write_json(folder / "metrics.json", {"run": summary, "ground_truth": None})
    plot_trajectories(
        folder / "trajectory.png",
        {run.method: run.poses},
        gt,
        title=plot_title or f"{sequence.name}: {run.method}",
        background_xy=voxel_map.top_down() if voxel_map is not None and len(voxel_map) else None,
    )
    return run, report


def run_summary(run: OdometryRun) -> dict[str, Any]:
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
        "wall_seconds": run.wall_seconds,
        "frames_per_second": run.frames_per_second,
        "stage_seconds": run.stage_seconds,
    }


def polish_starts(run: OdometryRun) -> dict[str, int]:
    """How often each start won the polish (``icp_start`` / ``kiss_start`` of the frames): whether the
    global estimate or the motion prior carried a run."""
    starts = (info.get("icp_start") or info.get("kiss_start") for info in run.per_frame_info)
    return dict(Counter(start for start in starts if start))


@dataclass
class MethodOutcome:
    """One row of a comparison."""

    method: str
    needs_initial_guess: bool
    run: OdometryRun
    report: EvaluationReport | None


ProgressFactory = Callable[[str, int], AbstractContextManager[Callable[[int, Transform], None]]]


def compare_methods(
    sequence: LidarSequence,
    method_names: Sequence[str],
    frame_indices: Sequence[int],
    folder: Path,
    *,
    initial_guess: InitialGuess = InitialGuess.CONSTANT_VELOCITY,
    progress: ProgressFactory | None = None,
    options: Mapping[str, Mapping[str, Any]] | None = None,
) -> list[MethodOutcome]:
    """Run each method on the same frames (one sub-folder each) and overlay their trajectories.

    Ctrl-C stops the method in progress and skips the rest; what finished is kept and plotted.
    ``options`` maps a method name to its constructor options (e.g. ``{"vcr": {"weights": path}}``).
    """
    outcomes: list[MethodOutcome] = []
    for name in method_names:
        odometry = build_odometry(name, initial_guess, **(options or {}).get(name, {}))
        registrar = getattr(odometry, "registrar", None)
        needs_guess = bool(getattr(registrar, "needs_initial_guess", True))
        with progress(name, len(frame_indices)) if progress else nullcontext(None) as advance:
            run, report = run_and_save(sequence, odometry, frame_indices, folder / name, progress=advance)
        outcomes.append(MethodOutcome(name, needs_guess, run, report))
        if run.interrupted:
            break
    if outcomes:
        plot_trajectories(
            folder / "trajectories.png",
            {o.method: o.run.poses for o in outcomes if len(o.run.poses)},
            ground_truth_for(sequence, frame_indices),
            title=f"{sequence.name}, stride {_stride_of(frame_indices)}",
        )
        write_json(
            folder / "compare.json",
            {
                o.method: {"run": run_summary(o.run), **(o.report.to_dict() if o.report else {})}
                for o in outcomes
            },
        )
    return outcomes


def _stride_of(frame_indices: Sequence[int]) -> int:
    return frame_indices[1] - frame_indices[0] if len(frame_indices) > 1 else 1
