"""``run|map --visualize``: the odometry drawn as it goes, from its per-frame hook.

Each frame: the current scan (world frame), a local map of the recent scans on a voxel grid, the
trajectory so far, and markers where the network was asked (``consult="on-doubt"``: the frames whose
``global`` reason is not ``not needed``) or a motion was flagged. With a display the window redraws
every few frames (a frame's drawing must not cost more than its registration) and stays open at the
end; off-screen, the end of the run is written as ``--screenshot``.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.odometry.chain import network_asked
from vcr_odom.viewer.result import (
    ESTIMATE,
    FLAGGED,
    GROUND_TRUTH,
    LOOP,
    NETWORK,
    Color,
    Loop,
    ResultData,
    height_colours,
    loop_arcs,
    scale_of,
)
from vcr_odom.viewer.scene import Scene, check_screenshot_path, follow_camera, overview_camera

SCAN: Color = (0.55, 0.75, 1.00)
MAX_SCAN_POINTS = 40_000
LOCAL_MAP_VOXEL_M = 0.5
LOCAL_MAP_RADIUS_M = 80.0
REDRAW_SECONDS = 0.1
FOLLOW_DISTANCE_M = 60.0
FRAME_SCAN_M = 30.0


class LiveView:
    """The per-frame hook of ``--visualize``: ``view(index, pose, points, info)``.

    ``screenshot``: draw off-screen and write the last frame's picture there at :meth:`finish`;
    without it a window opens (a display is needed: checked here, before the run starts).
    """

    def __init__(
        self,
        screenshot: Path | None = None,
        *,
        width: int = 1280,
        height: int = 720,
        trajectory: tuple[str, Color] = ("trajectory", ESTIMATE),
    ) -> None:
        check_screenshot_path(screenshot)
        self.screenshot = screenshot
        self.trajectory = trajectory
        self._paths: list[tuple[str, NDArray[np.float64], Color]] = []
        self._map: ResultData | None = None
        self._loops: list[Loop] = []
        self.scene = Scene(headless=screenshot is not None, width=width, height=height)
        self.width, self.height = width, height
        self.frames: list[int] = []
        self.positions: list[NDArray[np.float64]] = []
        self.asked: list[int] = []
        self.flagged: list[int] = []
        self.scan = np.empty((0, 3))
        self.pose = np.eye(4)
        self._map_keys = np.empty((0, 3), dtype=np.int64)
        self._map_points = np.empty((0, 3))
        self._drawn_at = 0.0
        self.follow = True
        if not self.scene.headless:
            self.scene.ps.set_user_callback(self._controls)

    def __call__(
        self, index: int, pose: NDArray[np.float64], points: NDArray[Any], info: Mapping[str, Any]
    ) -> None:
        """One frame as the odometry placed it (LiDAR frame, world = the first frame)."""
        pose = np.asarray(pose, dtype=np.float64)
        xyz = np.asarray(points, dtype=np.float64)[:, :3]
        if len(xyz) > MAX_SCAN_POINTS:
            xyz = xyz[:: int(np.ceil(len(xyz) / MAX_SCAN_POINTS))]
        self.pose = pose
        self.scan = xyz @ pose[:3, :3].T + pose[:3, 3]
        self.frames.append(int(index))
        self.positions.append(pose[:3, 3].copy())
        if network_asked(info):
            self.asked.append(int(index))
        if info.get("flagged"):
            self.flagged.append(int(index))
        self._add_to_local_map(self.scan, pose[:3, 3])
        if not self.scene.headless and time.monotonic() - self._drawn_at >= REDRAW_SECONDS:
            self.draw()
            if self.follow:
                self.scene.look(follow_camera(self.pose, self.width, self.height, FOLLOW_DISTANCE_M))
            self.scene.tick()
            self._drawn_at = time.monotonic()

    def _add_to_local_map(self, world: NDArray[np.float64], centre: NDArray[np.float64]) -> None:
        """One point per voxel (the first seen), within ``LOCAL_MAP_RADIUS_M`` of the sensor."""
        keys = np.floor(world / LOCAL_MAP_VOXEL_M).astype(np.int64)
        keys = np.concatenate([self._map_keys, keys])
        points = np.concatenate([self._map_points, world])
        keys, first = np.unique(keys, axis=0, return_index=True)
        points = points[first]
        near = np.linalg.norm(points[:, :2] - centre[:2], axis=1) <= LOCAL_MAP_RADIUS_M
        self._map_keys, self._map_points = keys[near], points[near]

    def mark(self, frame_indices: Sequence[int], per_frame_info: Sequence[Mapping[str, Any]]) -> None:
        """The markers from the finished run's records (exact, where the live ones came a batch at a
        time on a GPU and saw the batch's last frame's)."""
        self.asked = [i for i, info in zip(frame_indices, per_frame_info, strict=True) if network_asked(info)]
        self.flagged = [
            i for i, info in zip(frame_indices, per_frame_info, strict=True) if info.get("flagged")
        ]

    def draw(self, size: float = FOLLOW_DISTANCE_M) -> list[tuple[str, Color]]:
        """Put the state into the scene, lines and points sized for a view ``size`` metres across;
        returns the legend of what is drawn."""
        scene = self.scene
        path = np.array(self.positions) if self.positions else np.empty((0, 3))
        line, marker, dot = max(0.0025 * size, 0.03), max(0.008 * size, 0.1), max(0.001 * size, 0.03)
        legend: list[tuple[str, Color]] = []
        scene.points("local map", self._map_points, height_colours(self._map_points), dot)
        scene.points("scan", self.scan, SCAN, 1.2 * dot)
        legend += [("scan", SCAN), ("local map", (0.6, 0.6, 0.6))]
        scene.path(self.trajectory[0], path, self.trajectory[1], line)
        legend.append(self.trajectory)
        where = {frame: k for k, frame in enumerate(self.frames)}
        for name, frames, colour in (
            ("network asked", self.asked, NETWORK),
            ("flagged", self.flagged, FLAGGED),
        ):
            label = f"{name} ({len(frames)})"
            for drawn in [n for n in scene.names() if n.startswith(f"{name} (")]:
                scene.remove(drawn)  # its label counts the frames, so it changes name
            if frames:
                scene.points(label, path[[where[f] for f in frames if f in where]], colour, marker)
                legend.append((label, colour))
        return legend

    def show_ground_truth(self, poses: NDArray[np.float64]) -> None:
        """The ground truth of the frames run, drawn at :meth:`finish`."""
        self._paths.append(("ground truth", poses[:, :3, 3], GROUND_TRUTH))

    def show_map(self, data: ResultData) -> None:
        """After ``map``'s loop phase: its optimised trajectory and accepted loops, drawn at :meth:`finish`."""
        self._paths.append(("map (optimised)", data.poses[:, :3, 3], ESTIMATE))
        self._loops = [loop for loop in data.loops if loop.accepted]
        self._map = data

    def framed(self) -> NDArray[np.float64]:
        """What the end's overview shows: every trajectory, and the scan within ``FRAME_SCAN_M`` of the
        sensor (a short drive is then seen in its street, a long one whole)."""
        parts = [np.array(self.positions).reshape(-1, 3), *(points for _, points, _ in self._paths)]
        near = self.scan[np.linalg.norm(self.scan[:, :2] - self.pose[:2, 3], axis=1) <= FRAME_SCAN_M]
        parts.append(near[:: max(len(near) // 500, 1)])
        framed = np.concatenate(parts)
        return framed if len(framed) else np.zeros((1, 3))

    def finish(self) -> Path | None:
        """The end of the run: the whole trajectory framed; its picture written off-screen, or the
        window left to the user until closed. Returns the picture's path, if one was written."""
        framed = self.framed()
        size = scale_of(framed)
        legend = self.draw(size)
        line = max(0.0025 * size, 0.03)
        for name, points, colour in self._paths:
            self.scene.path(name, points, colour, line)
            legend.append((name, colour))
        if self._map is not None and self._loops:
            name = f"loops accepted ({len(self._loops)})"
            self.scene.polylines(name, loop_arcs(self._map, self._loops, size), LOOP, 1.5 * line)
            legend.append((name, LOOP))
        self.scene.look(overview_camera(framed, self.width, self.height))
        if self.screenshot is not None:
            return self.scene.screenshot(self.screenshot, legend)
        self.scene.show()
        return None

    def _controls(self) -> None:
        """The window's own panel: follow the sensor, or leave the camera to the mouse."""
        imgui = self.scene.ps.imgui
        _, self.follow = imgui.Checkbox("follow the sensor", self.follow)
