"""What a vehicle can do between two scans, and where a local method starts."""

from __future__ import annotations

from enum import StrEnum

import numpy as np
from pydantic import Field

from vcr_odom.geometry import Transform, rotation_angle
from vcr_odom.settings import Settings


class InitialGuess(StrEnum):
    """Where a local method starts: the identity (the paper's ICP baseline) or the last motion."""

    IDENTITY = "identity"
    CONSTANT_VELOCITY = "constant-velocity"


class MotionLimits(Settings):
    """An estimate beyond these is a failed registration, not a motion.

    Limits scale with the time between the frames, so strided runs keep them meaningful. 40 m/s is
    144 km/h; 90 deg/s is a sharp urban turn taken at speed. A motion's speed also may not depart from
    the recent estimates' (``recent_speed``) by more than ``max_acceleration_m_s2`` allows over the
    pair, plus ``step_noise_m`` (the estimates' own error): a scan matcher sliding along a corridor
    jumps from a walk to 24 m/s in one pair, under the speed limit, and the constant-velocity prior
    then carries the slide on.
    """

    max_speed_m_s: float = Field(default=40.0, gt=0)
    max_turn_rate_deg_s: float = Field(default=90.0, gt=0)
    max_acceleration_m_s2: float = Field(default=20.0, gt=0)
    step_noise_m: float = Field(default=0.75, ge=0)

    def violation(self, motion: Transform, seconds: float, recent_speed: float | None = None) -> str | None:
        """Why ``motion`` is implausible over ``seconds``, or None when it is plausible; ``recent_speed``:
        what the estimates before it agree on (m/s), where there are enough of them."""
        seconds = max(seconds, 1e-3)
        if not np.all(np.isfinite(motion)):
            return "non-finite estimate"
        distance = float(np.linalg.norm(motion[:3, 3]))
        if distance > self.max_speed_m_s * seconds:
            return f"moved {distance:.1f} m in {seconds:.2f} s (limit {self.max_speed_m_s:g} m/s)"
        angle = float(np.degrees(rotation_angle(motion)))
        if angle > self.max_turn_rate_deg_s * seconds:
            return f"turned {angle:.1f} deg in {seconds:.2f} s (limit {self.max_turn_rate_deg_s:g} deg/s)"
        if recent_speed is not None:
            change = abs(distance - recent_speed * seconds)
            allowed = self.step_noise_m + self.max_acceleration_m_s2 * seconds**2
            if change > allowed:
                return (
                    f"moved {distance:.2f} m in {seconds:.2f} s where the recent pairs moved "
                    f"{recent_speed:.1f} m/s ({change:.2f} m apart, limit {allowed:.2f} m)"
                )
        return None
