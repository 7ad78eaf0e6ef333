"""Relative poses chained into a trajectory: one class for every pairwise method, polished or not.

The work of a frame is split in three calls so that whoever runs the loop can time each, run the first
ahead in another thread, and, for a batching registrar, hand several frames over at once:

- :meth:`Odometry.prepare` is per-frame work without state (the registrar's and the polish's): a
  frame is prepared once and serves as the source of one pair and the target of the next;
- :meth:`Odometry.register` estimates each frame's motion from its predecessor (batched where the
  registrar batches: the relative poses are independent);
- :meth:`Odometry.advance` is the sequential part: the frame's motion (``_motion``, its whole path
  in one method: the polish from the prior, the doubt rule, the registrar's estimate, the motion
  limits) chained onto the pose.

With a polish, ``consult="on-doubt"`` asks the global registrar only where the motion prior's polished
result is in doubt (:class:`DoubtRule`); its per-frame work then waits until a pair needs it.
"""

from __future__ import annotations

import statistics
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from vcr_odom.data.base import Points
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import Transform, motion_difference, project_to_se3
from vcr_odom.odometry.agreement import BASIN_DEG, BASIN_M, MARKEDLY_WORSE, within_basin
from vcr_odom.odometry.limits import InitialGuess, MotionLimits
from vcr_odom.odometry.polish import Polish, PolishResult, PriorAttempt
from vcr_odom.registration.base import (
    FAILED_STATUSES,
    TOO_FEW_POINTS,
    BatchRegistrar,
    Registrar,
    RegistrationResult,
)

FAR_FROM_PRIOR = "far from the prior"
NOT_NEEDED = "not needed"
SECOND_START_AGREES = "the polish from standing still ends there too"
RECENT_PAIRS = 5
"""Pairs whose median estimated speed a new pair's may not depart from implausibly
(:class:`~vcr_odom.odometry.limits.MotionLimits`): the estimates as made, before any was replaced, so
that a real change of speed that several pairs agree on is believed, never locked out (a failed
registration, or an estimate beyond the speed and turn limits, measures no speed: its pair counts as
chained)."""
RATE_HINT = "give the real times with --times FILE or a times.txt beside the scans"

Consult = Literal["every-frame", "on-doubt"]
CONSULT_CHOICES: dict[str, str] = {
    "every-frame": "the global registrar on every pair; the polish starts from its estimate and the prior",
    "on-doubt": "the polish from the motion prior first; the global registrar only on a run's first pair, "
    "where that result fits poorly, is implausible or far from the prior, and on every pair while most "
    "recent pairs were in doubt",
}


@dataclass
class PreparedFrame:
    """A frame as the registrar and the polish need it; ``registrar`` is None until a pair needs it
    (``consult="on-doubt"``), which is why the points are kept."""

    points: Points
    timestamp: float
    polish: Any = None
    registrar: Any = None


@dataclass
class Step:
    """A frame's pose in the first frame's LiDAR frame and what happened (``flagged``, ``reason``, ...)."""

    pose: Transform
    info: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class DoubtRule:
    """When the prior's result is not taken on trust.

    - On a run's first pair (no motion history), and when its motion is implausible.
    - When it fits worse than ``ratio`` times the median fit of the last ``window`` results that were:
      a wrong result fits the other scan markedly worse than the ones before it
      (:data:`~vcr_odom.odometry.agreement.MARKEDLY_WORSE`, the margin by which the polish also
      ranks two starts' results), while the fit itself varies by sensor and scene, hence a ratio to the
      run's own history.
    - When the local method had to move more than ``correction_m`` or ``correction_deg`` from the
      motion prior to get there (0 turns a check off): the prior started outside the basin within
      which two starts end in one result (:data:`~vcr_odom.odometry.agreement.BASIN_M`, ``BASIN_DEG``),
      where a wrong minimum can fit as well as the right one. The fit misses these quiet failures;
      keyframes saved by distance, whose spacing the constant-velocity prior cannot know, meet them
      most (docs/benchmarks.md, "Robust by default", has the measurements). A car at 10 Hz stays well inside.
      Such a result is first put to a second start (``second_start``; False skips it): the polish from
      standing still. Where that start lies outside the prediction's basin and still ends in the
      prediction's result, two independent starts agree and the result is not in doubt: the test the
      network's start would put it to, at the cost of one local registration instead of the network.
    - When the checks above doubted more than ``share`` of the last ``window`` pairs (at least half a
      window of them): on such a stretch (keyframes, large strides) the prior is wrong more often than
      right, so a pair it seems to get right is no more trustworthy than its neighbours, and asking on
      it too adds little to what is asked already. A pair asked for this reason alone does not count
      as doubted, so the asking ends when the prior holds again. 1 turns this off.
    """

    ratio: float = MARKEDLY_WORSE
    window: int = 20
    correction_m: float = BASIN_M
    correction_deg: float = BASIN_DEG
    share: float = 0.5
    second_start: bool = True


