"""A finished result folder (``run`` or ``map``) read for the 3-D view, and drawn.

Everything is put in the LiDAR frame of the run's first frame, the frame ``map.ply`` is written in:
the trajectory files are camera-frame where the run knew a calibration (``frames.json`` says), so
they are converted with the ``Tr`` the run read. The ground truth is not in the folder: it comes from
``--gt`` or from the data the run read (its ``config.json``), re-anchored at the first frame as the
scores are, and is left out with a note where neither is available.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.scans import read_tr
from vcr_odom.errors import DataError, VcrOdomError
from vcr_odom.evaluation.files import FRAMES_FILE, read_frames_file
from vcr_odom.geometry import camera_to_lidar_poses, normalise_to_first
from vcr_odom.io import read_kitti_poses
from vcr_odom.results import recorded_calibration, recorded_config
from vcr_odom.viewer.scene import Color, Scene, overview_camera

ESTIMATE: Color = (0.85, 0.13, 0.10)
GROUND_TRUTH: Color = (0.10, 0.60, 0.15)
ODOMETRY: Color = (0.10, 0.25, 0.65)
LOOP: Color = (0.60, 0.15, 0.75)
FLAGGED: Color = (1.00, 0.65, 0.00)
NETWORK: Color = (0.00, 0.75, 0.80)
REJECTED: dict[str, Color] = {
    "points": (0.55, 0.35, 0.20),
    "overlap": (0.95, 0.45, 0.60),
    "fit_rmse": (0.50, 0.50, 0.00),
    "odometry": (0.90, 0.30, 0.90),
    "degenerate": (0.30, 0.80, 0.95),
    "ambiguous": (0.85, 0.75, 0.10),
    "inconsistent": (0.15, 0.15, 0.15),
}
"""A colour per ``failed_check`` of ``loops.json`` (the reasons docs/usage.md lists)."""
OTHER_REJECTED: Color = (0.60, 0.60, 0.60)
MAX_MAP_POINTS = 1_500_000
"""Above this the map is thinned for drawing (an off-screen software renderer draws a few million)."""


@dataclass
class Loop:
    """A loop candidate between two frames of the trajectory, as ``loops.json`` records it."""

    source_frame: int
    target_frame: int
    accepted: bool
    check: str
    reason: str


@dataclass
class ResultData:
    """What ``view`` draws: LiDAR-frame poses (N x 4 x 4) of ``frame_indices``, the first = identity."""

    folder: Path
    frame_indices: list[int]
    poses: NDArray[np.float64]
    ground_truth: NDArray[np.float64] | None = None
    odometry: NDArray[np.float64] | None = None
    map_points: NDArray[np.float64] | None = None
    map_file: Path | None = None
    loops: list[Loop] = field(default_factory=list)
    flagged_frames: list[int] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def position_of(self, frame: int) -> NDArray[np.float64]:
        """The estimated position of ``frame`` (a frame index of the data, as loops.json names them)."""
        return self.poses[self.frame_indices.index(frame), :3, 3]


def read_result(
    folder: Path,
    *,
    gt: Path | None = None,
    calib: Path | None = None,
    with_map: bool = True,
    with_ground_truth: bool = True,
) -> ResultData:
    """Read ``folder`` as ``run`` or ``map`` wrote it; errors name the file and what was expected."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: not a folder; expected a result folder written by vcr-odom run or map")
    estimate = folder / "trajectory_kitti.txt"
    if not estimate.is_file():
        rows = sorted(p.parent.name for p in folder.glob("*/trajectory_kitti.txt"))
        raise DataError(
            f"{folder} holds no trajectory_kitti.txt; "
            + (
                f"it is a comparison: view one of its rows ({', '.join(rows)})"
                if rows
                else "expected a result folder written by vcr-odom run or map"
            )
        )
    raw = read_kitti_poses(estimate)
    recorded = read_frames_file(folder / FRAMES_FILE, sys.maxsize)
    indices = recorded.indices if recorded is not None else list(range(len(raw)))
    if len(indices) != len(raw):
        raise DataError(
            f"{folder / FRAMES_FILE} lists {len(indices)} frames but {estimate} holds {len(raw)} poses"
        )
    config = recorded_config(folder)
    notes: list[str] = []
    tr = _calibration(folder, calib, recorded is not None and recorded.poses_frame == "camera")

    def lidar(poses: NDArray[np.float64]) -> NDArray[np.float64]:
        return normalise_to_first(poses if tr is None else camera_to_lidar_poses(poses, tr))

    data = ResultData(folder, indices, lidar(raw), notes=notes)
    odometry_file = folder / "odometry_kitti.txt"
    if odometry_file.is_file():
        data.odometry = lidar(read_kitti_poses(odometry_file))
    if with_ground_truth:
        data.ground_truth = _ground_truth(gt, config, indices, tr, notes)
    data.loops = _loops(folder / "loops.json", set(indices))
    data.flagged_frames = _flagged(folder / "metrics.json", set(indices))
    if with_map:
        data.map_file = _map_file(folder, config)
        if data.map_file is not None:
            data.map_points = _read_map(data.map_file)
    return data


