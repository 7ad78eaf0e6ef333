"""Per-pair relative-motion errors: the geodesic rotation and translation errors with a success rate,
and the Euler-angle figures of the paper's (DCP-style) tables."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vcr_odom.errors import DataError
from vcr_odom.geometry import euler_zyx, rotation_angle
from vcr_odom.jsonsafe import json_safe
from vcr_odom.metrics.checks import as_poses, check_pair, positive, positive_int, relative

EULER_AXES = ("yaw", "pitch", "roll")
XYZ_AXES = ("x", "y", "z")


def relative_motions(poses: ArrayLike, stride: int = 1) -> NDArray[np.float64]:
    """Relative transforms ``inv(P_i) P_{i+stride}`` for every i (overlapping pairs), ``(M - stride, 4, 4)``."""
    poses = as_poses(poses, "poses")
    stride = positive_int(stride, "stride")
    if len(poses) <= stride:
        raise DataError(f"need more than stride={stride} poses to form pairs, got {len(poses)}")
    return relative(poses[:-stride], poses[stride:])


def _rmse(values: NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def _mae(values: NDArray[np.float64]) -> float:
    return float(np.mean(np.abs(values)))


@dataclass
class DcpErrors:
    """The paper's (DCP-style) Table III figures: Euler z-y-x angle errors and per-component translation.

    Pooled figures are over all pairs and all three axes; the per-axis dictionaries break them down.
    """

    euler_mse_deg2: float
    euler_rmse_deg: float
    euler_mae_deg: float
    euler_rmse_deg_per_axis: dict[str, float]
    euler_mae_deg_per_axis: dict[str, float]
    trans_mse_m2: float
    trans_rmse_m: float
    trans_mae_m: float
    trans_rmse_m_per_axis: dict[str, float]
    trans_mae_m_per_axis: dict[str, float]


@dataclass
class PairErrors:
    """Per-pair relative-motion errors: geodesic rotation (deg), translation distance (m), success rate."""

    num_pairs: int
    stride: int
    rot_rmse_deg: float
    rot_mae_deg: float
    trans_rmse_m: float
    trans_mae_m: float
    success_rate: float  # fraction of pairs under both thresholds
    success_rot_threshold_deg: float
    success_trans_threshold_m: float
    dcp: DcpErrors
    # Per-pair arrays for plotting (left out of to_dict unless asked for).
    rot_errors_deg: NDArray[np.float64] = field(repr=False)
    trans_errors_m: NDArray[np.float64] = field(repr=False)
    euler_errors_deg: NDArray[np.float64] = field(repr=False)  # (N, 3) yaw, pitch, roll
    trans_component_errors_m: NDArray[np.float64] = field(repr=False)  # (N, 3) x, y, z
    success: NDArray[np.bool_] = field(repr=False)

    _ARRAYS = ("rot_errors_deg", "trans_errors_m", "euler_errors_deg", "trans_component_errors_m", "success")

    def to_dict(self, include_arrays: bool = False) -> dict[str, Any]:
        result = {
            key: value for key, value in self.__dict__.items() if key not in self._ARRAYS and key != "dcp"
        }
        result["dcp"] = asdict(self.dcp)
        if include_arrays:
            result.update({key: getattr(self, key) for key in self._ARRAYS})
        return json_safe(result)


def pair_errors(
    est_relative: ArrayLike,
    gt_relative: ArrayLike,
    *,
    rot_threshold_deg: float = 2.0,
    trans_threshold_m: float = 0.5,
    stride: int = 1,
) -> PairErrors:
    """Errors of N estimated relative transforms against the true ones (``(N, 4, 4)`` each).

    Rotation error is the geodesic angle of ``inv(R_gt) R_est``; translation error is
    ``|t_est - t_gt|``. A pair succeeds when both are strictly under the thresholds (2 deg and
    0.5 m by default). Euler errors are differences of intrinsic Z-Y-X angles wrapped to
    [-180, 180) so that a yaw near +-180 deg does not count as a 360 deg error. ``stride`` is
    recorded only, to label the result.
    """
    est, gt = check_pair(est_relative, gt_relative, minimum=1, what="relative transforms")
    rot_threshold_deg = positive(rot_threshold_deg, "rot_threshold_deg")
    trans_threshold_m = positive(trans_threshold_m, "trans_threshold_m")
    stride = positive_int(stride, "stride")

    rot_deg = np.degrees(np.atleast_1d(rotation_angle(np.linalg.solve(gt[:, :3, :3], est[:, :3, :3]))))
    trans_components = est[:, :3, 3] - gt[:, :3, 3]
    trans_m = np.linalg.norm(trans_components, axis=1)
    euler_deg = np.degrees(euler_zyx(est) - euler_zyx(gt))
    euler_deg = (euler_deg + 180.0) % 360.0 - 180.0
    success = (rot_deg < rot_threshold_deg) & (trans_m < trans_threshold_m)

    dcp = DcpErrors(
        euler_mse_deg2=float(np.mean(np.square(euler_deg))),
        euler_rmse_deg=_rmse(euler_deg),
        euler_mae_deg=_mae(euler_deg),
        euler_rmse_deg_per_axis={axis: _rmse(euler_deg[:, k]) for k, axis in enumerate(EULER_AXES)},
        euler_mae_deg_per_axis={axis: _mae(euler_deg[:, k]) for k, axis in enumerate(EULER_AXES)},
        trans_mse_m2=float(np.mean(np.square(trans_components))),
        trans_rmse_m=_rmse(trans_components),
        trans_mae_m=_mae(trans_components),
        trans_rmse_m_per_axis={axis: _rmse(trans_components[:, k]) for k, axis in enumerate(XYZ_AXES)},
        trans_mae_m_per_axis={axis: _mae(trans_components[:, k]) for k, axis in enumerate(XYZ_AXES)},
    )
    return PairErrors(
        num_pairs=len(est),
        stride=stride,
        rot_rmse_deg=_rmse(rot_deg),
        rot_mae_deg=_mae(rot_deg),
        trans_rmse_m=_rmse(trans_m),
        trans_mae_m=_mae(trans_m),
        success_rate=float(np.mean(success)),
        success_rot_threshold_deg=rot_threshold_deg,
        success_trans_threshold_m=trans_threshold_m,
        dcp=dcp,
        rot_errors_deg=rot_deg,
        trans_errors_m=trans_m,
        euler_errors_deg=euler_deg,
        trans_component_errors_m=trans_components,
        success=success,
    )


def trajectory_pair_errors(
    est: ArrayLike,
    gt: ArrayLike,
    *,
    stride: int = 1,
    rot_threshold_deg: float = 2.0,
    trans_threshold_m: float = 0.5,
) -> PairErrors:
    """:func:`pair_errors` on the pairs (i, i + stride) of two trajectories."""
    est, gt = check_pair(est, gt)
    return pair_errors(
        relative_motions(est, stride),
        relative_motions(gt, stride),
        rot_threshold_deg=rot_threshold_deg,
        trans_threshold_m=trans_threshold_m,
        stride=stride,
    )
