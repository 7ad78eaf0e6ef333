"""The frame loop: load each frame once, run a method over it, and time every stage from outside.

The method does the algorithm; the loop does the bookkeeping (stage times, per-frame records, Ctrl-C),
so a method's code holds no timers and every method is timed the same way.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import LidarSequence, Points
from vcr_odom.device import cores_shared_by
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import Transform
from vcr_odom.odometry.chain import Odometry, PreparedFrame, Step
from vcr_odom.odometry.degeneracy import single_plane
from vcr_odom.registration.base import FinishingOdometry, SequentialOdometry
from vcr_odom.results import interruption_reason


@dataclass
class OdometryRun:
    """What a run produced; ``poses`` are LiDAR-frame poses of ``frame_indices``, the first = identity.

    ``stage_seconds``: ``load`` (reading frames) and, for a chained method, ``prepare`` (per-frame
    work), both in the producer thread when frames are prefetched; ``register`` (pairwise estimates),
    ``advance`` (checks, polish, chaining), or ``step`` for a method that keeps its own state
    (kiss-icp); ``optimise`` for a method that revises its trajectory at the end (KISS-SLAM's pose
    graph); ``waiting`` (for the producer); ``bookkeeping``, the rest of the wall time.
    ``slam``: what such a method reported (loop closures, its settings); empty for odometry.
    ``interruption``: why an ``interrupted`` run stopped (``interrupted (SIGTERM)``, ...), for its marker.
    """

    method: str
    frame_indices: list[int]
    poses: NDArray[np.float64]
    timestamps: NDArray[np.float64]
    stage_seconds: dict[str, float]
    wall_seconds: float
    interrupted: bool = False
    per_frame_info: list[dict[str, Any]] = field(default_factory=list)
    slam: dict[str, Any] = field(default_factory=dict)
    interruption: str = ""

    @property
    def flagged_frames(self) -> list[int]:
        """Frames whose motion estimate was implausible and replaced (see ``MotionLimits``)."""
        return [
            i for i, info in zip(self.frame_indices, self.per_frame_info, strict=False) if info.get("flagged")
        ]

    @property
    def single_plane_frames(self) -> list[int]:
        """Frames whose scan was almost one plane (:mod:`~vcr_odom.odometry.degeneracy`): their motion
        along it could not be measured, whatever the method reported."""
        return [
            i
            for i, info in zip(self.frame_indices, self.per_frame_info, strict=False)
            if "single_plane_m" in info
        ]

    @property
    def weak_axis_frames(self) -> list[int]:
        """Frames whose scan left a direction unmeasured (:func:`~vcr_odom.odometry.degeneracy.weak_axes`):
        the polish kept its start's position along it."""
        return [
            i
            for i, info in zip(self.frame_indices, self.per_frame_info, strict=False)
            if info.get("weak_axes")
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


Chunk = tuple[list[int], list[tuple[Points, float]], list[PreparedFrame] | None]


def _produce(
    sequence: LidarSequence,
    method: Odometry | SequentialOdometry,
    chunks: list[list[int]],
    timer: StageTimer,
) -> Iterator[Chunk]:
    """Load each chunk of frames once and, for a chained method, do its per-frame work."""
    timestamps = sequence.timestamps
    for chunk in chunks:
        with timer("load"):
            frames = [(sequence.frame(index), float(timestamps[index])) for index in chunk]
        prepared = None
        if isinstance(method, Odometry) and method.prepare_ahead:
            with timer("prepare"):
                prepared = method.prepare(frames)
        yield chunk, frames, prepared


def _ahead(produce: Iterator[Chunk], depth: int, stop: threading.Event) -> Iterator[Chunk]:
    """``produce`` run in a thread, at most ``depth`` chunks ahead of the consumer (a bounded queue),
    so frame t+1 is loaded and prepared while frame t is registered and polished. Its exceptions are
    raised here; ``stop`` ends it early (Ctrl-C in the consumer)."""
    items: queue.Queue[Chunk | BaseException | None] = queue.Queue(maxsize=depth)

    def work() -> None:
        try:
            for item in produce:
                while not stop.is_set():
                    try:
                        items.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
        except BaseException as error:  # handed to the consumer, which re-raises it
            items.put(error)
            return
        items.put(None)

    thread = threading.Thread(target=work, name="odometry-producer", daemon=True)
    thread.start()
    try:
        while (item := items.get()) is not None:
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        while thread.is_alive():  # let it see the stop and leave a put() it is blocked in
            with contextlib.suppress(queue.Empty):
                items.get(timeout=0.05)
        thread.join()


def _steps(method: Odometry | SequentialOdometry, item: Chunk, timer: StageTimer) -> list[Step]:
    _, frames, prepared = item
    if isinstance(method, Odometry):
        if prepared is None:
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
    prefetch: int = 2,
) -> OdometryRun:
    """Run ``method`` over the chosen frames. Ctrl-C (or SIGTERM, SIGHUP raised as
    :class:`~vcr_odom.errors.Interrupted`) stops cleanly and returns the partial trajectory.

    ``on_frame(index, pose, points)`` sees each frame once, as loaded (for progress, checkpoints, maps).
    ``prefetch``: chunks loaded (and, where :attr:`Odometry.prepare_ahead`, prepared) ahead in a
    second thread (0: all in this thread); the poses are the same either way. A chained method whose registrar batches (VCR-Net on a GPU) gets
    chunks of frames; the poses are the same, ``on_frame`` just comes a chunk at a time.
    A :class:`~vcr_odom.registration.base.FinishingOdometry` (KISS-SLAM) is finished after the last
    frame: the run's poses are then its optimised ones, where ``on_frame`` saw its online estimates.
    """
    if prefetch < 0:
        raise ConfigError(f"prefetch must be >= 0; got {prefetch}")
    if isinstance(method, Odometry):
        method.reset(timestamps_assumed=bool(getattr(sequence, "timestamps_assumed", False)))
    else:
        method.reset()
    timer = StageTimer()
    poses: list[Transform] = []
    infos: list[dict[str, Any]] = []
    used: list[int] = []
    started = time.perf_counter()
    interruption = ""
    batch = method.batch_size if isinstance(method, Odometry) else 1
    frame_indices = list(frame_indices)
    chunks = [frame_indices[i : i + batch] for i in range(0, len(frame_indices), batch)]
    produce = _produce(sequence, method, chunks, timer)
    stop = threading.Event()
    items = _ahead(produce, prefetch, stop) if prefetch else produce
    overlapped = bool(prefetch) and isinstance(method, Odometry) and method.registrar_works_ahead
    with cores_shared_by(2 if overlapped else 1):
        try:
            while True:
                with timer("waiting" if prefetch else "_serial"):
                    item = next(items, None)
                if item is None:
                    break
                for index, (points, _), step in zip(
                    item[0], item[1], _steps(method, item, timer), strict=True
                ):
                    poses.append(np.asarray(step.pose, dtype=np.float64))
                    thickness = single_plane(points)
                    infos.append(
                        step.info if thickness is None else {**step.info, "single_plane_m": thickness}
                    )
                    used.append(index)
                    if on_frame is not None:
                        on_frame(index, step.pose, points)
        except KeyboardInterrupt as error:
            interruption = interruption_reason(error)
        finally:
            stop.set()
            if hasattr(items, "close"):
                items.close()
    slam: dict[str, Any] = {}
    if poses and not interruption and isinstance(method, FinishingOdometry):
        try:
            with timer("optimise"):
                finished = method.finish(used)
            poses, slam = list(finished.poses), finished.summary
        except KeyboardInterrupt as error:  # while optimising: the online poses, marked interrupted
            interruption = f"{interruption_reason(error)} while optimising"
    wall = time.perf_counter() - started
    stages = {name: seconds for name, seconds in timer.seconds.items() if not name.startswith("_")}
    consumer = sum(stages.get(name, 0.0) for name in ("register", "advance", "step", "optimise", "waiting"))
    if not prefetch:
        consumer += stages.get("load", 0.0) + stages.get("prepare", 0.0)
    elif isinstance(method, Odometry) and not method.prepare_ahead:
        consumer += stages.get("prepare", 0.0)
    stages["bookkeeping"] = max(wall - consumer, 0.0)
    return OdometryRun(
        method=method.name,
        frame_indices=used,
        poses=np.stack(poses) if poses else np.empty((0, 4, 4)),
        timestamps=np.asarray(sequence.timestamps)[used] if used else np.empty(0),
        stage_seconds=stages,
        wall_seconds=wall,
        interrupted=bool(interruption),
        per_frame_info=infos,
        slam=slam,
        interruption=interruption,
    )
