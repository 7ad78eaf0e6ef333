"""``vcr-odom map``: odometry, then loop closure and a pose graph, into a result folder like ``run``'s.

Phases: the odometry (nodes recorded as it goes, checkpoints as in ``run``), candidates and their
verification, the pose graph, and the map from the nodes' scans at the optimised poses. The folder is
published as one unit at the end (``trajectory_*`` the optimised poses, ``odometry_*`` the odometry's,
``loops.json``, ``map.ply``, ``metrics.json``, the plot); a run stopped after the odometry keeps the
odometry's trajectory, marked partial with the reason.
"""

from __future__ import annotations

import copy
import dataclasses
import resource
import sys
import time
from collections import Counter
from collections.abc import Callable, Sequence
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
from pydantic import Field, model_validator

from vcr_odom.data.base import LidarSequence, Points
from vcr_odom.geometry import Transform, lidar_to_camera_poses
from vcr_odom.io import write_kitti_poses, write_tum_trajectory
from vcr_odom.loops.candidates import (
    ATTEMPT_SPACING_M,
    MAX_PASSAGE_ATTEMPTS,
    MIN_LOOP_PATH_M,
    REVISIT_RADIUS_M,
    find_candidates,
)
from vcr_odom.loops.drift import DriftModel
from vcr_odom.loops.graph import LoopEdge, correct_frames, factor_summary, optimise
from vcr_odom.loops.implied_starts import reject_loops_ambiguous_from_implied_starts
from vcr_odom.loops.nodes import NODE_SPACING_DEG, NODE_SPACING_M, Node, NodeNormals, NodeRecorder
from vcr_odom.loops.odometry_doubts import OdometryDoubts, fit_sigma_factors
from vcr_odom.loops.outranked import reject_weak_loops_corroborated_ones_contradict
from vcr_odom.loops.same_place import reject_disagreeing_submap_fits
from vcr_odom.loops.up_priors import ATTITUDE_SIGMA_DEG
from vcr_odom.loops.verify import CHECKS, LoopDecision, LoopVerifier
from vcr_odom.mapping import VoxelMap
from vcr_odom.metrics import EvaluationReport, evaluate
from vcr_odom.odometry.chain import Odometry
from vcr_odom.odometry.loop import OdometryRun, run_odometry
from vcr_odom.odometry.outputs import Checkpoints, ground_truth_for, run_summary, save_trajectory
from vcr_odom.odometry.run import ProgressFactory, RunSettings, method_for
from vcr_odom.plots import plot_trajectories
from vcr_odom.registration.base import SequentialOdometry
from vcr_odom.registration.vcr import VcrRegistrar, default_passes
from vcr_odom.results import (
    check_output_folder,
    create_result_folder,
    holds_trajectory,
    interruption_reason,
    point_latest_at,
    remove_result_folder,
    write_json,
)
from vcr_odom.settings import Settings

MAP_SCAN_SPACING_M = 6.0
"""Path between the scans map.ply is built from: every other node at the default spacing."""


class LoopOptions(Settings):
    """The loop closure's settings (``map``'s options beyond ``run``'s)."""

    node_spacing: float = Field(default=NODE_SPACING_M, gt=0, description="Metres between graph nodes.")
    node_angle: float = Field(default=NODE_SPACING_DEG, gt=0, description="A turn that makes a node (deg).")
    revisit_radius: float = Field(default=REVISIT_RADIUS_M, gt=0)
    min_loop_path: float = Field(default=MIN_LOOP_PATH_M, gt=0)
    attempt_spacing: float = Field(default=ATTEMPT_SPACING_M, ge=0)
    passage_attempts: int = Field(
        default=MAX_PASSAGE_ATTEMPTS,
        ge=1,
        description="At most about this many loop attempts along one revisit passage: a passage longer "
        "than this many times attempt_spacing is attempted every 1/passage_attempts of its length.",
    )
    max_drift: float = Field(
        default=DriftModel.translation_rate * 100,
        gt=0,
        le=50,
        description="How far the odometry may drift between two visits, in % of the path between them "
        f"(each frame counting as at least {DriftModel.path_per_frame_floor_m * 100:.0f} cm of it; plus "
        f"{DriftModel.translation_floor_m:g} m): a loop asking for more is rejected, and so is a "
        "look-alike place a block away.",
    )
    max_heading_drift: float = Field(
        default=DriftModel.rotation_deg_per_m * 100,
        gt=0,
        le=100,
        description="How far the odometry's heading may drift between two visits, in deg per 100 m of "
        f"path (plus {DriftModel.rotation_floor_deg:g} deg and {DriftModel.rotation_per_turned * 100:g} % "
        f"of the angle turned between them, at most {DriftModel.rotation_cap_deg:g} deg).",
    )
    loops: bool = Field(default=True, description="False: the odometry and its map only (a baseline).")
    ground_up: bool = Field(
        default=True,
        description="Hold each node's tilt to the up measured in its cloud (its walls', else its "
        "ground's) where the odometry's tilt drifted from it (False: loops alone).",
    )
    map_voxel: float = Field(default=0.5, ge=0.05)


