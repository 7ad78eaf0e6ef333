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
    144 km/h; 90 deg/s is a sharp urban turn taken at speed.
    """

    max_speed_m_s: float = Field(default=40.0, gt=0)
    max_turn_rate_deg_s: float = Field(default=90.0, gt=0)

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
