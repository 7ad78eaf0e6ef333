"""One small interface for every pairwise registration method (baselines and VCR-Net alike).

``prepare`` holds the per-frame work (down-sampling, normals, features, a network's encoding) so the
odometry loop does it once per frame and reuses it for both pairs the frame belongs to.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import Points
from vcr_odom.geometry import Transform

DEGENERATE = "degenerate correspondences"
TOO_FEW_POINTS = "too few points"
FAILED_STATUSES = (DEGENERATE, TOO_FEW_POINTS)
"""``info["status"]`` values that mean the transform is not an estimate: odometry falls back and flags."""
MIN_REGISTRATION_POINTS = 10
"""Fewer (distinct, down-sampled) points than this do not determine a 6-DoF motion: one point fixes
three of the six, and a least-squares solve then returns whatever its rank-deficient system gives (with
kiss-icp, a different pose on every run). Such a frame is not registered but flagged ``too few points``."""


@dataclass
class RegistrationResult:
    """``transform`` is ``T_target_source``: it maps source points into the target frame."""

    transform: Transform
    fitness: float = float("nan")
    inlier_rmse: float = float("nan")
    info: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class Registrar(Protocol):
    """A pairwise method. ``needs_initial_guess`` is False for global methods (FPFH+RANSAC, VCR-Net)."""

    name: str
    needs_initial_guess: bool

    def prepare(self, points: Points) -> Any: ...

    def register(
        self, source: Any, target: Any, initial_guess: Transform | None = None
    ) -> RegistrationResult: ...


@runtime_checkable
class BatchRegistrar(Registrar, Protocol):
    """A registrar that can prepare several frames and register several pairs in one call.

    Why: on a GPU the network's cost is launch-bound at batch 1; the relative poses of an odometry are
    independent, so a chunk of frames is encoded and its pairs registered together (chaining and the
    polish stay sequential). ``batch_size`` is the chunk the odometry loop should hand over.
    """

    batch_size: int

    def prepare_batch(self, frames: Sequence[Points]) -> list[Any]: ...

    def register_batch(self, pairs: Sequence[tuple[Any, Any]]) -> list[RegistrationResult]: ...


def identity_guess(initial_guess: Transform | None) -> Transform:
    return np.eye(4) if initial_guess is None else np.asarray(initial_guess, dtype=np.float64)


@runtime_checkable
class SequentialOdometry(Protocol):
    """A method that keeps its own state across frames (kiss-icp's local map, for one).

    ``step`` takes the raw frame and returns the pose of that frame in the frame-0 LiDAR frame.
    """

    name: str

    def reset(self) -> None: ...

    def step(self, points: Points, timestamp: float) -> Transform: ...


@dataclass
class FinishedTrajectory:
    """A finishing method's final word: ``poses`` (``(n, 4, 4)``, frame 0 = identity) of the frames it
    stepped through, and ``summary``, what it did beyond odometry (loop closures), for ``metrics.json``."""

    poses: NDArray[np.float64]
    summary: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class FinishingOdometry(SequentialOdometry, Protocol):
    """A sequential method that revises its whole trajectory once the frames end: a SLAM system whose
    pose graph, optimised over its loop closures, moves poses that ``step`` already returned.

    ``finish(frame_indices)`` is called once after the last ``step`` (not after Ctrl-C: the online poses
    are then kept) with the sequence's indices of the frames stepped, so closures can name frames.
    """

    def finish(self, frame_indices: Sequence[int]) -> FinishedTrajectory: ...
