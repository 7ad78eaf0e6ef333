"""The frame loop: chain relative poses into a trajectory, timing each stage.

Pairwise registrars are wrapped by :class:`PairwiseOdometry` so that the loop only ever talks to a
:class:`~vcr_odom.registration.base.SequentialOdometry` (kiss-icp is one natively).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import LidarSequence, Points
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import Transform, rotation_angle
from vcr_odom.registration.base import FAILED_STATUSES, Registrar, SequentialOdometry


class InitialGuess(StrEnum):
    """Where a local method starts: the identity (the paper's ICP baseline) or the last motion."""

    IDENTITY = "identity"
    CONSTANT_VELOCITY = "constant-velocity"


@dataclass(frozen=True)
class MotionLimits:
    """What a car can do between two scans; an estimate beyond it is a failed registration.

    Limits scale with the time between the frames, so strided runs (``--stride``) keep them meaningful.
    40 m/s is 144 km/h; 90 deg/s is a sharp urban turn at speed (KITTI peaks near 30 deg/s).
    """

    max_speed_m_s: float = 40.0
    max_turn_rate_deg_s: float = 90.0

    def violation(self, motion: Transform, seconds: float) -> str | None:
        """Why ``motion`` is implausible over ``seconds``, or None when it is plausible."""
        seconds = max(seconds, 1e-3)
        if not np.all(np.isfinite(motion)):
            return "non-finite estimate"
        distance = float(np.linalg.norm(motion[:3, 3]))
        if distance > self.max_speed_m_s * seconds:
            return f"moved {distance:.1f} m in {seconds:.2f} s (limit {self.max_speed_m_s:g} m/s)"
        angle = float(np.degrees(rotation_angle(motion)))
        if angle > self.max_turn_rate_deg_s * seconds:
            return f"turned {angle:.1f} deg in {seconds:.2f} s (limit {self.max_turn_rate_deg_s:g} deg/s)"
        return None


class PairwiseOdometry:
    """Turns a pairwise :class:`Registrar` into a sequential odometry.

    Each frame is prepared once; its prepared form serves as the source of one pair and the target of
    the next. ``pose[t+1] = pose[t] @ T_t_(t+1)``. A motion beyond ``limits`` (or a registration that
    reports too few points) is replaced by the previous motion and flagged in ``last_info``, so one bad
    pair never throws the trajectory across the map silently.
    """

    def __init__(
        self,
        registrar: Registrar,
        initial_guess: InitialGuess = InitialGuess.CONSTANT_VELOCITY,
        limits: MotionLimits | None = None,
    ):
        self.registrar = registrar
        self.initial_guess = InitialGuess(initial_guess)
        self.limits = limits or MotionLimits()
        self.name = registrar.name
        self.stage_seconds: dict[str, float] = {}
        self.last_info: dict[str, Any] = {}
        self.reset()

    def reset(self) -> None:
        self._previous: Any = None
        self._pose: Transform = np.eye(4)
        self._last_motion: Transform = np.eye(4)
        self._last_timestamp = 0.0
        self.stage_seconds = {"prepare": 0.0, "register": 0.0}
        self.last_info = {}

    def step(self, points: Points, timestamp: float) -> Transform:
        started = time.perf_counter()
        prepared = self.registrar.prepare(points)
        self.stage_seconds["prepare"] += time.perf_counter() - started
        if self._previous is None:
            self._previous, self._last_timestamp = prepared, timestamp
            return self._pose.copy()
        guess = self._last_motion if self.initial_guess is InitialGuess.CONSTANT_VELOCITY else np.eye(4)
        started = time.perf_counter()
        result = self.registrar.register(prepared, self._previous, guess)
        self.stage_seconds["register"] += time.perf_counter() - started
        self.last_info = {"fitness": result.fitness, "inlier_rmse": result.inlier_rmse, **result.info}
        motion = np.asarray(result.transform, dtype=np.float64)
        problem = self.limits.violation(motion, timestamp - self._last_timestamp)
        if problem is None and result.info.get("status") in FAILED_STATUSES:
            problem = str(result.info["status"])
        if problem is not None:
            # Fall back to the previous motion (constant velocity): a better guess than any wild jump.
            self.last_info |= {"flagged": True, "reason": problem}
            motion = self._last_motion
        self._last_motion = motion
        self._pose = self._pose @ motion
        self._previous, self._last_timestamp = prepared, timestamp
        return self._pose.copy()


@dataclass
class OdometryRun:
    """What a run produced; ``poses`` are LiDAR-frame poses of ``frame_indices``, the first = identity."""

    method: str
    frame_indices: list[int]
    poses: NDArray[np.float64]
    timestamps: NDArray[np.float64]
    stage_seconds: dict[str, float]
    wall_seconds: float
    interrupted: bool = False
    per_frame_info: list[dict[str, Any]] = field(default_factory=list)

    @property
    def flagged_frames(self) -> list[int]:
        """Frames whose motion estimate was implausible and replaced (see :class:`MotionLimits`)."""
        return [
            i for i, info in zip(self.frame_indices, self.per_frame_info, strict=False) if info.get("flagged")
        ]

    @property
    def frames_per_second(self) -> float:
        processed = len(self.frame_indices)
        return processed / self.wall_seconds if self.wall_seconds > 0 else float("nan")


def select_frames(length: int, frames: str | None = None, stride: int = 1) -> list[int]:
    """Frame indices for ``--frames A:B`` (Python slice semantics, B exclusive) and ``--stride K``."""
    if stride < 1:
        raise ConfigError(f"--stride must be a positive integer, got {stride}")
    start, stop = 0, length
    if frames:
        parts = frames.split(":")
        if len(parts) != 2:
            raise ConfigError(f"--frames expects A:B (e.g. 0:100), got {frames!r}")
        try:
            start = int(parts[0]) if parts[0] else 0
            stop = int(parts[1]) if parts[1] else length
        except ValueError as error:
            raise ConfigError(f"--frames expects integers A:B, got {frames!r}") from error
        start, stop, _ = slice(start, stop).indices(length)
    indices = list(range(start, stop, stride))
    if len(indices) < 2:
        raise ConfigError(
            f"--frames {frames or ':'} with --stride {stride} selects {len(indices)} frame(s) of {length}; "
            "odometry needs at least 2"
        )
    return indices


def _batch_size(method: SequentialOdometry) -> int:
    """Frames handed over at once: a method with ``step_many`` says how many it batches; others take 1."""
    if not callable(getattr(method, "step_many", None)):
        return 1
    return max(1, int(getattr(method, "batch_size", 1)))


def run_odometry(
    sequence: LidarSequence,
    method: SequentialOdometry,
    frame_indices: Sequence[int],
    *,
    on_frame: Callable[[int, Transform, Points], None] | None = None,
) -> OdometryRun:
    """Run ``method`` over the chosen frames. Ctrl-C stops cleanly and returns the partial trajectory.

    ``on_frame(index, pose, points)`` sees each frame once, as loaded (for progress, checkpoints, maps).
    A method that batches (``step_many``, ``batch_size`` > 1: VCR-Net on a GPU) gets chunks of frames;
    the poses are the same, ``on_frame`` just comes a chunk at a time.
    """
    method.reset()
    poses: list[Transform] = []
    infos: list[dict[str, Any]] = []
    used: list[int] = []
    load_seconds = 0.0
    method_seconds = 0.0
    started = time.perf_counter()
    interrupted = False
    all_timestamps = sequence.timestamps
    batch = _batch_size(method)
    frame_indices = list(frame_indices)
    try:
        for chunk_start in range(0, len(frame_indices), batch):
            chunk = frame_indices[chunk_start : chunk_start + batch]
            load_started = time.perf_counter()
            frames = [(sequence.frame(index), float(all_timestamps[index])) for index in chunk]
            load_seconds += time.perf_counter() - load_started
            step_started = time.perf_counter()
            if batch > 1:
                outcomes = method.step_many(frames)  # type: ignore[attr-defined]
            else:
                pose = method.step(*frames[0])
                outcomes = [(pose, dict(getattr(method, "last_info", {})))]
            method_seconds += time.perf_counter() - step_started
            for index, (points, _), (pose, info) in zip(chunk, frames, outcomes, strict=True):
                poses.append(np.asarray(pose, dtype=np.float64))
                infos.append(info)
                used.append(index)
                if on_frame is not None:
                    on_frame(index, pose, points)
    except KeyboardInterrupt:
        interrupted = True
    wall = time.perf_counter() - started
    # "method" is the whole of step(); methods that time their own stages add them as "method/<stage>".
    stages = {"load": load_seconds, "method": method_seconds}
    stages |= {f"method/{k}": v for k, v in getattr(method, "stage_seconds", {}).items()}
    stages["bookkeeping"] = max(wall - load_seconds - method_seconds, 0.0)
    return OdometryRun(
        method=method.name,
        frame_indices=used,
        poses=np.stack(poses) if poses else np.empty((0, 4, 4)),
        timestamps=np.asarray(all_timestamps)[used] if used else np.empty(0),
        stage_seconds=stages,
        wall_seconds=wall,
        interrupted=interrupted,
        per_frame_info=infos,
    )
