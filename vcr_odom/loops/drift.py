"""How far the odometry may have drifted between two places: what a loop must agree with.

Why a bound that grows with the path between the two visits: odometry error accumulates with the
distance driven, so a loop between frames 500 m apart along the path may correct metres where one
between frames 30 m apart may correct decimetres. A false closure between two look-alike places
(a street of identical blocks) asks for a correction of a whole block: it is rejected here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from vcr_odom.geometry import invert


@dataclass(frozen=True)
class DriftModel:
    """Bounds on the odometry's error after ``path_m`` metres and ``frames`` registrations:
    ``floor + rate * max(path, frames * path_per_frame_floor)``.

    Translation: about three times the default odometry's drift on the synthetic drives and the
    KITTI sample (0.5-1 % of the distance): room for sensors it does worse on, and far below the
    offset of a look-alike place one block (30 m or more) away. The error grows with each
    registration, not with each metre: a car moves ~1 m a frame, a walker at 10 Hz 0.13 m, and a
    handheld Avia walk's odometry drifted 0.6-0.7 cm a frame (5 % of its path) where the cars' drift
    0.01-0.5 cm a frame. So a frame counts as at least a third of a metre of path (1 cm of drift a
    frame at 3 %), here and in the pose graph's odometry sigmas (:meth:`step_sigmas`), which changes
    nothing where a frame covers that much or more (cars, 2 Hz walks; tuned on the walk above,
    docs/benchmarks.md, "Loops of a walk at 10 Hz"). Heading: 10 deg / 100 m, a
    handheld scanner's drift, not a car's (0.3-0.7 deg / 100 m): no look-alike differs in heading
    only, and the three tuning walks (OS0, ~105 m loops) with their odometry turned 10 deg per 100 m
    (ATE 0.65-0.68 m, near the team's real OS0 walk's) kept none of their loops at 3 deg / 100 m
    (``benchmarks/loop_drift.py``; docs/benchmarks.md, "Loops under odometry drift"). A heading
    error also grows with each turn the odometry measures, as a translation error does with each
    registration: plus :attr:`rotation_per_turned` of the angle the sensor turned between the two
    visits (each frame's rotation, summed). A handheld walk round a ~55 m courtyard turns 700-900 deg
    in one lap (the lap and the looks about), and its odometry's heading came back 16-22 deg off
    (2-3 %; a car turns 30-60 deg per 100 m). At most :attr:`rotation_cap_deg`: the network
    registers within +-30 deg of the odometry's heading, and a crossing's or a symmetric room's wrong
    fits are turned 90 deg.
    """

    translation_rate: float = 0.03
    path_per_frame_floor_m: float = 1 / 3
    rotation_deg_per_m: float = 0.1
    translation_floor_m: float = 1.5
    rotation_floor_deg: float = 5.0
    rotation_cap_deg: float = 30.0
    rotation_per_turned: float = 0.02
    step_sigma_rate: float = 0.01
    step_sigma_deg_per_m: float = 0.01
    step_sigma_floor_m: float = 0.02
    step_sigma_floor_deg: float = 0.1

    def translation_bound(self, path_m: float, frames: int = 0) -> float:
        counted = max(path_m, frames * self.path_per_frame_floor_m)
        return self.translation_floor_m + self.translation_rate * counted

    def rotation_bound_deg(self, path_m: float, turned_deg: float = 0.0) -> float:
        grown = self.rotation_deg_per_m * path_m + self.rotation_per_turned * turned_deg
        return min(self.rotation_cap_deg, self.rotation_floor_deg + grown)

    def step_sigmas(self, step_m: float, frames: int = 0) -> tuple[float, float]:
        """One odometry edge's standard deviations (m, rad) over ``step_m`` metres and ``frames``
        registrations (each counted as :attr:`path_per_frame_floor_m` of path at least, as in the
        bound): the pose graph's weight of the odometry against the loops. The angle turned is left
        out here: with it (a tenth of the bound's share), the graph kept a right loop of walk 881 it
        now drops, and a false one (2.3 m along a corridor) of indoor walk 902 drifted 15 deg per
        100 m."""
        counted = max(step_m, frames * self.path_per_frame_floor_m)
        sigma_t = self.step_sigma_floor_m + self.step_sigma_rate * counted
        sigma_r = math.radians(self.step_sigma_floor_deg + self.step_sigma_deg_per_m * counted)
        return sigma_t, sigma_r

    def chain_sigmas(
        self, poses: NDArray[np.float64], frames: Sequence[int]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`step_sigmas` of each edge of a chain of poses (m, rad; one fewer than the poses),
        ``frames`` the registrations along each: what the pose graph weighs its odometry by, and what
        the loops' cycles (:mod:`~vcr_odom.loops.cycles`) measure it against."""
        sigmas = [
            self.step_sigmas(float(np.linalg.norm((invert(a) @ b)[:3, 3])), count)
            for a, b, count in zip(poses[:-1], poses[1:], frames, strict=True)
        ]
        array = np.array(sigmas, dtype=np.float64).reshape(-1, 2)
        return array[:, 0], array[:, 1]
