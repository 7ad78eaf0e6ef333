"""Relative poses chained into a trajectory: one class for every pairwise method, polished or not.

The work of a frame is split in three calls so that whoever runs the loop can time each and, for a
batching registrar, hand several frames over at once:

- :meth:`Odometry.prepare` is per-frame work without state (the registrar's and the polish's): a
  frame is prepared once and serves as the source of one pair and the target of the next;
- :meth:`Odometry.register` estimates each frame's motion from its predecessor (batched where the
  registrar batches: the relative poses are independent);
- :meth:`Odometry.advance` is the sequential part: plausibility check, polish, chaining.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vcr_odom.data.base import Points
from vcr_odom.geometry import Transform, project_to_se3
from vcr_odom.odometry.guided_kiss import motion_difference
from vcr_odom.odometry.limits import InitialGuess, MotionLimits
from vcr_odom.odometry.polish import Polish
from vcr_odom.registration.base import FAILED_STATUSES, BatchRegistrar, Registrar, RegistrationResult


@dataclass
class PreparedFrame:
    """A frame as the registrar and the polish need it."""

    registrar: Any
    polish: Any
    timestamp: float


@dataclass
class Step:
    """A frame's pose in the first frame's LiDAR frame and what happened (``flagged``, ``reason``, ...)."""

    pose: Transform
    info: dict[str, Any] = field(default_factory=dict)


class Odometry:
    """A pairwise :class:`Registrar` chained into odometry, with an optional :class:`Polish`.

    ``pose[t+1] = pose[t] @ T_t_(t+1)``. A motion beyond ``limits`` (or a registration that reports
    too few points) is replaced by the previous motion and flagged, so one bad pair never throws the
    trajectory across the map silently; a polish that leaves the limits is undone the same way.
    ``initial_guess``: where a registrar that needs one (ICP) starts; global ones get none.
    """

    def __init__(
        self,
        registrar: Registrar,
        polish: Polish | None = None,
        *,
        initial_guess: InitialGuess = InitialGuess.CONSTANT_VELOCITY,
        limits: MotionLimits | None = None,
    ) -> None:
        self.registrar = registrar
        self.polish = polish
        self.initial_guess = InitialGuess(initial_guess)
        self.limits = limits or MotionLimits()
        self.name = registrar.name if polish is None else f"{registrar.name}+{polish.name}"
        self.last_info: dict[str, Any] = {}
        self.reset()

    @property
    def batch_size(self) -> int:
        """Frames per call worth handing over (1 unless the registrar batches)."""
        if isinstance(self.registrar, BatchRegistrar):
            return max(1, int(getattr(self.registrar, "batch_size", 1)))
        return 1

    def reset(self) -> None:
        """Forget the previous frame and the pose: the next frame is the first (identity)."""
        self._previous: PreparedFrame | None = None
        self._pose: Transform = np.eye(4)
        self._last_motion: Transform = np.eye(4)
        self.last_info = {}

    def prepare(self, frames: Sequence[tuple[Points, float]]) -> list[PreparedFrame]:
        """Per-frame work for ``(points, timestamp)`` frames; no state is read or changed."""
        clouds = [points for points, _ in frames]
        if isinstance(self.registrar, BatchRegistrar) and len(clouds) > 1:
            prepared = self.registrar.prepare_batch(clouds)
        else:
            prepared = [self.registrar.prepare(points) for points in clouds]
        polished = [self.polish.prepare(points) if self.polish else None for points in clouds]
        return [
            PreparedFrame(p, q, float(t)) for p, q, (_, t) in zip(prepared, polished, frames, strict=True)
        ]

    def register(self, frames: Sequence[PreparedFrame]) -> list[RegistrationResult | None]:
        """Each frame's motion from its predecessor (the last advanced frame for the first of them);
        None for the first frame of a run, which has no predecessor."""
        predecessors = [self._previous, *frames[:-1]]
        pairs = [(f, p) for f, p in zip(frames, predecessors, strict=True) if p is not None]
        if isinstance(self.registrar, BatchRegistrar) and len(pairs) > 1:
            estimates = self.registrar.register_batch([(f.registrar, p.registrar) for f, p in pairs])
        else:
            guess = self._guess() if self.registrar.needs_initial_guess else None
            estimates = [self.registrar.register(f.registrar, p.registrar, guess) for f, p in pairs]
        return [None] * (len(frames) - len(pairs)) + list(estimates)

    def advance(self, frame: PreparedFrame, result: RegistrationResult | None) -> Step:
        """Check the estimate, polish it and chain it: the sequential half of a frame."""
        if self._previous is None or result is None:
            self._previous = frame
            if self.polish is not None:
                self.polish.start(frame.polish)
            self.last_info = {}
            return Step(self._pose.copy())
        previous = self._previous
        seconds = frame.timestamp - previous.timestamp
        coarse = np.asarray(result.transform, dtype=np.float64)
        info: dict[str, Any] = {"fitness": result.fitness, "inlier_rmse": result.inlier_rmse, **result.info}
        problem = self.limits.violation(coarse, seconds)
        if problem is None and result.info.get("status") in FAILED_STATUSES:
            problem = str(result.info["status"])
        if problem is not None:
            info |= {"flagged": True, "reason": problem}
            coarse = self._last_motion
        motion = coarse
        if self.polish is not None:
            polished = self.polish.refine(
                frame.polish, previous.polish, coarse, pose=self._pose, last_motion=self._last_motion
            )
            motion = polished.motion
            change_m, change_deg = motion_difference(coarse, motion)
            info |= polished.info | {"polish_change_m": change_m, "polish_change_deg": change_deg}
            diverged = self.limits.violation(motion, seconds)
            if diverged is not None:
                info |= {"flagged": True, "reason": f"polish diverged: {diverged}"}
                self.polish.restart(frame.polish, self._pose, coarse)
                motion = coarse
        # Re-orthonormalised at every step: a rotation error of the pose would otherwise grow from
        # chained float rounding, and kiss-icp (which takes poses from here) needs exact SE(3).
        self._pose = project_to_se3(self._pose @ motion)
        self._last_motion = motion
        self._previous = frame
        self.last_info = info
        return Step(self._pose.copy(), info)

    def step(self, points: Points, timestamp: float = 0.0) -> Transform:
        """One frame at a time (the :class:`SequentialOdometry` interface); ``last_info`` says what happened."""
        (frame,) = self.prepare([(points, timestamp)])
        (result,) = self.register([frame])
        return self.advance(frame, result).pose

    def _guess(self) -> Transform:
        if self.initial_guess is InitialGuess.CONSTANT_VELOCITY:
            return self._last_motion
        return np.eye(4)