def _calibration(folder: Path, calib: Path | None, camera_frame: bool) -> NDArray[np.float64] | None:
    """``Tr`` for camera-frame trajectory files: ``--calib``, else the calib.txt the run read."""
    if not camera_frame:
        return None
    path = calib or recorded_calibration(folder)
    if path is None:
        raise DataError(
            f"{folder / FRAMES_FILE} says the trajectory is camera-frame and the calib.txt its run read "
            "is gone: give --calib FILE (KITTI calib.txt with a Tr line)"
        )
    return read_tr(path, required=True)


def _ground_truth(
    gt: Path | None,
    config: dict[str, Any],
    indices: list[int],
    tr: NDArray[np.float64] | None,
    notes: list[str],
) -> NDArray[np.float64] | None:
    """``--gt`` (KITTI format, every frame of the data), else the data's own, for ``indices``."""
    if gt is not None:
        poses = read_kitti_poses(gt)
        if max(indices) >= len(poses):
            raise DataError(
                f"--gt {gt} holds {len(poses)} poses but the result names frame {max(indices)}; "
                "expected the ground truth of every frame of the data the run read"
            )
        poses = poses[indices]
        return normalise_to_first(poses if tr is None else camera_to_lidar_poses(poses, tr))
    selection = config.get("selection")
    if not isinstance(selection, dict):
        notes.append("no ground truth drawn: config.json does not say which data the run read (give --gt)")
        return None
    from vcr_odom.data.selection import FrameSelection  # opening data imports its readers

    try:
        sequence = FrameSelection(**selection).open()
        truth = sequence.gt_poses
    except (VcrOdomError, OSError, ValueError) as error:
        notes.append(f"no ground truth drawn: the data the run read does not open ({error}); give --gt")
        return None
    if truth is None:
        notes.append("no ground truth drawn: the data the run read has none")
        return None
    if max(indices) >= len(truth):
        notes.append(
            f"no ground truth drawn: it has {len(truth)} poses, the result names frame {max(indices)}"
        )
        return None
    return normalise_to_first(truth[indices])


def _loops(path: Path, frames: set[int]) -> list[Loop]:
    """Every candidate of ``loops.json`` whose two frames are in the trajectory."""
    if not path.is_file():
        return []
    try:
        candidates = json.loads(path.read_text(encoding="utf-8"))["candidates"]
        loops = [
            Loop(
                int(c["source_frame"]),
                int(c["target_frame"]),
                bool(c["accepted"]),
                str(c.get("failed_check") or ""),
                str(c.get("reason") or ""),
            )
            for c in candidates
        ]
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise DataError(
            f"{path}: expected {{'candidates': [{{'source_frame', 'target_frame', 'accepted', ...}}]}} "
            f"as vcr-odom map writes it ({type(error).__name__}: {error})"
        ) from error
    return [loop for loop in loops if loop.source_frame in frames and loop.target_frame in frames]


def _flagged(path: Path, frames: set[int]) -> list[int]:
    """``metrics.json``'s flagged frames (the odometry's, for a map)."""
    try:
        flagged = json.loads(path.read_text(encoding="utf-8"))["run"]["flagged_frames"]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    return [int(f) for f in flagged if isinstance(f, int) and f in frames]


def _map_file(folder: Path, config: dict[str, Any]) -> Path | None:
    """``map.ply`` in the folder (map), else the file ``run --save-map`` wrote, where it still is."""
    own = folder / "map.ply"
    if own.is_file():
        return own
    saved = config.get("save_map")
    return Path(saved) if saved and Path(saved).is_file() else None


def _read_map(path: Path) -> NDArray[np.float64]:
    import open3d as o3d

    cloud = o3d.io.read_point_cloud(str(path))
    if len(cloud.points) == 0:
        raise DataError(f"{path}: no points read; expected a .ply or .pcd map as vcr-odom writes it")
    if len(cloud.points) > MAX_MAP_POINTS:
        step = int(np.ceil(len(cloud.points) / MAX_MAP_POINTS))
        cloud = cloud.uniform_down_sample(step)
    return np.asarray(cloud.points, dtype=np.float64)


# -- drawing ----------------------------------------------------------------------------------------


