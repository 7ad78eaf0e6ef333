"""A test stand-in for a global registrar: the ground-truth motion of each consecutive pair, which a
test may replace for chosen pairs (a wrong estimate, a failure status, float32 noise)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from vcr_odom.registration.base import RegistrationResult

Tweak = Callable[[int, np.ndarray], RegistrationResult]


class ScriptedRegistrar:
    """Pair ``k`` (1-based, frame k-1 -> k) answers ``tweak(k, truth)``, or the truth when no tweak."""

    name = "scripted"
    needs_initial_guess = False

    def __init__(self, poses: np.ndarray, tweak: Tweak | None = None) -> None:
        self.poses = np.asarray(poses)
        self.tweak = tweak
        self.pair = 0

    def prepare(self, points: np.ndarray) -> int:
        return len(points)  # anything but None: None means "no previous frame yet"

    def register(
        self, source: int, target: int, initial_guess: np.ndarray | None = None
    ) -> RegistrationResult:
        self.pair += 1
        truth = np.linalg.inv(self.poses[self.pair - 1]) @ self.poses[self.pair]
        return self.tweak(self.pair, truth) if self.tweak is not None else RegistrationResult(truth)
