"""KITTI devkit drift (``evaluate_odometry.cpp``) and the end-point error every sequence gets.

The drift is our own implementation of the devkit because ``kiss_icp.metrics.sequence_error`` only
returns the two averages at the fixed 100..800 m lengths, while the report needs the per-length
breakdown, other lengths for short sequences, and the segment count; the tests cross-check it against
kiss-icp's port.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vcr_odom.errors import ConfigError
from vcr_odom.geometry import rotation_angle
from vcr_odom.jsonsafe import json_safe
from vcr_odom.metrics.checks import check_pair, positive, positive_int, relative

KITTI_SEGMENT_LENGTHS_M: tuple[float, ...] = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
"""The devkit's segment lengths (m): the KITTI odometry benchmark's definition."""
KITTI_STEP_FRAMES = 10
"""The devkit starts a segment every 10 frames (one second at 10 Hz)."""


def trajectory_distances(poses: ArrayLike) -> NDArray[np.float64]:
    """Cumulative path length (m) at each pose, summed exactly as the devkit does (left to right)."""
    poses = np.asarray(poses, dtype=np.float64)
    delta = poses[1:, :3, 3] - poses[:-1, :3, 3]
    steps = np.sqrt(delta[:, 0] * delta[:, 0] + delta[:, 1] * delta[:, 1] + delta[:, 2] * delta[:, 2])
    return np.concatenate([[0.0], np.cumsum(steps)])


def short_segment_lengths(path_length_m: float, count: int = 8) -> tuple[float, ...]:
    """Segment lengths for a path too short for 100 m segments: ``unit * (1..count)``.

    ``unit`` is the largest 1-2-5 number with ``count * unit <= path length`` (a 50 m path gets
    5, 10, ..., 40 m; a 99 m path 10, ..., 80 m), so the table keeps the devkit's shape (eight
    lengths, the longest at most the path) at a smaller scale, with round numbers a reader can trust.
    """
    if not path_length_m > 0:
        return ()
    target = path_length_m / count
    exponent = math.floor(math.log10(target))
    unit = 0.0
    for power in (exponent - 1, exponent):
        for mantissa in (1.0, 2.0, 5.0):
            candidate = mantissa * 10.0**power
            if candidate <= target * (1 + 1e-12):
                unit = candidate
    return tuple(round(unit * k, 10) for k in range(1, count + 1))


@dataclass
class DriftAtLength:
    """Devkit drift of the segments of one length."""

    length_m: float
    num_segments: int
    t_rel_percent: float  # NaN when the path has no segment of this length
    r_rel_deg_per_100m: float


@dataclass
class DriftResult:
    """KITTI devkit drift: mean over *all* segments of all lengths, as the devkit and kiss-icp average."""

    t_rel_percent: float
    r_rel_deg_per_100m: float
    num_segments: int
    segment_lengths_m: tuple[float, ...]
    step_frames: int
    path_length_m: float
    short_sequence: bool
    label: str
    per_length: list[DriftAtLength] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return json_safe(asdict(self))


def kitti_drift(
    est: ArrayLike,
    gt: ArrayLike,
    *,
    segment_lengths_m: Sequence[float] | None = None,
    step_frames: int = KITTI_STEP_FRAMES,
) -> DriftResult:
    """KITTI devkit relative drift, with the per-length breakdown the devkit plots.

    For every start frame (every ``step_frames``) and length L, the segment ends at the first frame
    whose ground-truth path distance exceeds start + L; its error is
    ``E = inv(inv(est_s) est_e) @ inv(gt_s) gt_e``, ``t_err = |t_E| / L`` and
    ``r_err = angle(R_E) / L``, the geodesic angle the devkit takes as ``acos((trace(R_E) - 1) / 2)``
    (dividing by the nominal L, as the devkit does, so a straight-line scale error of 1 % with 1 m
    steps reads 1 % * (L + 1) / L).

    ``segment_lengths_m=None`` uses 100..800 m, or, when the path is too short for a single 100 m
    segment, :func:`short_segment_lengths`, flagged ``short_sequence`` and named in ``label``.
    """
    est, gt = check_pair(est, gt)
    step_frames = positive_int(step_frames, "step_frames")
    dist = trajectory_distances(gt)
    path_length_m = float(dist[-1])

    short = False
    if segment_lengths_m is None:
        lengths = KITTI_SEGMENT_LENGTHS_M
        # The devkit needs dist > start + L, so no 100 m segment exists unless the path exceeds 100 m.
        if not path_length_m > KITTI_SEGMENT_LENGTHS_M[0]:
            lengths = short_segment_lengths(path_length_m)
            short = True
    else:
        lengths = tuple(positive(length, "segment_lengths_m") for length in segment_lengths_m)
        if not lengths:
            raise ConfigError("segment_lengths_m must name at least one length")

    first = np.arange(0, len(gt), step_frames)
    t_errs: list[NDArray[np.float64]] = []
    r_errs: list[NDArray[np.float64]] = []
    per_length: list[DriftAtLength] = []
    for length in lengths:
        # searchsorted 'right' = the first index whose distance is strictly greater (the devkit's test).
        last = np.searchsorted(dist, dist[first] + length, side="right")
        valid = last < len(gt)
        starts, ends = first[valid], last[valid]
        delta_gt = relative(gt[starts], gt[ends])
        delta_est = relative(est[starts], est[ends])
        error = relative(delta_est, delta_gt)
        t_err = np.linalg.norm(error[:, :3, 3], axis=1) / length
        r_err = np.atleast_1d(rotation_angle(error)) / length if len(error) else np.zeros(0)
        t_errs.append(t_err)
        r_errs.append(r_err)
        per_length.append(
            DriftAtLength(
                length_m=float(length),
                num_segments=len(t_err),
                t_rel_percent=float(100.0 * t_err.mean()) if len(t_err) else math.nan,
                r_rel_deg_per_100m=float(np.degrees(r_err.mean()) * 100.0) if len(r_err) else math.nan,
            )
        )
    all_t = np.concatenate(t_errs) if t_errs else np.zeros(0)
    all_r = np.concatenate(r_errs) if r_errs else np.zeros(0)
    count = len(all_t)

    lengths_text = ", ".join(f"{length:g}" for length in lengths)
    if short:
        label = (
            f"short sequence ({path_length_m:.1f} m path, under the KITTI 100 m minimum): "
            f"drift over segments of {lengths_text} m, not comparable with KITTI figures"
        )
    elif segment_lengths_m is None:
        label = "KITTI devkit drift over segments of 100-800 m"
    else:
        label = f"devkit-style drift over segments of {lengths_text} m"
    if count == 0:
        label += f" (no segment fits the {path_length_m:.1f} m path)"

    return DriftResult(
        t_rel_percent=float(100.0 * all_t.mean()) if count else math.nan,
        r_rel_deg_per_100m=float(np.degrees(all_r.mean()) * 100.0) if count else math.nan,
        num_segments=count,
        segment_lengths_m=tuple(float(length) for length in lengths),
        step_frames=step_frames,
        path_length_m=path_length_m,
        short_sequence=short,
        label=label,
        per_length=per_length,
    )


@dataclass
class EndpointDrift:
    """Error of the final pose relative to the first: the figure every sequence length gets."""

    trans_error_m: float
    trans_error_percent: float  # of the ground-truth path length; NaN for a path of length 0
    rot_error_deg: float
    path_length_m: float

    def to_dict(self) -> dict[str, Any]:
        return json_safe(asdict(self))


def endpoint_drift(est: ArrayLike, gt: ArrayLike) -> EndpointDrift:
    """Devkit-style error of the whole run, first frame to last: ``|t_E|`` in m and % of path, angle(R_E).

    ``|t_E|`` equals the distance between the estimated and true final positions seen from frame 0.
    """
    est, gt = check_pair(est, gt)
    error = relative(relative(est[0], est[-1]), relative(gt[0], gt[-1]))
    trans_m = float(np.linalg.norm(error[:3, 3]))
    path_length_m = float(trajectory_distances(gt)[-1])
    return EndpointDrift(
        trans_error_m=trans_m,
        trans_error_percent=100.0 * trans_m / path_length_m if path_length_m > 0 else math.nan,
        rot_error_deg=math.degrees(rotation_angle(error)),
        path_length_m=path_length_m,
    )
