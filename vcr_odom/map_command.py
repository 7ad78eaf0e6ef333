"""``vcr-odom map``: odometry, then loop closure and a pose graph, into a result folder like ``run``'s.

Phases: the odometry (nodes recorded as it goes, checkpoints as in ``run``), the loop phase
(:func:`~vcr_odom.loops.pipeline.close_loops`), and the map from the nodes' scans at the optimised
poses. The folder is published as one unit at the end (``trajectory_*`` the optimised poses,
``odometry_*`` the odometry's, ``loops.json``, ``map.ply``, ``metrics.json``, the plot); a run stopped
after the odometry keeps the odometry's trajectory, marked partial with the reason.
"""

from __future__ import annotations

import dataclasses
import resource
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
from pydantic import model_validator

from vcr_odom.data.base import LidarSequence, Points
from vcr_odom.errors import DataError
from vcr_odom.geometry import Transform, lidar_to_camera_poses
from vcr_odom.io import describe_os_error, write_kitti_poses, write_tum_trajectory
from vcr_odom.loops import pipeline
from vcr_odom.loops.nodes import Node, NodeRecorder
from vcr_odom.loops.pipeline import Phases, loop_network, loops_json
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.loops.verify import CHECKS, LoopDecision
from vcr_odom.mapping import VoxelMap
from vcr_odom.metrics import EvaluationReport, evaluate
from vcr_odom.odometry.chain import Odometry
from vcr_odom.odometry.frame_loop import OdometryRun, run_odometry
from vcr_odom.odometry.outputs import Checkpoints, ground_truth_for, run_summary, save_trajectory
from vcr_odom.odometry.run import FrameHook, ProgressFactory, RunSettings, method_for
from vcr_odom.plots import plot_trajectories
from vcr_odom.registration.base import SequentialOdometry
from vcr_odom.registration.vcr import VcrRegistrar
from vcr_odom.results import (
    check_output_folder,
    create_result_folder,
    holds_trajectory,
    interruption_reason,
    note_kept,
    point_latest_at,
    remove_result_folder,
    write_json,
)


class MapSettings(RunSettings, LoopSettings):
    """Everything ``vcr-odom map`` is told: ``run``'s options (without ``--save-map``: the map is
    always written into the folder) and the loop closure's."""

    @model_validator(mode="after")
    def _no_save_map(self) -> MapSettings:
        if self.save_map is not None:
            raise ValueError(
                "save_map does not apply to map: map.ply is always written into the result folder, "
                "from the optimised poses"
            )
        return self


@dataclass
class MapOutcome:
    folder: Path | None
    sequence: LidarSequence
    odometry: OdometryRun
    poses: np.ndarray
    decisions: list[LoopDecision]
    report: EvaluationReport | None
    odometry_report: EvaluationReport | None
    seconds: dict[str, float]

    @property
    def mapped_run(self) -> OdometryRun:
        """The odometry's run with the optimised poses, its loop count and the whole map's wall time
        (a comparison's row: its frames/s is the map's, not the odometry's)."""
        closures = {"loop_closures": sum(d.accepted for d in self.decisions)}
        return dataclasses.replace(
            self.odometry,
            method=f"{self.odometry.method}+loops",
            poses=self.poses,
            slam=closures,
            wall_seconds=sum(self.seconds.values()),
        )


def map_sequence(
    settings: MapSettings, progress: ProgressFactory | None = None, on_frame: FrameHook | None = None
) -> MapOutcome:
    """Check everything, build the odometry and the loop network, and map into a new result folder."""
    check_output_folder(settings.results_dir, "--results-dir")
    sequence = settings.selection.open()
    indices = settings.selection.indices(sequence)
    odometry = method_for(settings, sequence.timestamps[indices])
    # --no-loops maps the odometry alone: no network to load
    network = (
        loop_network(settings.weights, settings.device, settings.vcr_points, odometry)
        if settings.loops
        else None
    )
    folder = create_result_folder(
        settings.results_dir,
        f"map_{sequence.label}_{settings.spec}",
        {"command": "map", "sequence": sequence.name, **settings.to_dict()},
        frames_selected=len(indices),
    )
    return map_and_save(
        sequence,
        odometry,
        network,
        indices,
        folder,
        LoopSettings(**{k: getattr(settings, k) for k in LoopSettings.model_fields}),
        progress=progress,
        on_saved=lambda: point_latest_at(settings.results_dir, folder),
        hook=on_frame,
    )


