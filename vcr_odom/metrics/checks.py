"""Input checks and the one relative-pose product that every metric shares.

Errors name the argument (``DataError`` for data, ``ConfigError`` for options) so that the CLI can
show one line instead of a traceback.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vcr_odom.errors import ConfigError, DataError

ROTATION_TOLERANCE = 1e-3
"""Largest ``|R^T R - I|`` entry accepted as a rotation: loose enough for float32 estimates and
7-digit pose files, tight enough to refuse a scaled or sheared block that no angle describes."""


def as_poses(poses: ArrayLike, name: str) -> NDArray[np.float64]:
    """Validate one ``(M, 4, 4)`` pose array: finite, with rotation blocks that are rotations."""
    try:
        array = np.asarray(poses, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise DataError(f"{name}: could not read the poses as a float array ({error})") from error
    if array.ndim != 3 or array.shape[1:] != (4, 4):
        raise DataError(f"{name}: expected an (M, 4, 4) array of poses, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        bad = np.flatnonzero(~np.all(np.isfinite(array), axis=(1, 2)))
        raise DataError(f"{name}: {len(bad)} pose(s) contain NaN or inf (first at index {bad[0]})")
    rotations = array[:, :3, :3]
    deviation = np.abs(np.swapaxes(rotations, 1, 2) @ rotations - np.eye(3)).max(axis=(1, 2))
    improper = (deviation > ROTATION_TOLERANCE) | (np.linalg.det(rotations) <= 0)
    if np.any(improper):
        bad = np.flatnonzero(improper)
        raise DataError(
            f"{name}: {len(bad)} pose(s) have a rotation block that is not a rotation matrix "
            f"(first at index {bad[0]})"
        )
    return array


def check_pair(
    est: ArrayLike, gt: ArrayLike, minimum: int = 2, what: str = "poses"
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Validate an estimate/ground-truth pair: same length, at least ``minimum`` entries, finite."""
    est_array = as_poses(est, f"estimated {what}")
    gt_array = as_poses(gt, f"ground-truth {what}")
    if len(est_array) != len(gt_array):
        raise DataError(
            f"estimate has {len(est_array)} {what} but ground truth has {len(gt_array)}: "
            "they must match one to one"
        )
    if len(gt_array) < minimum:
        raise DataError(f"need at least {minimum} {what} to evaluate, got {len(gt_array)}")
    return est_array, gt_array


def positive(value: float, option: str) -> float:
    """A finite number > 0, else a ConfigError naming ``option``."""
    if not (isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value) and value > 0):
        raise ConfigError(f"{option} must be a positive number, got {value!r}")
    return float(value)


def positive_int(value: int, option: str) -> int:
    """An integer >= 1 (not a bool), else a ConfigError naming ``option``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"{option} must be a positive integer, got {value!r}")
    return int(value)


def relative(pose_a: NDArray[np.float64], pose_b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``inv(a) @ b`` with the general matrix inverse, as the devkit and kiss-icp compute it.

    KITTI pose files are printed to 7 significant digits, so their rotations are only nearly
    orthonormal; the closed-form ``geometry.invert`` (a transpose) would then leave false rotation in
    ``inv(a) @ a``, which the general inverse does not.
    """
    return np.linalg.solve(pose_a, pose_b)
