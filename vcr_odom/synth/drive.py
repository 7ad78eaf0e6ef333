"""The car's drive along the road: cruising speeds that slow for curves, optional standing start and
stops, and the LiDAR pose at each frame (the car on its four wheels, with a little body motion).

Every random draw has its own generator seeded from the sequence seed, so the drive never depends on
how the scene or the scans were generated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vcr_odom.errors import ConfigError
from vcr_odom.geometry import rotation_from_euler_zyx
from vcr_odom.synth.road import PREROLL, ROAD_STEP, Road
from vcr_odom.synth.scene import StreetScene

START_DWELL = (1.0, 3.0)
STOP_DWELL = (2.0, 8.0)
STOP_SPACING = (60.0, 300.0)
"""With stops: seconds standing before pulling away, seconds per stop, metres between stops."""
WHEELBASE, TRACK = 2.7, 1.6
"""Where the car's wheels touch the road (m): a VW Passat like KITTI's recording car."""


@dataclass(frozen=True)
class Drive:
    """Where the car is at each frame: stations along the road and LiDAR -> world poses."""

    stations: NDArray[np.float64]
    speeds: NDArray[np.float64]
    world_poses: NDArray[np.float64]

    @property
    def length(self) -> float:
        """Distance driven (m), summed over the sensor's frame-to-frame steps."""
        return float(np.linalg.norm(np.diff(self.world_poses[:, :3, 3], axis=0), axis=1).sum())


def make_drive(
    scene: StreetScene,
    *,
    frames: int,
    speed: float,
    height: float,
    seed: int,
    stops: bool,
    frame_period: float,
) -> Drive:
    """The car follows the scene's path (the road, on the open street) at the speed profile (with
    ``stops``: from a standing start, stopping now and then); yaw follows the path, pitch and roll the
    ground under it, plus a little body pitch/roll from braking and cornering. The sensor sits
    ``height`` metres above the ground."""
    path = scene.path.line
    s, v = _stations_and_speeds(path.curvature, frames, speed, seed, stops, frame_period)
    stations = np.arange(len(path.xy)) * ROAD_STEP
    speed_at = np.interp(s, stations, v)
    accel = np.interp(s, stations, np.gradient(v, ROAD_STEP) * v)
    xy, heading, curvature = path.sample(s)
    poses = _vehicle_poses(scene, xy, heading, accel, speed_at**2 * curvature, height)
    return Drive(s, speed_at, poses)


def drive_travel(
    path: Road, *, frames: int, speed: float, seed: int, stops: bool, frame_period: float
) -> float:
    """How far (m) along ``path`` the car of :func:`make_drive` gets from its first frame to its last
    (what a route is sized by). Past the path's end it drives on as if the path ran straight on."""
    reach = PREROLL + frames * frame_period * speed * 1.5 + 10.0
    extra = max(0, math.ceil(reach / ROAD_STEP) + 1 - len(path.xy))
    curvature = np.concatenate([path.curvature, np.zeros(extra)])
    s, _ = _stations_and_speeds(curvature, frames, speed, seed, stops, frame_period)
    return float(s[-1] - s[0])


