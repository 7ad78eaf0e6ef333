"""Synthetic LiDAR sequences: a car drives through the procedural street of :mod:`synth_scene` and a
spinning LiDAR ray-casts it; the result is written in the KITTI odometry layout.

For variety in training data the sensor (:data:`SENSOR_MODELS`: KITTI's HDL-64E by default, HDL-32E,
VLP-16, OS1-128), its mounting height, the scene style (:data:`SCENE_STYLES`), the speed, standing
starts and stops, and the frame rate can all be chosen; :meth:`SynthSequence.varied` draws them.

It is the built-in data set of ``vcr-odom`` (demo, tests, training): ground truth is exact, any
length is available, and the same seed always gives byte-identical files.

Conventions (see DESIGN.md): LiDAR frame x forward, y left, z up; internal poses are LiDAR-frame 4x4
matrices with frame 0 = identity; ``poses/XX.txt`` holds camera-frame poses
``T_cam = Tr @ T_lidar @ inv(Tr)`` like KITTI's own files.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
from numpy.typing import NDArray

from vcr_odom.data.synth_scene import (
    PREROLL,
    ROAD_STEP,
    SCENE_STYLES,
    MeshPart,
    StreetScene,
    Surface,
    scene_style,
)
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import (
    invert,
    lidar_to_camera_poses,
    project_to_se3,
    rotation_from_euler_zyx,
)
from vcr_odom.io import atomic_write_bytes, write_kitti_calib, write_kitti_poses, write_times

FRAME_PERIOD = 0.1
"""Seconds between frames by default: the HDL-64E spins at 10 Hz in KITTI."""
HEIGHT_RANGE = (1.5, 2.1)
"""Mounting heights (m) :meth:`SynthSequence.varied` draws from: low hatchbacks to vans and roof racks."""
START_DWELL = (1.0, 3.0)
STOP_DWELL = (2.0, 8.0)
STOP_SPACING = (60.0, 300.0)
"""With stops: seconds standing before pulling away, seconds per stop, metres between stops."""

# KITTI odometry calibration of sequences 00-02 (the rig the sensor model imitates).
KITTI_P0 = [7.188560e02, 0.0, 6.071928e02, 0.0, 0.0, 7.188560e02, 1.852157e02, 0.0, 0.0, 0.0, 1.0, 0.0]
KITTI_P1 = [
    7.188560e02,
    0.0,
    6.071928e02,
    -3.861448e02,
    0.0,
    7.188560e02,
    1.852157e02,
    0.0,
    0.0,
    0.0,
    1.0,
    0.0,
]
KITTI_P2 = [
    7.188560e02, 0.0, 6.071928e02, 4.538225e01, 0.0, 7.188560e02, 1.852157e02, -1.130887e-01,
    0.0, 0.0, 1.0, 3.779761e-03,
]  # fmt: skip
KITTI_P3 = [
    7.188560e02, 0.0, 6.071928e02, -3.372877e02, 0.0, 7.188560e02, 1.852157e02, 2.369057e00,
    0.0, 0.0, 1.0, 4.915215e-03,
]  # fmt: skip
KITTI_TR = project_to_se3(
    [
        [4.276802385584e-04, -9.999672484946e-01, -8.084491683471e-03, -1.198459927713e-02],
        [-7.210626507497e-03, 8.081198471645e-03, -9.999413164504e-01, -5.403984729748e-02],
        [9.999738645903e-01, 4.859485810390e-04, -7.206933692422e-03, -2.921968648686e-01],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
"""KITTI's velodyne -> left camera transform ``Tr``: x forward/z up into z forward/y down; made exactly
rigid (a ~1e-7 change, as the KITTI loader does) so that camera <-> LiDAR pose conversions round-trip."""


# ----------------------------------------------------------------------------------------------
# Sensor


SENSOR_MODELS = ("hdl64", "hdl32", "vlp16", "os128")
"""Names accepted by :meth:`SensorConfig.model` (``hdl64`` is the default :class:`SensorConfig`)."""


@dataclass(frozen=True)
class SensorConfig:
    """A spinning LiDAR; the defaults are KITTI's HDL-64E.

    Beams are given as blocks of evenly spaced elevations ``(top_deg, bottom_deg, count)``, top first.
    Like the real HDL-64E, the default has two: 32 upper lasers about 1/3 deg apart and 32 lower lasers
    about 1/2 deg apart, spanning +2 deg to -24.8 deg. Other sensors: :meth:`model`.
    """

    beam_blocks: tuple[tuple[float, float, int], ...] = ((2.0, -8.33, 32), (-8.83, -24.8, 32))
    azimuth_steps: int = 2083
    range_noise: float = 0.02
    min_range: float = 2.5
    max_range: float = 120.0
    height: float = 1.73
    dropout: float = 0.02
    reflectance_noise: float = 0.03
    azimuth_spread: float = 4.0
    """Per-laser azimuth offsets are drawn within +-this (deg); 0 where lasers fire in one column."""
    name: str = "hdl64"

    def __post_init__(self) -> None:
        if not self.beam_blocks or any(int(count) < 1 for *_, count in self.beam_blocks):
            raise ConfigError(f"sensor beam_blocks need at least one beam each, got {self.beam_blocks!r}")
        if self.azimuth_steps < 1:
            raise ConfigError(f"sensor azimuth_steps must be >= 1, got {self.azimuth_steps!r}")
        if not 0.0 <= self.min_range < self.max_range:
            raise ConfigError(
                f"sensor needs 0 <= min_range < max_range, got {self.min_range}, {self.max_range}"
            )

    @classmethod
    def model(cls, name: str) -> SensorConfig:
        """A named sensor preset (see :data:`SENSOR_MODELS`); ``hdl64`` equals ``SensorConfig()``."""
        if name not in _SENSOR_PRESETS:
            raise ConfigError(f"sensor must be one of {', '.join(SENSOR_MODELS)}, got {name!r}")
        return cls(name=name, **_SENSOR_PRESETS[name])

    @property
    def n_beams(self) -> int:
        return sum(int(count) for *_, count in self.beam_blocks)

    @property
    def elevations(self) -> NDArray[np.float64]:
        """Beam elevation angles in radians, top beam first."""
        blocks = [np.linspace(top, bottom, int(count)) for top, bottom, count in self.beam_blocks]
        return np.radians(np.concatenate(blocks))

    @property
    def n_rays(self) -> int:
        return self.n_beams * self.azimuth_steps

    @property
    def beam_azimuth_offsets(self) -> NDArray[np.float64]:
        """Fixed per-laser azimuth offsets (radians, within +-``azimuth_spread`` deg), like the rotational
        corrections of a real HDL-64E: its 64 lasers do not fire along one vertical line."""
        if self.azimuth_spread <= 0.0:
            return np.zeros(self.n_beams)
        spread = self.azimuth_spread
        return np.radians(np.random.default_rng(64).uniform(-spread, spread, self.n_beams))

    def directions(self) -> NDArray[np.float64]:
        """Unit ray directions ``(n_rays, 3)`` in the LiDAR frame, laser by laser (KITTI's ring order),
        each ring turning clockwise from straight behind like the real sensor."""
        elevation = self.elevations[:, None]
        steps = np.arange(self.azimuth_steps) * (2.0 * math.pi / self.azimuth_steps)
        azimuth = math.pi - steps[None, :] + self.beam_azimuth_offsets[:, None]
        ce = np.cos(elevation)
        directions = np.stack(
            [ce * np.cos(azimuth), ce * np.sin(azimuth), np.broadcast_to(np.sin(elevation), azimuth.shape)],
            -1,
        )
        return directions.reshape(-1, 3)


_SENSOR_PRESETS: dict[str, dict[str, Any]] = {
    "hdl64": {},
    # Velodyne HDL-32E: 32 lasers 1.33 deg apart, 0.2 deg azimuth at 10 Hz, +-2 cm accuracy.
    "hdl32": {
        "beam_blocks": ((10.67, -30.67, 32),), "azimuth_steps": 1800, "range_noise": 0.015,
        "min_range": 1.0, "max_range": 100.0, "azimuth_spread": 0.0,
    },
    # Velodyne VLP-16 (Puck): 16 lasers 2 deg apart, 0.2 deg azimuth at 10 Hz, +-3 cm accuracy.
    "vlp16": {
        "beam_blocks": ((15.0, -15.0, 16),), "azimuth_steps": 1800, "range_noise": 0.03,
        "min_range": 1.0, "max_range": 100.0, "azimuth_spread": 0.0,
    },
    # Ouster OS1-128 in its 1024x10 mode: 45 deg vertical field, a few cm of range noise.
    "os128": {
        "beam_blocks": ((22.5, -22.5, 128),), "azimuth_steps": 1024, "range_noise": 0.03,
        "min_range": 0.8, "max_range": 120.0, "azimuth_spread": 0.0,
    },
}  # fmt: skip


# Per-surface sensor behaviour (albedo itself is per triangle, see synth_scene): the probability that a
# hit returns nothing (glass), a one-sided range spread (m) into porous foliage, and retro-reflectors
# (signs, road paint) that stay bright at grazing incidence.
_NO_RETURN = np.zeros(len(Surface), dtype=np.float32)
_NO_RETURN[Surface.GLASS] = 0.6
_NO_RETURN[Surface.CAR_GLASS] = 0.45
_NO_RETURN[Surface.VEGETATION] = 0.1
_POROUS = np.zeros(len(Surface), dtype=np.float32)
_POROUS[Surface.VEGETATION] = 0.12
_RETRO = np.zeros(len(Surface), dtype=bool)
_RETRO[[Surface.SIGN, Surface.PAINT]] = True


class LidarSimulator:
    """Ray-casts one scene with open3d's Embree-backed :class:`RaycastingScene`: one call per frame."""

    def __init__(self, mesh: MeshPart, sensor: SensorConfig) -> None:
        self.sensor = sensor
        self.surface = mesh.surface
        self.albedo = mesh.albedo
        self._directions = sensor.directions().astype(np.float32)
        self._axes = np.ascontiguousarray(self._directions.T)  # x, y, z rows: fast gathers per axis
        self._threads = _available_cores()
        self._scene = o3d.t.geometry.RaycastingScene()
        if len(mesh):
            self._scene.add_triangles(
                o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                o3d.core.Tensor(mesh.triangles.astype(np.uint32)),
            )

    def scan(self, pose: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.float32]:
        """Points ``(N, 4)`` float32 (x, y, z in the LiDAR frame, reflectance in [0, 1]) for a sensor
        at world pose ``pose`` (LiDAR -> world).

        The spin phase is random per frame (a real sensor's firing grid is not locked to the car), so
        two frames never share a sampling pattern a network could lock on to.
        """
        sensor = self.sensor
        phase = rng.uniform(0.0, 2.0 * math.pi / sensor.azimuth_steps)
        spin = rotation_from_euler_zyx(-phase, 0.0, 0.0)
        rays = np.empty((len(self._directions), 6), dtype=np.float32)
        rays[:, :3] = pose[:3, 3]
        _rotate_into(self._directions, pose[:3, :3] @ spin, rays[:, 3:])
        hits = self._scene.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=self._threads)
        t_hit = hits["t_hit"].numpy()
        index = np.flatnonzero(t_hit <= sensor.max_range)  # inf (no hit) compares False
        n = len(index)
        t_hit = t_hit[index]
        primitive = hits["primitive_ids"].numpy()[index]
        surface = self.surface[primitive]
        # Range: Gaussian noise everywhere, a one-sided spread into foliage.
        measured = t_hit + rng.standard_normal(n, dtype=np.float32) * np.float32(sensor.range_noise)
        porous = np.flatnonzero(_POROUS[surface])
        measured[porous] += (
            np.abs(rng.standard_normal(len(porous), dtype=np.float32)) * _POROUS[surface[porous]]
        )
        # Incidence over all rays (contiguous, cheaper than gathering first); misses are never selected.
        cos_all = np.einsum("ij,ij->i", hits["primitive_normals"].numpy(), rays[:, 3:])
        reflectance = self._reflectance(surface, self.albedo[primitive], np.abs(cos_all[index]), t_hit, rng)
        returned = rng.random(n, dtype=np.float32) >= np.maximum(
            _NO_RETURN[surface], np.float32(sensor.dropout)
        )
        returned &= (measured >= sensor.min_range) & (measured <= sensor.max_range)
        keep = index[returned]
        r = measured[returned]
        x, y, z = (self._axes[i][keep] for i in range(3))
        c, s = np.float32(spin[0, 0]), np.float32(spin[1, 0])
        return np.stack([(c * x - s * y) * r, (s * x + c * y) * r, z * r, reflectance[returned]], axis=1)

    def _reflectance(
        self,
        surface: NDArray[np.uint8],
        albedo: NDArray[np.float32],
        cos_incidence: NDArray[np.float32],
        distance: NDArray[np.float32],
        rng: np.random.Generator,
    ) -> NDArray[np.float32]:
        """Albedo with a mild incidence falloff (retro-reflectors keep their brightness), weak far returns,
        speckle and a noise floor, quantised to 0.01.

        Fitted by eye to KITTI's HDL-64E scans: median about 0.3 within 40 m, weak (mostly < 0.1) beyond.
        """
        shading = np.where(_RETRO[surface], 0.85 + 0.15 * cos_incidence, 0.55 + 0.45 * cos_incidence)
        value = albedo * shading / (1.0 + (distance * np.float32(1.0 / 42.0)) ** 6)
        # 10 % speckle plus a constant floor, drawn as one Gaussian of the combined spread.
        sigma = np.sqrt((0.1 * value) ** 2 + np.float32(self.sensor.reflectance_noise) ** 2)
        value += sigma * rng.standard_normal(len(value), dtype=np.float32)
        return np.round(np.clip(value, 0.0, 1.0), 2)