def height_colours(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Light to dark grey with height (2nd to 98th percentile): the lines drawn over it keep their colours."""
    z = points[:, 2]
    low, high = np.percentile(z, [2, 98]) if len(z) else (0.0, 1.0)
    shade = 0.88 - 0.45 * np.clip((z - low) / max(high - low, 1e-6), 0.0, 1.0)
    return np.repeat(shade[:, None], 3, axis=1)


def scale_of(points: NDArray[np.float64]) -> float:
    """The scene's size in metres (the diagonal of what is framed), for line widths that stay visible."""
    points = points.reshape(-1, 3)
    return max(float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))), 1.0) if len(points) else 1.0


def framed_points(data: ResultData) -> NDArray[np.float64]:
    """What the overview camera must see: the trajectories (the map may reach far beyond them)."""
    parts = [data.poses[:, :3, 3]]
    parts += [t[:, :3, 3] for t in (data.ground_truth, data.odometry) if t is not None]
    return np.concatenate(parts)


def draw_result(
    scene: Scene, data: ResultData, *, rejected: bool = False, width: int = 1280, height: int = 720
) -> list[tuple[str, Color]]:
    """Draw ``data`` and frame it; returns the legend (label, colour) of what was drawn."""
    framed = framed_points(data)
    size = scale_of(framed)
    line, marker = max(0.0025 * size, 0.03), max(0.006 * size, 0.08)
    legend: list[tuple[str, Color]] = []
    if data.map_points is not None:
        scene.points("map", data.map_points, height_colours(data.map_points), max(0.0008 * size, 0.02))
    if data.ground_truth is not None:
        scene.path("ground truth", data.ground_truth[:, :3, 3], GROUND_TRUTH, line)
        legend.append(("ground truth", GROUND_TRUTH))
    if data.odometry is not None:
        scene.path("odometry", data.odometry[:, :3, 3], ODOMETRY, line)
        legend.append(("odometry", ODOMETRY))
    label = "map (optimised)" if data.odometry is not None else "estimate"
    scene.path(label, data.poses[:, :3, 3], ESTIMATE, line)
    legend.append((label, ESTIMATE))
    accepted = [loop for loop in data.loops if loop.accepted]
    if accepted:
        _draw_loops(scene, data, accepted, f"loops accepted ({len(accepted)})", LOOP, 1.5 * line, size)
        legend.append((f"loops accepted ({len(accepted)})", LOOP))
    if rejected:
        by_check: dict[str, list[Loop]] = {}
        for loop in data.loops:
            if not loop.accepted:
                by_check.setdefault(loop.check or "other", []).append(loop)
        for check, loops in sorted(by_check.items()):
            name = f"rejected: {check} ({len(loops)})"
            colour = REJECTED.get(check, OTHER_REJECTED)
            _draw_loops(scene, data, loops, name, colour, 0.8 * line, size)
            legend.append((name, colour))
    if data.flagged_frames:
        flagged = np.array([data.position_of(f) for f in data.flagged_frames])
        scene.points(f"flagged frames ({len(flagged)})", flagged, FLAGGED, marker)
        legend.append((f"flagged frames ({len(flagged)})", FLAGGED))
    scene.look(overview_camera(framed, width, height))
    return legend


def loop_arc(
    start: NDArray[np.float64], end: NDArray[np.float64], lift_m: float, steps: int = 12
) -> NDArray[np.float64]:
    """A loop drawn from ``start`` to ``end`` as an arc raised by ``lift_m`` at its middle: the two
    visits of a place lie on top of each other, and a straight line between them would hide under
    the trajectories it joins."""
    t = np.linspace(0.0, 1.0, steps + 1)[:, None]
    return start + t * (end - start) + 4.0 * lift_m * t * (1.0 - t) * np.array([0.0, 0.0, 1.0])


def loop_lift(start: NDArray[np.float64], end: NDArray[np.float64], size_m: float) -> float:
    """How high a loop's arc rises: half its length, at least 3 % of the scene's size."""
    return max(0.5 * float(np.linalg.norm(end - start)), 0.03 * size_m)


def loop_arcs(data: ResultData, loops: list[Loop], size_m: float) -> list[NDArray[np.float64]]:
    """The arcs of ``loops`` between their frames' positions (:func:`loop_arc`)."""
    ends = [(data.position_of(loop.source_frame), data.position_of(loop.target_frame)) for loop in loops]
    return [loop_arc(a, b, loop_lift(a, b, size_m)) for a, b in ends]


def _draw_loops(
    scene: Scene, data: ResultData, loops: list[Loop], name: str, colour: Color, radius: float, size: float
) -> None:
    scene.polylines(name, loop_arcs(data, loops, size), colour, radius)
