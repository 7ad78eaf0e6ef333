"""How much of an odometry's ATE its per-step rotation errors make, and how much its per-step
translation errors: each step's error against the truth split in two, each part chained alone
along the truth's steps. Used by ``loop_replay.py replay --truth-loops``.

Why it matters for loop closure: a loop measures where the odometry has carried the vehicle by the
time it comes back, and a heading error made on the way turns everything after it, so the graph
finds it and undoes it nearly whole; a translation error made between two revisits leaves nothing a
loop can see except its sum. ``loop_bound.py`` measures the same split on odometry made noisy on
purpose, with every loop perfect.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from vcr_odom.geometry import invert
from vcr_odom.metrics.evo_errors import ate_rpe


@dataclass(frozen=True)
class ErrorSplit:
    """SE(3)-aligned ATEs [m] of the truth with only the odometry's rotation errors, and with only
    its translation errors, per step; and the odometry's scale error (its steps' error along the true
    steps over their length, least squares: -0.03 measures every step 3 % short), which a route that
    comes back keeps coming back with, so that no loop sees it."""

    rotation_only_ate_m: float
    translation_only_ate_m: float
    scale_error: float

    @property
    def rotation_share(self) -> float:
        """The rotation-only ATE's share of the two (0: all translation, 1: all rotation)."""
        total = self.rotation_only_ate_m + self.translation_only_ate_m
        return self.rotation_only_ate_m / total if total > 0 else float("nan")


def error_split(odometry: ArrayLike, truth: ArrayLike) -> ErrorSplit:
    """The split of ``odometry``'s error (N x 4 x 4 poses) against ``truth`` (the same frames).

    A step's error is ``E = (G_k^-1 G_k+1)^-1 (O_k^-1 O_k+1)``, in the vehicle's frame at the step's
    start; its rotation and its translation are each applied after the truth's step."""
    odometry, truth = np.asarray(odometry, dtype=float), np.asarray(truth, dtype=float)
    if odometry.shape != truth.shape or odometry.ndim != 3 or odometry.shape[1:] != (4, 4):
        raise ValueError(
            f"expected two N x 4 x 4 pose arrays of one shape, got {odometry.shape} and {truth.shape}"
        )
    rotation_only, translation_only = [truth[0]], [truth[0]]
    along, squared = 0.0, 0.0
    for k in range(len(truth) - 1):
        true_step = invert(truth[k]) @ truth[k + 1]
        measured = invert(odometry[k]) @ odometry[k + 1]
        along += float((measured[:3, 3] - true_step[:3, 3]) @ true_step[:3, 3])
        squared += float(true_step[:3, 3] @ true_step[:3, 3])
        error = invert(true_step) @ measured
        turned, moved = np.eye(4), np.eye(4)
        turned[:3, :3], moved[:3, 3] = error[:3, :3], error[:3, 3]
        rotation_only.append(rotation_only[-1] @ true_step @ turned)
        translation_only.append(translation_only[-1] @ true_step @ moved)
    return ErrorSplit(
        rotation_only_ate_m=ate_rpe(np.array(rotation_only), truth, alignment="se3").ate_trans_rmse_m,
        translation_only_ate_m=ate_rpe(np.array(translation_only), truth, alignment="se3").ate_trans_rmse_m,
        scale_error=along / squared if squared > 0 else float("nan"),
    )