def _rotate_into(
    vectors: NDArray[np.float32], rotation: NDArray[np.float64], out: NDArray[np.float32]
) -> None:
    """``out = vectors @ rotation.T`` column by column: a BLAS call here would start its own threads and
    fight Embree's for the same cores."""
    r = rotation.astype(np.float32)
    for i in range(3):
        np.multiply(vectors[:, 0], r[i, 0], out=out[:, i])
        out[:, i] += vectors[:, 1] * r[i, 1]
        out[:, i] += vectors[:, 2] * r[i, 2]


def _available_cores() -> int:
    """Cores this process may use (Embree's automatic choice over-subscribes shared machines)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


# ----------------------------------------------------------------------------------------------
# Drive


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


def _speed_profile(
    scene: StreetScene,
    speed: float,
    rng: np.random.Generator,
    stops: NDArray[np.int64] | None = None,
) -> NDArray[np.float64]:
    """Speed (m/s) at every road sample: random cruising speeds between 0.5x and 1.5x ``speed``,
    slowed for curves (lateral acceleration <= 2 m/s^2), zero at the ``stops`` samples, and limited to
    gentle acceleration/braking (so the car brakes into each stop and pulls away from it)."""
    n = len(scene.road.xy)
    stations = np.arange(n) * ROAD_STEP
    knots, targets = [0.0], [speed * rng.uniform(0.5, 1.5)]
    while knots[-1] < stations[-1]:  # drawn in order along the road: a longer road starts the same way
        knots.append(knots[-1] + rng.uniform(60.0, 250.0))
        targets.append(speed * rng.uniform(0.5, 1.5))
    v = np.interp(stations, knots, targets)
    v = np.minimum(v, np.sqrt(2.0 / np.maximum(np.abs(scene.road.curvature), 1e-6)))
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


def make_drive(
    scene: StreetScene,
    frames: int,
    speed: float,
    sensor: SensorConfig,
    seed: int,
    stops: bool = False,
    frame_period: float = FRAME_PERIOD,
) -> Drive:
    """The car follows the road at the speed profile (with ``stops``: from a standing start, stopping
    now and then); yaw follows the road, pitch and roll the ground under it, plus a little body
    pitch/roll from braking and cornering."""
    n = len(scene.road.xy)
    stop_at, dwell = (
        _stops(n, np.random.default_rng([seed, 7])) if stops else (np.zeros(0, np.int64), np.zeros(0))
    )
    v = _speed_profile(scene, speed, np.random.default_rng([seed, 4]), stop_at)
    stations = np.arange(n) * ROAD_STEP
    s = _frame_stations(v, np.arange(frames) * frame_period, stop_at, dwell)
    speed_at = np.interp(s, stations, v)
    accel = np.interp(s, stations, np.gradient(v, ROAD_STEP) * v)
    xy, heading, curvature = scene.road.sample(s)
    poses = _vehicle_poses(scene, xy, heading, accel, speed_at**2 * curvature, sensor.height)
    return Drive(s, speed_at, poses)


WHEELBASE, TRACK = 2.7, 1.6
"""Where the car's wheels touch the road (m): a VW Passat like KITTI's recording car."""


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


# ----------------------------------------------------------------------------------------------
# The sequence


class SynthSequence:
    """A synthetic drive as a :class:`~vcr_odom.data.base.LidarSequence`, generated on demand.

    Frames are ray-cast in windows of ``window`` frames: each window gets one ray-casting scene of
    everything the sensor can reach from its poses, so memory and build time stay bounded for any
    length and a frame's content never depends on which frames were asked for before.

    ``sensor`` is a :class:`SensorConfig` or a preset name (:data:`SENSOR_MODELS`); ``height`` overrides
    its mounting height (m); ``scene`` is a style of :data:`SCENE_STYLES`; ``stops`` makes the car start
    from rest and stop now and then; ``frame_period`` is the time between frames (s). The defaults give
    the original sequences, byte for byte.
    """

    def __init__(
        self,
        frames: int = 200,
        seed: int = 0,
        speed: float = 10.0,
        sensor: SensorConfig | str | None = None,
        window: int = 200,
        *,
        height: float | None = None,
        scene: str = "suburban",
        stops: bool = False,
        frame_period: float = FRAME_PERIOD,
    ) -> None:
        _check_options(frames, seed, speed)
        _check_setup(height, frame_period)
        scene_style(scene)  # fail now, not on first use
        if window < 1:
            raise ConfigError(f"window must be >= 1 frame, got {window!r}")
        if isinstance(sensor, str):
            sensor = SensorConfig.model(sensor)
        sensor = sensor or SensorConfig()
        self.frames = frames
        self.seed = seed
        self.speed = speed
        self.sensor = sensor if height is None else replace(sensor, height=float(height))
        self.window = window
        self.scene_style = scene
        self.stops = bool(stops)
        self.frame_period = float(frame_period)
        extras = [scene] if scene != "suburban" else []
        extras += [self.sensor.name] if self.sensor.name != "hdl64" else []
        self.name = "-".join([f"synth-seed{seed}", *extras])
        self._simulators: dict[int, LidarSimulator] = {}

    @classmethod
    def varied(cls, seed: int, frames: int = 200, window: int = 200) -> SynthSequence:
        """A drive with a random sensor, mounting height, scene style, speed and stops (all drawn from
        ``seed``), so training data covers more than one car and one kind of street."""
        rng = np.random.default_rng([seed, 6])
        scene = str(rng.choice(SCENE_STYLES))
        speeds = {"highway": (18.0, 28.0), "avenue": (8.0, 16.0), "oldtown": (3.0, 8.0)}
        return cls(
            frames=frames,
            seed=seed,
            speed=float(rng.uniform(*speeds.get(scene, (6.0, 14.0)))),
            sensor=str(rng.choice(SENSOR_MODELS)),
            window=window,
            height=float(rng.uniform(*HEIGHT_RANGE)),
            scene=scene,
            stops=scene != "highway" and bool(rng.random() < 0.5),
        )

    @cached_property
    def scene(self) -> StreetScene:
        # Road long enough for the fastest possible drive plus what the sensor sees beyond its end.
        reach = self.frames * self.frame_period * self.speed * 1.5 + self.sensor.max_range + 60.0
        return StreetScene(self.seed, reach, scene=self.scene_style)

    @cached_property
    def drive(self) -> Drive:
        return make_drive(
            self.scene, self.frames, self.speed, self.sensor, self.seed, self.stops, self.frame_period
        )

    def __len__(self) -> int:
        return self.frames

    @property
    def world_poses(self) -> NDArray[np.float64]:
        """LiDAR -> world poses of the procedural world (not re-anchored)."""
        return self.drive.world_poses

    @cached_property
    def _relative_poses(self) -> NDArray[np.float64]:
        return invert(self.world_poses[0])[None] @ self.world_poses

    @property
    def gt_poses(self) -> NDArray[np.float64]:
        """LiDAR-frame poses with frame 0 = identity (DESIGN's convention); a copy, safe to modify."""
        return self._relative_poses.copy()

    @property
    def timestamps(self) -> NDArray[np.float64]:
        return np.arange(self.frames) * self.frame_period

    @property
    def tr_velo_to_cam(self) -> NDArray[np.float64]:
        return KITTI_TR.copy()

    @property
    def length(self) -> float:
        """Length of the drive in metres."""
        return self.drive.length

    def frame(self, index: int) -> NDArray[np.float32]:
        """Ray-cast frame ``index``: float32 ``(N, 4)`` in the LiDAR frame, like a KITTI ``.bin``."""
        if not 0 <= index < self.frames:
            raise IndexError(f"frame {index} out of range for a sequence of {self.frames} frames")
        simulator = self._simulator(index // self.window)
        return simulator.scan(self.world_poses[index], np.random.default_rng([self.seed, 5, index]))

    def frame_and_pose(self, index: int) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
        """A frame and its LiDAR-frame ground-truth pose (frame 0 = identity), without writing."""
        return self.frame(index), self._relative_poses[index].copy()

    def _simulator(self, window: int) -> LidarSimulator:
        if window not in self._simulators:
            self._simulators.clear()  # one window at a time keeps memory flat
            poses = self.world_poses[window * self.window : (window + 1) * self.window]
            mesh = self.scene.mesh_near(poses[:, :2, 3], self.sensor.max_range + 1.0)
            self._simulators[window] = LidarSimulator(mesh, self.sensor)
        return self._simulators[window]


def _check_options(frames: int, seed: int, speed: float) -> None:
    if not isinstance(frames, (int, np.integer)) or frames < 2:
        raise ConfigError(f"frames must be an integer >= 2, got {frames!r}")
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    if not 1.0 <= speed <= 30.0:
        raise ConfigError(f"speed must be between 1 and 30 m/s, got {speed!r}")


def _check_setup(height: float | None, frame_period: float) -> None:
    if height is not None and not 0.3 <= height <= 5.0:
        raise ConfigError(f"height must be between 0.3 and 5 m, got {height!r}")
    if not 0.02 <= frame_period <= 1.0:
        raise ConfigError(f"frame_period must be between 0.02 and 1 s (1-50 Hz), got {frame_period!r}")


# ----------------------------------------------------------------------------------------------
# Writing the KITTI layout

SEQUENCE_NAME = re.compile(r"^[A-Za-z0-9_-]+$")
"""What ``seq`` may be: it becomes a folder and a file name."""


def write_bin(path: Path, points: NDArray[np.float32]) -> Path:
    """Write a KITTI ``.bin`` atomically: never a half-written frame."""
    return atomic_write_bytes(path, np.ascontiguousarray(points, dtype=np.float32).tobytes())


def kitti_calib() -> dict[str, object]:
    """``calib.txt`` entries of KITTI's sequences 00-02 (the projections are unused but expected)."""
    return {"P0": KITTI_P0, "P1": KITTI_P1, "P2": KITTI_P2, "P3": KITTI_P3, "Tr": KITTI_TR}


def write_sequence(
    sequence: SynthSequence,
    out_root: str | os.PathLike[str],
    seq: str = "00",
    progress: Callable[[int], None] | None = None,
) -> Path:
    """Write ``sequence`` under ``out_root`` in the KITTI odometry layout; returns the sequence folder.

    Frames first, then ``calib.txt``, ``times.txt`` and last the poses, so a sequence with a poses file
    is complete. Stale frames of an earlier, longer run in the same folder are removed.
    """
    if not SEQUENCE_NAME.match(seq):
        raise ConfigError(f"seq must be letters, digits, '-' or '_', got {seq!r}")
    root = Path(out_root)
    seq_dir = root / "sequences" / seq
    velodyne = seq_dir / "velodyne"
    velodyne.mkdir(parents=True, exist_ok=True)
    (root / "poses" / f"{seq}.txt").unlink(missing_ok=True)
    for stale in velodyne.glob("*.bin"):
        if stale.stem.isdigit() and int(stale.stem) >= len(sequence):
            stale.unlink()
    for index in range(len(sequence)):
        write_bin(velodyne / f"{index:06d}.bin", sequence.frame(index))
        if progress is not None:
            progress(index + 1)
    write_kitti_calib(seq_dir / "calib.txt", kitti_calib())
    write_times(seq_dir / "times.txt", sequence.timestamps)
    write_kitti_poses(root / "poses" / f"{seq}.txt", lidar_to_camera_poses(sequence.gt_poses, KITTI_TR))
    return seq_dir


def generate_sequence(
    out_root: str | os.PathLike[str],
    seq: str = "00",
    frames: int = 200,
    seed: int = 0,
    speed: float = 10.0,
    progress: Callable[[int], None] | None = None,
    **options: Any,
) -> Path:
    """Generate and write a synthetic sequence in the KITTI layout; returns ``<out_root>/sequences/<seq>``.

    ``options`` go to :class:`SynthSequence` (``sensor``, ``height``, ``scene``, ``stops``, ``frame_period``).
    """
    sequence = SynthSequence(frames=frames, seed=seed, speed=speed, **options)
    return write_sequence(sequence, out_root, seq, progress)