def map_and_save(
    sequence: LidarSequence,
    odometry: Odometry | SequentialOdometry,
    network: VcrRegistrar | None,
    indices: Sequence[int],
    folder: Path,
    options: LoopSettings,
    *,
    progress: ProgressFactory | None = None,
    on_saved: Callable[[], Any] | None = None,
    hook: FrameHook | None = None,
) -> MapOutcome:
    """Run the odometry with a node recorder, close loops, optimise and publish ``folder``'s unit
    (see the module doc); ``folder`` is None in the outcome where nothing was kept."""
    spec = odometry.name
    recorder = NodeRecorder(options.node_spacing_m, options.node_angle_deg)
    checkpoints = Checkpoints(folder, sequence, len(indices), method=f"{spec} (odometry)", on_saved=on_saved)
    phase = Phases(progress)
    kept: Path | None = folder
    try:
        with phase(f"{spec} on {sequence.name}", len(indices)) as advance:

            def on_frame(index: int, pose: Transform, points: Points) -> None:
                checkpoints(index, pose)
                recorder(index, pose, points)
                advance(index, pose)
                if hook is not None:
                    hook(index, pose, points, getattr(odometry, "last_info", {}))

            run = run_odometry(sequence, odometry, indices, on_frame=on_frame)
        phase.seconds["odometry"] = run.wall_seconds
        if run.interrupted or not run.frame_indices:
            checkpoints.save(
                f"{run.interruption or 'interrupted'} during the odometry after {checkpoints.frames_done} of "
                f"{len(indices)} frames: no loop closure"
            )
            if not run.frame_indices:
                remove_result_folder(folder)
                kept = None
            return MapOutcome(kept, sequence, run, run.poses, [], None, None, phase.seconds)
        nodes = recorder.finish()
        closed = pipeline.close_loops(options, network, nodes, run.poses, phase)
        decisions, poses, up = closed.decisions, closed.poses, closed.ground_up
        voxel_map = _map_from_nodes(sequence, nodes, poses, options, phase)
    except BaseException as error:
        checkpoints.save(f"{interruption_reason(error)} (after {checkpoints.frames_done} odometry frames)")
        if not holds_trajectory(folder):
            remove_result_folder(folder)
            note_kept(error, "no result folder was kept")
        else:  # stopped in the loop phase or the map: the odometry is there, and where must be said
            note_kept(
                error,
                f"the odometry's {checkpoints.frames_done} frames are kept in {folder} "
                "(result.json: partial; no loop closure)",
            )
        raise
    gt = ground_truth_for(sequence, run.frame_indices)
    report = evaluate(poses, gt) if gt is not None and len(poses) >= 2 else None
    odometry_report = evaluate(run.poses, gt) if gt is not None and len(poses) >= 2 else None
    outcome = MapOutcome(folder, sequence, run, poses, decisions, report, odometry_report, phase.seconds)
    memory = {
        "frames": len(run.frame_indices),
        "nodes": len(nodes),
        "node_bytes": recorder.nbytes,
        "map_points": len(voxel_map),
        "peak_rss_bytes": _peak_rss_bytes(),
    }

    def write_metrics(unit: Path) -> None:
        write_json(
            unit / "metrics.json",
            {
                "run": run_summary(run),
                "loops": _loop_summary(decisions)
                | {
                    "ground_up": up,
                    "odometry_covariance_scale": round(closed.odometry_scale, 4),
                    "node_voxel_m": recorder.cloud_voxel,
                },
                "seconds": phase.seconds,
                "memory": memory,
                **(report.to_dict() if report is not None else {"ground_truth": None}),
                "odometry": odometry_report.to_dict() if odometry_report is not None else None,
            },
        )

    def write_plot(unit: Path) -> None:
        accepted = [d for d in decisions if d.accepted]
        plot_trajectories(
            unit / "trajectory.png",
            {f"map ({len(accepted)} loops)": poses, "odometry": run.poses},
            gt,
            title=f"{sequence.name}: {spec} + loop closure",
            background_xy=voxel_map.top_down() if len(voxel_map) else None,
            links=[
                (poses[nodes[d.candidate.source].position], poses[nodes[d.candidate.target].position])
                for d in accepted
            ],
        )

    writers: dict[str, Callable[[Path], Any]] = {  # the small files first: a full disk takes the map
        "odometry_kitti.txt, odometry_tum.txt": lambda unit: _write_odometry(unit, run, sequence),
        "loops.json": lambda unit: write_json(unit / "loops.json", loops_json(decisions, nodes)),
        "metrics.json": write_metrics,
        "map.ply": lambda unit: voxel_map.save(unit / "map.ply"),
        "trajectory.png": write_plot,
    }
    failed: dict[str, str] = {}

    def extras(unit: Path) -> str | None:
        """Each file on its own: one that cannot be written (a full disk) is named, the rest kept."""
        for names, write in writers.items():
            try:
                write(unit)
            except (OSError, DataError) as error:
                cause = error if isinstance(error, OSError) else error.__cause__
                failed[names] = (
                    describe_os_error(cause)
                    if isinstance(cause, OSError)
                    else str(error).replace(str(unit), str(folder))
                )
                for name in names.split(", "):
                    (unit / name).unlink(missing_ok=True)
        return f"not written: {'; '.join(f'{n} ({r})' for n, r in failed.items())}" if failed else None

    try:
        save_trajectory(folder, outcome.mapped_run, sequence, frames_selected=len(indices), extras=extras)
    except BaseException as error:  # the trajectory itself could not be written, or an interrupt
        save_trajectory(
            folder,
            outcome.mapped_run,
            sequence,
            frames_selected=len(indices),
            status="partial",
            reason=f"{interruption_reason(error)} while writing the map, loops and scores",
        )
        note_kept(error, f"the optimised trajectory is kept in {folder} (result.json: partial)")
        raise
    if on_saved is not None:
        on_saved()
    if failed:
        kept = [n for n in writers if n not in failed]
        first = next(iter(failed.values()))
        raise DataError(
            f"{folder}: {', '.join(failed)} not written ({first}); kept: trajectory_kitti.txt, "
            f"trajectory_tum.txt, {', '.join(kept) or 'nothing else'} (result.json: partial)"
        )
    return outcome


