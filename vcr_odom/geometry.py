"""SE(3) helpers shared by every stage.

Poses are 4x4 float64 homogeneous matrices; a registration returns ``T_target_source``.
Kept in one place so that frame conventions are decided once.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Transform = NDArray[np.float64]


def make_transform(rotation: ArrayLike, translation: ArrayLike) -> Transform:
    """Build a 4x4 transform from a 3x3 rotation and a 3-vector."""
    transform = np.eye(4)
    transform[:3, :3] = np.asarray(rotation, dtype=np.float64)
    transform[:3, 3] = np.asarray(translation, dtype=np.float64)
    return transform


def invert(transform: ArrayLike) -> Transform:
    """Closed-form inverse of rigid transforms, ``(..., 4, 4)``; exact where ``np.linalg.inv`` is not."""
    transform = np.asarray(transform, dtype=np.float64)
    rotation_t = np.swapaxes(transform[..., :3, :3], -1, -2)
    inverse = np.zeros_like(transform)
    inverse[..., :3, :3] = rotation_t
    inverse[..., :3, 3] = -np.einsum("...ij,...j->...i", rotation_t, transform[..., :3, 3])
    inverse[..., 3, 3] = 1.0
    return inverse


def relative(pose_a: ArrayLike, pose_b: ArrayLike) -> Transform:
    """Motion from pose a to pose b, ``inv(a) @ b`` (broadcasts over leading axes)."""
    return invert(pose_a) @ np.asarray(pose_b, dtype=np.float64)


def transform_points(transform: ArrayLike, points: ArrayLike) -> NDArray[np.float64]:
    """Apply a transform to the xyz columns of ``(N, >=3)`` points; extra columns are dropped."""
    transform = np.asarray(transform, dtype=np.float64)
    xyz = np.asarray(points, dtype=np.float64)[:, :3]
    return xyz @ transform[:3, :3].T + transform[:3, 3]


def rotation_angle(rotation: ArrayLike) -> NDArray[np.float64] | float:
    """Geodesic angle (radians) of rotation matrices ``(..., 3, 3)`` or transforms ``(..., 4, 4)``."""
    matrix = np.asarray(rotation, dtype=np.float64)[..., :3, :3]
    cos = (np.trace(matrix, axis1=-2, axis2=-1) - 1.0) / 2.0
    angle = np.arccos(np.clip(cos, -1.0, 1.0))
    return float(angle) if np.ndim(angle) == 0 else angle


def rotation_from_euler_zyx(yaw: float, pitch: float, roll: float) -> NDArray[np.float64]:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)``, radians (the intrinsic z-y-x convention)."""
    cz, sz = np.cos(yaw), np.sin(yaw)
    cy, sy = np.cos(pitch), np.sin(pitch)
    cx, sx = np.cos(roll), np.sin(roll)
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    return rz @ ry @ rx


def euler_zyx(rotation: ArrayLike) -> NDArray[np.float64]:
    """Inverse of :func:`rotation_from_euler_zyx`: ``(..., 3)`` array of (yaw, pitch, roll) in radians.

    This is scipy's ``as_euler('zyx')``, the convention of the paper's (DCP-style) tables.
    """
    matrix = np.asarray(rotation, dtype=np.float64)[..., :3, :3]
    yaw = np.arctan2(matrix[..., 1, 0], matrix[..., 0, 0])
    pitch = np.arcsin(np.clip(-matrix[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(matrix[..., 2, 1], matrix[..., 2, 2])
    return np.stack([yaw, pitch, roll], axis=-1)


def weighted_kabsch(source: ArrayLike, target: ArrayLike, weights: ArrayLike | None = None) -> Transform:
    """Least-squares rigid transform mapping ``source`` onto ``target`` (reflection-safe)."""
    src = np.asarray(source, dtype=np.float64)[:, :3]
    tgt = np.asarray(target, dtype=np.float64)[:, :3]
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    if src.shape != tgt.shape or len(w) != len(src) or len(src) < 3:
        raise ValueError("weighted_kabsch needs matching (N>=3, 3) point sets and N weights")
    w = w / w.sum()
    src_mean = w @ src
    tgt_mean = w @ tgt
    covariance = (src - src_mean).T @ ((tgt - tgt_mean) * w[:, None])
    u, _, vt = np.linalg.svd(covariance)
    fix = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rotation = vt.T @ fix @ u.T
    return make_transform(rotation, tgt_mean - rotation @ src_mean)


def lidar_to_camera_poses(poses_lidar: ArrayLike, tr_velo_to_cam: ArrayLike) -> Transform:
    """``T_cam = Tr @ T_lidar @ inv(Tr)``: the frame KITTI's ``poses/XX.txt`` files use."""
    tr = np.asarray(tr_velo_to_cam, dtype=np.float64)
    return tr @ np.asarray(poses_lidar, dtype=np.float64) @ invert(tr)


def camera_to_lidar_poses(poses_camera: ArrayLike, tr_velo_to_cam: ArrayLike) -> Transform:
    """``T_lidar = inv(Tr) @ T_cam @ Tr`` (DESIGN: internal trajectories are in the LiDAR frame)."""
    tr = np.asarray(tr_velo_to_cam, dtype=np.float64)
    return invert(tr) @ np.asarray(poses_camera, dtype=np.float64) @ tr


def normalise_to_first(poses: ArrayLike) -> Transform:
    """Re-anchor a trajectory so that frame 0 is the identity."""
    poses = np.asarray(poses, dtype=np.float64)
    return invert(poses[0])[None] @ poses


def project_to_se3(poses: ArrayLike) -> Transform:
    """Nearest proper rotations (SVD) for ``(..., 4, 4)`` poses, bottom row reset.

    KITTI pose files are printed to 7 digits, so their rotations are orthonormal only to ~2e-7; left
    as they are, the transpose-inverse of :func:`invert` shows up to 0.04 deg of false rotation, and
    evo rejects them as invalid SO(3).
    """
    poses = np.array(poses, dtype=np.float64)
    u, _, vt = np.linalg.svd(poses[..., :3, :3])
    fix = np.ones((*poses.shape[:-2], 3))
    fix[..., 2] = np.sign(np.linalg.det(u @ vt))
    poses[..., :3, :3] = (u * fix[..., None, :]) @ vt
    poses[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    return poses