class MapSettings(RunSettings, LoopOptions):
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


def loop_network(
    weights: Path | None,
    device: str,
    points: int | None,
    odometry: Odometry | SequentialOdometry | None = None,
) -> VcrRegistrar:
    """The network that registers loop candidates (loaded before any folder: a bad file fails first).

    Where the odometry already runs VCR-Net from the same options, its loaded network is shared (one
    copy of the weights in memory, one load) with the weights' own number of passes: the odometry's
    polished pairs run one, a loop with no guess takes what the weights default to."""
    registrar = getattr(odometry, "registrar", None)
    if isinstance(registrar, VcrRegistrar):
        shared = copy.copy(registrar)
        shared.passes = default_passes(shared.config)
        return shared
    return VcrRegistrar(weights=weights, device=device, num_points=points)


def map_sequence(settings: MapSettings, progress: ProgressFactory | None = None) -> MapOutcome:
    """Check everything, build the odometry and the loop network, and map into a new result folder."""
    check_output_folder(settings.results_dir, "--results-dir")
    sequence = settings.selection.open()
    indices = settings.selection.indices(sequence)
    odometry = method_for(settings)
    network = loop_network(settings.weights, settings.device, settings.vcr_points, odometry)
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
        LoopOptions(**{k: getattr(settings, k) for k in LoopOptions.model_fields}),
        progress=progress,
        on_saved=lambda: point_latest_at(settings.results_dir, folder),
    )


def map_and_save(
    sequence: LidarSequence,
    odometry: Odometry | SequentialOdometry,
    network: VcrRegistrar,
    indices: Sequence[int],
    folder: Path,
    options: LoopOptions,
    *,
    progress: ProgressFactory | None = None,
    on_saved: Callable[[], Any] | None = None,
) -> MapOutcome:
    """Run the odometry with a node recorder, close loops, optimise and publish ``folder``'s unit
    (see the module doc); ``folder`` is None in the outcome where nothing was kept."""
    spec = odometry.name
    recorder = NodeRecorder(options.node_spacing, options.node_angle)
    checkpoints = Checkpoints(folder, sequence, len(indices), method=f"{spec} (odometry)", on_saved=on_saved)
    phase = Phases(progress)
    kept: Path | None = folder
    try:
        with phase(f"{spec} on {sequence.name}", len(indices)) as advance:

            def on_frame(index: int, pose: Transform, points: Points) -> None:
                checkpoints(index, pose)
                recorder(index, pose, points)
                advance(index, pose)

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
        doubts = OdometryDoubts.of_run(run.frame_indices, run.per_frame_info)
        closed = close_loops(options, network, nodes, run.poses, phase, doubts)
        decisions, poses, up = closed.decisions, closed.poses, closed.ground_up
        voxel_map = _map_from_nodes(sequence, nodes, poses, options.map_voxel, phase)
    except BaseException as error:
        checkpoints.save(f"{interruption_reason(error)} (after {checkpoints.frames_done} odometry frames)")
        if not holds_trajectory(folder):
            remove_result_folder(folder)
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

    def extras(unit: Path) -> None:
        _write_odometry(unit, run, sequence)
        write_json(unit / "loops.json", loops_json(decisions, nodes))
        voxel_map.save(unit / "map.ply")
        write_json(
            unit / "metrics.json",
            {
                "run": run_summary(run),
                "loops": _loop_summary(decisions)
                | {
                    "ground_up": up,
                    "odometry_sigma_scale": closed.odometry_scale,
                    "odometry_heading_sigmas": closed.heading_support,
                    "odometry_fit_sigmas": closed.fit_doubts,
                    "node_voxel_m": recorder.cloud_voxel,
                },
                "seconds": phase.seconds,
                "memory": memory,
                **(report.to_dict() if report is not None else {"ground_truth": None}),
                "odometry": odometry_report.to_dict() if odometry_report is not None else None,
            },
        )
        accepted = _accepted(decisions)
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

    try:
        save_trajectory(folder, outcome.mapped_run, sequence, frames_selected=len(indices), extras=extras)
    except BaseException as error:  # e.g. a full disk writing map.ply: keep the optimised poses, say so
        save_trajectory(
            folder,
            outcome.mapped_run,
            sequence,
            frames_selected=len(indices),
            status="partial",
            reason=f"{interruption_reason(error)} while writing the map, loops and scores",
        )
        raise
    if on_saved is not None:
        on_saved()
    return outcome