def _stations_and_speeds(
    curvature: NDArray[np.float64], frames: int, speed: float, seed: int, stops: bool, frame_period: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Path station at each frame, and the speed profile at every path sample (of ``curvature``)."""
    stop_at, dwell = (
        _stops(len(curvature), np.random.default_rng([seed, 7]))
        if stops
        else (np.zeros(0, np.int64), np.zeros(0))
    )
    v = _speed_profile(curvature, speed, np.random.default_rng([seed, 4]), stop_at)
    return _frame_stations(v, np.arange(frames) * frame_period, stop_at, dwell), v


def _speed_profile(
    path_curvature: NDArray[np.float64],
    speed: float,
    rng: np.random.Generator,
    stops: NDArray[np.int64] | None = None,
) -> NDArray[np.float64]:
    """Speed (m/s) at every road sample: random cruising speeds between 0.5x and 1.5x ``speed``,
    slowed for curves (lateral acceleration <= 2 m/s^2), zero at the ``stops`` samples, and limited to
    gentle acceleration/braking (so the car brakes into each stop and pulls away from it)."""
    n = len(path_curvature)
    stations = np.arange(n) * ROAD_STEP
    knots, targets = [0.0], [speed * rng.uniform(0.5, 1.5)]
    while knots[-1] < stations[-1]:  # drawn in order along the road: a longer road starts the same way
        knots.append(knots[-1] + rng.uniform(60.0, 250.0))
        targets.append(speed * rng.uniform(0.5, 1.5))
    v = np.interp(stations, knots, targets)
    v = np.minimum(v, np.sqrt(2.0 / np.maximum(np.abs(path_curvature), 1e-6)))
    if stops is not None:
        v[stops] = 0.0
    accelerate, brake = 1.2, 2.0
    for i in range(1, n):
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2.0 * accelerate * ROAD_STEP))
    for i in range(n - 2, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2.0 * brake * ROAD_STEP))
    return v


def _stops(n_samples: int, rng: np.random.Generator) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Road samples where the car stands and for how long (s): a standing start at the first frame,
    then a stop every 60-300 m (traffic lights, junctions, queues)."""
    index, dwell = [round(PREROLL / ROAD_STEP)], [rng.uniform(*START_DWELL)]
    while True:
        next_stop = index[-1] + int(rng.uniform(*STOP_SPACING) / ROAD_STEP)
        if next_stop >= n_samples - 1:
            return np.array(index, dtype=np.int64), np.array(dwell)
        index.append(next_stop)
        dwell.append(rng.uniform(*STOP_DWELL))


def _frame_stations(
    v: NDArray[np.float64],
    frame_times_from_start: NDArray[np.float64],
    stops: NDArray[np.int64],
    dwell: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Station at each frame time (seconds after the car passes :data:`PREROLL`).

    Constant acceleration between road samples gives the time to each sample; at a stop the car waits
    ``dwell`` seconds, so frames in that wait share one station exactly (zero motion between them).
    """
    stations = np.arange(len(v)) * ROAD_STEP
    time = np.concatenate([[0.0], np.cumsum(2.0 * ROAD_STEP / (v[1:] + v[:-1]))])
    if not len(stops):  # the original drive, kept bit for bit: linear in time between samples
        frame_times = np.interp(PREROLL, stations, time) + frame_times_from_start
        _check_road(frame_times, time)
        return np.interp(frame_times, time, stations)
    wait = np.zeros(len(v))
    wait[stops] = dwell
    time = time + np.cumsum(wait) - wait  # arrival at each sample
    knots_t = np.concatenate([time, time[stops] + dwell])  # each stop twice: arrival and departure
    order = np.argsort(knots_t, kind="stable")
    knots_t = knots_t[order]
    knots_s = np.concatenate([stations, stations[stops]])[order]
    knots_v = np.concatenate([v, v[stops]])[order]
    frame_times = np.interp(PREROLL, stations, time) + frame_times_from_start
    _check_road(frame_times, knots_t)
    # Exact constant-acceleration motion within each interval: near a stop the samples are seconds
    # apart, and linear interpolation there would jerk the speed from frame to frame.
    j = np.clip(np.searchsorted(knots_t, frame_times, side="right") - 1, 0, len(knots_t) - 2)
    tau = frame_times - knots_t[j]
    accel = (knots_v[j + 1] - knots_v[j]) / (knots_t[j + 1] - knots_t[j])
    return knots_s[j] + knots_v[j] * tau + 0.5 * accel * tau * tau


def _check_road(frame_times: NDArray[np.float64], knot_times: NDArray[np.float64]) -> None:
    if frame_times[-1] > knot_times[-1]:
        raise ConfigError("road too short for the drive")  # cannot happen: the road is sized for it


def _vehicle_poses(
    scene: StreetScene,
    xy: NDArray[np.float64],
    heading: NDArray[np.float64],
    a_long: NDArray[np.float64],
    a_lat: NDArray[np.float64],
    height: float,
) -> NDArray[np.float64]:
    """LiDAR -> world poses ``(N, 4, 4)``: the car stands on its four wheels (so it pitches and rolls
    with hills, camber and ripples), the sensor ``height`` above the ground at its centre, plus a
    little body motion on the suspension (the nose dips when braking, the body rolls out of a turn)."""
    forward = np.stack([np.cos(heading), np.sin(heading)], 1)
    left = np.stack([-np.sin(heading), np.cos(heading)], 1)
    corners = [(u, v) for u in (WHEELBASE / 2, -WHEELBASE / 2) for v in (TRACK / 2, -TRACK / 2)]
    wheels = np.stack([xy + u * forward + v * left for u, v in corners], 1)  # (N, 4, 2): FL FR RL RR
    z = scene.layout.ground_height(wheels.reshape(-1, 2)).reshape(-1, 4)
    slope_forward = (z[:, 0] + z[:, 1] - z[:, 2] - z[:, 3]) / (2.0 * WHEELBASE)
    slope_left = (z[:, 0] + z[:, 2] - z[:, 1] - z[:, 3]) / (2.0 * TRACK)
    gradient = slope_forward[:, None] * forward + slope_left[:, None] * left
    up = np.column_stack([-gradient, np.ones(len(xy))])
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    ahead = np.column_stack([forward, np.zeros(len(xy))])
    ahead -= up * np.einsum("ij,ij->i", ahead, up)[:, None]
    ahead /= np.linalg.norm(ahead, axis=1, keepdims=True)
    ground_rotation = np.stack([ahead, np.cross(up, ahead), up], axis=2)
    ground_point = np.column_stack([xy, z.mean(axis=1)])
    poses = np.tile(np.eye(4), (len(xy), 1, 1))
    for k in range(len(xy)):
        body = rotation_from_euler_zyx(0.0, -0.004 * a_long[k], 0.006 * a_lat[k])
        poses[k, :3, :3] = ground_rotation[k] @ body
    poses[:, :3, 3] = ground_point + ground_rotation[:, :, 2] * height
    return poses
