"""The camera/LiDAR calibration synthetic sequences carry: KITTI's own, so that tools written for
KITTI (camera-frame pose files, ``calib.txt``) read them unchanged."""

from __future__ import annotations

from numpy.typing import ArrayLike

from vcr_odom.geometry import project_to_se3

# KITTI odometry calibration of sequences 00-02 (the rig the sensor model imitates).
KITTI_P0 = [7.188560e02, 0.0, 6.071928e02, 0.0, 0.0, 7.188560e02, 1.852157e02, 0.0, 0.0, 0.0, 1.0, 0.0]
KITTI_P1 = [
    7.188560e02,
    0.0,
    6.071928e02,
    -3.861448e02,
    0.0,
    7.188560e02,
    1.852157e02,
    0.0,
    0.0,
    0.0,
    1.0,
    0.0,
]
KITTI_P2 = [
    7.188560e02, 0.0, 6.071928e02, 4.538225e01, 0.0, 7.188560e02, 1.852157e02, -1.130887e-01,
    0.0, 0.0, 1.0, 3.779761e-03,
]  # fmt: skip
KITTI_P3 = [
    7.188560e02, 0.0, 6.071928e02, -3.372877e02, 0.0, 7.188560e02, 1.852157e02, 2.369057e00,
    0.0, 0.0, 1.0, 4.915215e-03,
]  # fmt: skip
KITTI_TR = project_to_se3(
    [
        [4.276802385584e-04, -9.999672484946e-01, -8.084491683471e-03, -1.198459927713e-02],
        [-7.210626507497e-03, 8.081198471645e-03, -9.999413164504e-01, -5.403984729748e-02],
        [9.999738645903e-01, 4.859485810390e-04, -7.206933692422e-03, -2.921968648686e-01],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
"""KITTI's velodyne -> left camera transform ``Tr``: x forward/z up into z forward/y down; made exactly
rigid (a ~1e-7 change, as the KITTI loader does) so that camera <-> LiDAR pose conversions round-trip."""


def kitti_calib() -> dict[str, ArrayLike]:
    """``calib.txt`` entries of KITTI's sequences 00-02 (the projections are unused but expected)."""
    return {"P0": KITTI_P0, "P1": KITTI_P1, "P2": KITTI_P2, "P3": KITTI_P3, "Tr": KITTI_TR}