def network_asked(info: Mapping[str, Any]) -> bool:
    """Whether the global registrar (the network) was asked for this frame's motion: with
    ``consult="on-doubt"`` a frame's ``global`` says why, or that it was not needed (and why not)."""
    reason = info.get("global")
    return bool(reason) and not str(reason).startswith(NOT_NEEDED)


def _flag_unregistered(info: dict[str, Any]) -> dict[str, Any]:
    """A frame the polish could not register (too few points: it kept its start, the previous
    motion) is flagged as one the registrar could not, so run and map name it and their poses agree."""
    if info.get("polish_status") == TOO_FEW_POINTS and not info.get("flagged"):
        info |= {"flagged": True, "reason": TOO_FEW_POINTS}
    return info


class Odometry:
    """A pairwise :class:`Registrar` chained into odometry, with an optional :class:`Polish`.

    ``pose[t+1] = pose[t] @ T_t_(t+1)``. A motion beyond ``limits`` (or a registration that reports
    too few points) is replaced by the previous motion and flagged, so one bad pair never throws the
    trajectory across the map silently; a polish that leaves the limits is undone the same way. The
    limits include a speed change against the last :data:`RECENT_PAIRS` estimates.
    ``initial_guess``: where a registrar that needs one (ICP) starts; global ones get none.
    ``consult``: see :data:`CONSULT_CHOICES` (only with a polish).
    """

    def __init__(
        self,
        registrar: Registrar,
        polish: Polish | None = None,
        *,
        initial_guess: InitialGuess = InitialGuess.CONSTANT_VELOCITY,
        limits: MotionLimits | None = None,
        consult: Consult = "every-frame",
        doubt: DoubtRule | None = None,
    ) -> None:
        if consult not in CONSULT_CHOICES:
            raise ConfigError(f"consult must be one of {', '.join(CONSULT_CHOICES)}; got {consult!r}")
        self.registrar = registrar
        self.polish = polish
        self.initial_guess = InitialGuess(initial_guess)
        self.limits = limits or MotionLimits()
        self.consult: Consult = consult if polish is not None else "every-frame"
        self.doubt = doubt or DoubtRule()
        self.name = registrar.name if polish is None else f"{registrar.name}+{polish.name}"
        self.last_info: dict[str, Any] = {}
        self.reset()

    @property
    def batch_size(self) -> int:
        """Frames per call worth handing over (1 unless the registrar batches every pair)."""
        if isinstance(self.registrar, BatchRegistrar) and self.consult == "every-frame":
            return max(1, int(getattr(self.registrar, "batch_size", 1)))
        return 1

    @property
    def prepare_ahead(self) -> bool:
        """Whether the per-frame work gains from running in a second thread: not where it is kiss-icp's
        (its C++ holds Python's GIL, so a thread only adds switching; docs/results.md "Benchmarks and speed")."""
        return self.polish is None or self.polish.prepare_ahead

    @property
    def registrar_works_ahead(self) -> bool:
        """Whether the registrar's per-frame work (VCR-Net's encoder) runs in :meth:`prepare`, so that a
        loop preparing ahead runs it beside :meth:`register`'s (``consult="every-frame"``)."""
        return self.consult == "every-frame" and self.prepare_ahead

    def reset(self, *, timestamps_assumed: bool = False) -> None:
        """Forget the previous frame and the pose: the next frame is the first (identity).

        ``timestamps_assumed``: the sequence's frame rate is a guess (no times file), so a motion the
        limits call implausible may only mean the guess is wrong: it is flagged, never replaced."""
        self._replace_implausible = not timestamps_assumed
        self._previous: PreparedFrame | None = None
        self._pose: Transform = np.eye(4)
        self._last_motion: Transform = np.eye(4)
        self._speeds: deque[float] = deque(maxlen=RECENT_PAIRS)
        self._estimated: Transform | None = None  # this pair's estimate before any replacement
        self._fits: deque[float] = deque(maxlen=self.doubt.window)
        self._doubted: deque[bool] = deque(maxlen=self.doubt.window)
        self.last_info = {}

    def prepare(self, frames: Sequence[tuple[Points, float]]) -> list[PreparedFrame]:
        """Per-frame work for ``(points, timestamp)`` frames; no state is read or changed."""
        prepared = [PreparedFrame(points, float(t)) for points, t in frames]
        if self.polish is not None:
            for frame in prepared:
                frame.polish = self.polish.prepare(frame.points)
        if self.consult == "every-frame":
            self._prepare_for_registrar(prepared)
        return prepared

    def register(self, frames: Sequence[PreparedFrame]) -> list[RegistrationResult | None]:
        """Each frame's motion from its predecessor (the last advanced frame for the first of them);
        None for a run's first frame, and for every frame with ``consult="on-doubt"`` (the estimate is
        asked for in :meth:`advance`, where a pair needs it)."""
        if self.consult == "on-doubt":
            return [None] * len(frames)
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
        previous = self._previous
        if previous is None:
            return self._first(frame)
        seconds = frame.timestamp - previous.timestamp
        motion, info = self._motion(frame, previous, result, seconds)
        estimated = motion if self._estimated is None else self._estimated
        self._speeds.append(float(np.linalg.norm(estimated[:3, 3])) / max(seconds, 1e-3))
        self._estimated = None
        # Re-orthonormalised at every step: a rotation error of the pose would otherwise grow from
        # chained float rounding, and kiss-icp (which takes poses from here) needs exact SE(3).
        self._pose = project_to_se3(self._pose @ motion)
        self._last_motion = motion
        self._previous = frame
        self.last_info = info
        return Step(self._pose.copy(), info)

    def _motion(
        self,
        frame: PreparedFrame,
        previous: PreparedFrame,
        result: RegistrationResult | None,
        seconds: float,
    ) -> tuple[Transform, dict[str, Any]]:
        """A frame's motion from its predecessor: the whole path of a frame, in order.

        1. Without a polish, the registrar's estimate, within the motion limits, is the motion.
        2. ``on-doubt``: the polish registers the frame from the motion prior; where :class:`DoubtRule`
           does not doubt that result, it is the motion and the registrar is not asked.
        3. Otherwise the registrar's estimate (asked for now where :meth:`register` did not), within
           the motion limits, is a start for the polish beside the prior's; the polish keeps the start
           that fits markedly better.
        4. A polished motion beyond the limits is undone: the estimate stands and the polish restarts.
        """
        if self.polish is None:
            assert result is not None, "register() gives every frame after the first an estimate"
            return self._checked(result, seconds)
        attempt: PriorAttempt | None = None
        reason: str | None = None
        if self.consult == "on-doubt":
            attempt = self.polish.from_prior(
                frame.polish, previous.polish, pose=self._pose, last_motion=self._last_motion
            )
            reason, not_asked = self._doubt(attempt, frame, previous, seconds)
            if reason is None:
                polished = self._finish(attempt, frame, previous, None)
                self._fits.append(attempt.fit)
                info = polished.info | {"prior_fit": attempt.fit, "global": not_asked}
                return polished.motion, _flag_unregistered(info)
        if result is None:
            self._prepare_for_registrar([f for f in (previous, frame) if f.registrar is None])
            result = self.registrar.register(frame.registrar, previous.registrar, None)
        coarse, info = self._checked(result, seconds)
        if attempt is not None:
            info |= {"prior_fit": attempt.fit, "global": reason}
        polished = self._finish(attempt, frame, previous, coarse)
        motion = self._kept(polished, coarse, frame, seconds, info)
        if attempt is not None and polished.fit is not None and not info.get("flagged"):
            self._fits.append(polished.fit)  # the accepted result: what later priors are held to
        return motion, info

    def _first(self, frame: PreparedFrame) -> Step:
        """A run's first frame: the identity, and the polish's map begun there."""
        self._previous = frame
        self.last_info = {}
        if self.polish is not None:
            self.polish.start(frame.polish)
            voxel = getattr(self.polish, "voxel_size", None)  # kiss-icp's map grid, chosen by now
            if voxel is not None:
                plane = bool(getattr(self.polish, "point_to_plane", False))
                engine = getattr(self.polish, "engine", None)
                self.last_info = {
                    "polish_voxel_m": voxel,
                    "polish_point_to_plane": plane,
                    "polish_engine": engine,
                }
        return Step(self._pose.copy(), dict(self.last_info))

    def _finish(
        self,
        attempt: PriorAttempt | None,
        frame: PreparedFrame,
        previous: PreparedFrame,
        coarse: Transform | None,
    ) -> PolishResult:
        assert self.polish is not None
        return self.polish.finish(
            attempt, frame.polish, previous.polish, coarse, pose=self._pose, last_motion=self._last_motion
        )

    def step(self, points: Points, timestamp: float = 0.0) -> Transform:
        """One frame at a time (the :class:`SequentialOdometry` interface); ``last_info`` says what happened."""
        (frame,) = self.prepare([(points, timestamp)])
        (result,) = self.register([frame])
        return self.advance(frame, result).pose

    def _doubt(
        self, attempt: PriorAttempt, frame: PreparedFrame, previous: PreparedFrame, seconds: float
    ) -> tuple[str | None, str]:
        """Why the prior's result is doubted (:class:`DoubtRule`), or None and why the registrar is
        not needed."""
        reason = self._doubt_about(attempt, seconds)
        confirmed = self._second_start_confirms(reason, attempt, frame, previous)
        if confirmed:
            reason = None
        self._doubted.append(reason is not None)  # the prior's own record: asking for the share below
        reason = reason or self._doubt_everywhere()  # does not count, so the share can fall again
        return reason, f"{NOT_NEEDED}: {SECOND_START_AGREES}" if confirmed else NOT_NEEDED

    def _doubt_about(self, attempt: PriorAttempt, seconds: float) -> str | None:
        if not self._fits:
            return "first pair"
        implausible = self._implausible(attempt.motion, seconds)
        if implausible is not None:
            return f"prior implausible: {implausible}"
        median = statistics.median(self._fits)
        if attempt.fit < self.doubt.ratio * median:
            return f"poor fit {attempt.fit:.2f} (median {median:.2f})"
        moved_m, turned_deg = attempt.correction
        if 0.0 < self.doubt.correction_m < moved_m or 0.0 < self.doubt.correction_deg < turned_deg:
            return f"{FAR_FROM_PRIOR}: {moved_m:.2f} m, {turned_deg:.1f} deg"
        return None

    def _second_start_confirms(
        self, reason: str | None, attempt: PriorAttempt, frame: PreparedFrame, previous: PreparedFrame
    ) -> bool:
        """Whether a result doubted only for lying far from the prior is confirmed (``second_start``):
        the polish from standing still, a start outside the prediction's basin, ends in the prediction's
        result, so two independent starts share one minimum."""
        if not (self.doubt.second_start and reason is not None and reason.startswith(FAR_FROM_PRIOR)):
            return False
        assert self.polish is not None
        if within_basin(self._last_motion, np.eye(4)):
            return False  # one start twice: it confirms nothing
        return within_basin(self.polish.from_rest(attempt, frame.polish, previous.polish), attempt.motion)

    def _doubt_everywhere(self) -> str | None:
        doubted, seen = sum(self._doubted), len(self._doubted)
        if 2 * seen >= self.doubt.window and doubted > self.doubt.share * seen:
            return f"most recent pairs in doubt ({doubted} of {seen})"
        return None

    def _checked(self, result: RegistrationResult, seconds: float) -> tuple[Transform, dict[str, Any]]:
        """The registrar's estimate, or the last motion where it failed or is beyond the limits (flagged)."""
        coarse = np.asarray(result.transform, dtype=np.float64)
        info: dict[str, Any] = {"fitness": result.fitness, "inlier_rmse": result.inlier_rmse, **result.info}
        failed = result.info.get("status") in FAILED_STATUSES
        replace = self._beyond_limits(coarse, seconds, info, "", failed=failed)
        if failed and not replace:
            info |= {"flagged": True, "reason": str(result.info["status"])}
        return (self._last_motion if replace or failed else coarse), info

    def _kept(
        self,
        polished: PolishResult,
        coarse: Transform,
        frame: PreparedFrame,
        seconds: float,
        info: dict[str, Any],
    ) -> Transform:
        """The polished motion, or the checked estimate where the polish left the motion limits
        (flagged; the polish restarts there)."""
        assert self.polish is not None
        change_m, change_deg = motion_difference(coarse, polished.motion)
        info |= polished.info | {"polish_change_m": change_m, "polish_change_deg": change_deg}
        _flag_unregistered(info)
        if not self._beyond_limits(polished.motion, seconds, info, "polish"):
            return polished.motion
        self.polish.restart(frame.polish, self._pose, coarse)
        self._fits.clear()
        return coarse

    def _beyond_limits(
        self, motion: Transform, seconds: float, info: dict[str, Any], what: str, *, failed: bool = False
    ) -> bool:
        """The motion limits, applied to an estimate (``what`` empty) or the polish's result: whether
        ``motion`` must be replaced, ``info`` flagged with why. At an assumed frame rate an implausible
        motion may only mean the guess is wrong: it is flagged and kept. Also keeps ``motion`` as the
        pair's measured speed (:meth:`_note_estimate`)."""
        self._note_estimate(motion, seconds, failed)
        problem = self._implausible(motion, seconds)
        if problem is None:
            return False
        label = f"{what}: " if what else ""
        if not self._replace_implausible:
            reason = f"{label}{problem} at the assumed frame rate; kept ({RATE_HINT})"
            info |= {"flagged": True, "reason": reason}
            return False
        info |= {"flagged": True, "reason": f"{what} diverged: {problem}" if what else problem}
        return True

    def _implausible(self, motion: Transform, seconds: float) -> str | None:
        """Why ``motion`` is beyond the motion limits, the recent pairs' speed included, or None."""
        return self.limits.violation(motion, seconds, self._recent_speed())

    def _prepare_for_registrar(self, frames: Sequence[PreparedFrame]) -> None:
        if not frames:
            return
        clouds = [frame.points for frame in frames]
        if isinstance(self.registrar, BatchRegistrar) and len(clouds) > 1:
            prepared = self.registrar.prepare_batch(clouds)
        else:
            prepared = [self.registrar.prepare(points) for points in clouds]
        for frame, registrar_frame in zip(frames, prepared, strict=True):
            frame.registrar = registrar_frame

    def _note_estimate(self, motion: Transform, seconds: float, failed: bool = False) -> None:
        """Keep ``motion`` as this pair's estimate for :meth:`_recent_speed`, unless the registration
        failed or the motion is beyond the speed and turn limits: that is no measurement of a speed
        (the pair's chained motion counts instead)."""
        measured = not failed and self.limits.violation(motion, seconds) is None
        self._estimated = motion if measured else None

    def _recent_speed(self) -> float | None:
        """The median speed the last :data:`RECENT_PAIRS` pairs were estimated at (before any was
        replaced: a run of estimates that agree on a new speed is believed), or None over fewer than
        three."""
        return statistics.median(self._speeds) if len(self._speeds) >= 3 else None

    def _guess(self) -> Transform:
        if self.initial_guess is InitialGuess.CONSTANT_VELOCITY:
            return self._last_motion
        return np.eye(4)