class Phases:
    """One progress bar per phase (or none) and each phase's wall time."""

    def __init__(self, progress: ProgressFactory | None) -> None:
        self.progress = progress
        self.seconds: dict[str, float] = {}

    def __call__(self, title: str, total: int) -> Any:
        if self.progress is None:
            return nullcontext(lambda *_: None)
        return self.progress(title, total)


def _accepted(decisions: list[LoopDecision]) -> list[LoopDecision]:
    return [d for d in decisions if d.accepted]


@dataclass
class ClosedLoops:
    """What the loop phase made of an odometry: every candidate's decision (a loop the graph dropped
    is no longer accepted), every frame's optimised pose, and what the graph made of the ground's up."""

    decisions: list[LoopDecision]
    poses: np.ndarray
    ground_up: dict[str, Any]
    odometry_scale: dict[str, Any] | None = None
    """How the loops' cycles scaled the graph's odometry sigmas (None without loops)."""
    heading_support: dict[str, Any] | None = None
    """How far the graph raised its odometry edges' heading sigmas where the scans held the heading
    weakly (None without loops)."""
    fit_doubts: dict[str, Any] | None = None
    """How far the graph raised its odometry edges' sigmas where the odometry's frames fitted poorly
    (None without loops)."""


def close_loops(
    settings: LoopOptions,
    network: VcrRegistrar,
    nodes: list[Node],
    odometry_poses: np.ndarray,
    phase: Phases | None = None,
    doubts: OdometryDoubts | None = None,
) -> ClosedLoops:
    """Candidates, verification and the graph on nodes recorded along ``odometry_poses`` (every frame's,
    as the :class:`NodeRecorder` saw them): ``map``'s loop phase, and a benchmark's on a recorded or
    drifted odometry. ``doubts``: what the odometry said of its frames (:mod:`~vcr_odom.loops.odometry_doubts`;
    none for a benchmark's drift)."""
    phase = phase or Phases(None)
    doubts = doubts or OdometryDoubts()
    drift = DriftModel(
        translation_rate=settings.max_drift / 100, rotation_deg_per_m=settings.max_heading_drift / 100
    )
    started = time.perf_counter()
    decisions: list[LoopDecision] = []
    normals = NodeNormals(nodes)  # the verification's and the graph's, estimated once per node
    if settings.loops:
        candidates = find_candidates(
            nodes,
            drift,
            settings.revisit_radius,
            settings.min_loop_path,
            settings.attempt_spacing,
            settings.passage_attempts,
        )
        verifier = LoopVerifier(network, drift, doubts.flagged_frames, normals)
        with phase("loop candidates", len(candidates)) as advance:
            for candidate in candidates:
                decisions.append(verifier.verify(candidate, nodes))
                advance(candidate.source, candidate.prior)
        reject_disagreeing_submap_fits(decisions, nodes)
        reject_loops_ambiguous_from_implied_starts(decisions, nodes, normals)
        reject_weak_loops_corroborated_ones_contradict(decisions, nodes)
    phase.seconds["loops"] = time.perf_counter() - started
    started = time.perf_counter()
    edges = [
        LoopEdge(
            d.candidate.source, d.candidate.target, d.measured, d.information, corroborated=d.corroborated
        )
        for d in _accepted(decisions)
    ]
    attitude_deg = ATTITUDE_SIGMA_DEG if settings.ground_up else 0.0
    fit_factors = fit_sigma_factors(nodes, doubts.fits) if edges else None  # no loop: no graph to weigh
    graph = optimise(nodes, edges, drift, attitude_deg, fit_factors, normals)
    for k, (decision, kept, weight) in enumerate(
        zip(_accepted(decisions), graph.kept, graph.weights, strict=True)
    ):
        decision.scores["graph_weight"] = round(weight, 4)
        if not kept:
            decision.reject("graph", dropped_reason(graph.cycle_outliers.get(k), weight, len(edges)))
    before = np.stack([node.pose for node in nodes])
    if any(graph.kept):
        poses = correct_frames(odometry_poses, [n.position for n in nodes], before, graph.node_poses)
    else:
        poses = np.array(odometry_poses, copy=True)
    phase.seconds["graph"] = time.perf_counter() - started
    up = {"used": False} if graph.up is None else graph.up.to_dict() | {"dropped": graph.up_dropped}
    scale = None
    if graph.odometry is not None:
        scale = graph.odometry.to_dict() | {
            "trusted_loops": graph.trusted,
            "final_loop_share": graph.loop_share,
        }
    heading = None if graph.heading_factors is None else factor_summary(graph.heading_factors)
    fits = None if graph.fit_factors is None else factor_summary(graph.fit_factors)
    return ClosedLoops(decisions, poses, up, scale, heading, fits)