def _map_from_nodes(
    sequence: LidarSequence, nodes: list[Node], poses: np.ndarray, settings: LoopSettings, phase: Phases
) -> VoxelMap:
    """The map from node scans at their optimised poses, one every ``map_scan_spacing_m`` of path
    (read again, in order: a recording streams). A place stays in a 60 m scan for many of them."""
    started = time.perf_counter()
    voxel = settings.map_voxel_m
    voxel_map = VoxelMap(voxel_size=voxel)
    last_path = -np.inf
    with phase("map", len(nodes)) as advance:
        for node in nodes:
            if node is nodes[-1] or node.path_m - last_path >= settings.map_scan_spacing_m:
                voxel_map.add(_thinned(sequence.frame(node.frame_index), voxel / 2), poses[node.position])
                last_path = node.path_m
            advance(node.frame_index, poses[node.position])
    phase.seconds["map"] = time.perf_counter() - started
    return voxel_map


def _thinned(points: Points, voxel: float) -> Points:
    """``points`` (with reflectance) on a grid of half the map's voxel first: open3d's legacy voxel
    filter is ~5x faster than the tensor one the map bins with (anchored at the origin), and the map's
    own binning then sees ~10x fewer points."""
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points[:, :3], dtype=np.float64)))
    reflectance = points[:, 3] if points.shape[1] > 3 else np.zeros(len(points))
    cloud.colors = o3d.utility.Vector3dVector(np.repeat(np.asarray(reflectance, np.float64)[:, None], 3, 1))
    down = cloud.voxel_down_sample(voxel)
    return np.column_stack([np.asarray(down.points), np.asarray(down.colors)[:, 0]]).astype(np.float32)


def _write_odometry(unit: Path, run: OdometryRun, sequence: LidarSequence) -> None:
    """``odometry_kitti.txt`` / ``odometry_tum.txt``: the odometry's poses, in the frame and format of
    the trajectory files beside them."""
    tr = sequence.tr_velo_to_cam
    poses = run.poses if tr is None else lidar_to_camera_poses(run.poses, tr)
    write_kitti_poses(unit / "odometry_kitti.txt", poses)
    write_tum_trajectory(unit / "odometry_tum.txt", poses, run.timestamps)


def _loop_summary(decisions: list[LoopDecision]) -> dict[str, Any]:
    outcomes = Counter(decision.check or "accepted" for decision in decisions)
    return {
        "candidates": len(decisions),
        "accepted": sum(d.accepted for d in decisions),
        "network_input_kept_ground": sum(
            bool(d.scores and d.scores.network_input_kept_ground) for d in decisions
        ),
        "by_outcome": {name: outcomes[name] for name in ("accepted", *CHECKS) if outcomes[name]},
    }


def _peak_rss_bytes() -> int:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)
