"""The frame loop: load each frame once, run a method over it, and time every stage from outside.

The method does the algorithm; the loop does the bookkeeping (stage times, per-frame records, Ctrl-C),
so a method's code holds no timers and every method is timed the same way.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import LidarSequence, Points
from vcr_odom.geometry import Transform
from vcr_odom.odometry.chain import Odometry, Step
from vcr_odom.registration.base import SequentialOdometry


@dataclass
class OdometryRun:
    """What a run produced; ``poses`` are LiDAR-frame poses of ``frame_indices``, the first = identity.

    ``stage_seconds``: ``load`` (reading frames), then for a chained method ``prepare`` (per-frame
    work), ``register`` (pairwise estimates), ``advance`` (checks, polish, chaining), or ``step`` for
    a method that keeps its own state (kiss-icp); ``bookkeeping`` is the rest of the wall time.
    """

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
        """Frames whose motion estimate was implausible and replaced (see ``MotionLimits``)."""
        return [
            i for i, info in zip(self.frame_indices, self.per_frame_info, strict=False) if info.get("flagged")
        ]

    @property
    def frames_per_second(self) -> float:
        processed = len(self.frame_indices)
        return processed / self.wall_seconds if self.wall_seconds > 0 else float("nan")


class StageTimer:
    """Accumulated wall time per named stage."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        started = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] += time.perf_counter() - started


def _steps(
    method: Odometry | SequentialOdometry, frames: list[tuple[Points, float]], timer: StageTimer
) -> list[Step]:
    if isinstance(method, Odometry):
        with timer("prepare"):
            prepared = method.prepare(frames)
        with timer("register"):
            results = method.register(prepared)
        with timer("advance"):
            return [method.advance(frame, result) for frame, result in zip(prepared, results, strict=True)]
    steps = []
    for points, timestamp in frames:
        with timer("step"):
            pose = method.step(points, timestamp)
        steps.append(Step(np.asarray(pose, dtype=np.float64), dict(getattr(method, "last_info", {}))))
    return steps


def run_odometry(
    sequence: LidarSequence,
    method: Odometry | SequentialOdometry,
    frame_indices: Sequence[int],
    *,
    on_frame: Callable[[int, Transform, Points], None] | None = None,
) -> OdometryRun:
    """Run ``method`` over the chosen frames. Ctrl-C stops cleanly and returns the partial trajectory.

    ``on_frame(index, pose, points)`` sees each frame once, as loaded (for progress, checkpoints, maps).
    A chained method whose registrar batches (VCR-Net on a GPU) gets chunks of frames; the poses are
    the same, ``on_frame`` just comes a chunk at a time.
    """
    method.reset()
    timer = StageTimer()
    poses: list[Transform] = []
    infos: list[dict[str, Any]] = []
    used: list[int] = []
    started = time.perf_counter()
    interrupted = False
    all_timestamps = sequence.timestamps
    batch = method.batch_size if isinstance(method, Odometry) else 1
    frame_indices = list(frame_indices)
    try:
        for chunk_start in range(0, len(frame_indices), batch):
            chunk = frame_indices[chunk_start : chunk_start + batch]
            with timer("load"):
                frames = [(sequence.frame(index), float(all_timestamps[index])) for index in chunk]
            for index, (points, _), step in zip(chunk, frames, _steps(method, frames, timer), strict=True):
                poses.append(np.asarray(step.pose, dtype=np.float64))
                infos.append(step.info)
                used.append(index)
                if on_frame is not None:
                    on_frame(index, step.pose, points)
    except KeyboardInterrupt:
        interrupted = True
    wall = time.perf_counter() - started
    stages = dict(timer.seconds)
    stages["bookkeeping"] = max(wall - sum(stages.values()), 0.0)
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