def dropped_reason(cycle_outlier: tuple[int, int] | None, weight: float, loops: int) -> str:
    """Why the graph dropped a loop (``loops.json``): its cycles with the loops near it, or its weight
    after the robust rounds, against the odometry's sigmas and the ``loops - 1`` other loops (a lone
    loop can only disagree with the odometry)."""
    if cycle_outlier is not None:
        misclosed, cycles = cycle_outlier
        if cycles == 2:  # two loops that agree outvote it (:func:`~vcr_odom.loops.cycles.cycle_outliers`)
            return "dropped: its cycles with the two loops near it do not close, while theirs does"
        return f"dropped: {misclosed} of its {cycles} cycles with the loops near it do not close"
    others = loops - 1
    against = "the odometry" if others == 0 else f"the odometry and the {others} other loop(s)"
    return f"dropped: disagrees with {against} (graph weight {weight:.2f})"


def _map_from_nodes(
    sequence: LidarSequence, nodes: list[Node], poses: np.ndarray, voxel: float, phase: Phases
) -> VoxelMap:
    """The map from node scans at their optimised poses, one every :data:`MAP_SCAN_SPACING_M` of path
    (read again, in order: a recording streams). A place stays in a 60 m scan for many of them."""
    started = time.perf_counter()
    voxel_map = VoxelMap(voxel_size=voxel)
    last_path = -np.inf
    with phase("map", len(nodes)) as advance:
        for node in nodes:
            if node is nodes[-1] or node.path_m - last_path >= MAP_SCAN_SPACING_M:
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


def loops_json(decisions: list[LoopDecision], nodes: list[Node]) -> dict[str, Any]:
    """``loops.json``: every node (frame, path) and every candidate's decision."""
    return {
        "nodes": [
            {"node": k, "frame": n.frame_index, "path_m": round(n.path_m, 3)} for k, n in enumerate(nodes)
        ],
        "candidates": [d.to_dict() for d in decisions],
    }


def _loop_summary(decisions: list[LoopDecision]) -> dict[str, Any]:
    outcomes = Counter(decision.check or "accepted" for decision in decisions)
    return {
        "candidates": len(decisions),
        "accepted": sum(d.accepted for d in decisions),
        "beyond_drift_bound": beyond_drift_bound(decisions),
        "network_input_kept_ground": sum(bool(d.scores.get("network_input_kept_ground")) for d in decisions),
        "by_outcome": {name: outcomes[name] for name in ("accepted", *CHECKS) if outcomes[name]},
    }


def beyond_drift_bound(decisions: list[LoopDecision]) -> int:
    """Candidates that fit (overlap and RMSE passed) but asked the odometry for more than its drift
    bound: look-alike places, or an odometry that drifts more than the bound's options allow."""
    return sum(d.check == "drift_bound" for d in decisions)


def _peak_rss_bytes() -> int:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak if sys.platform == "darwin" else peak * 1024)
