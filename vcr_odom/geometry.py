"""SE(3) helpers shared by every stage.

Poses are 4x4 float64 homogeneous matrices; a registration returns ``T_target_source``.
Kept in one place so that frame conventions are decided once.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

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
    """Geodesic angle (radians, in [0, pi]) of rotation matrices ``(..., 3, 3)`` or transforms ``(..., 4, 4)``.

    scipy goes through the quaternion, which stays accurate near 0 and 180 degrees where
    ``arccos((trace - 1) / 2)`` loses half its digits.
    """
    matrix = np.asarray(rotation, dtype=np.float64)[..., :3, :3]
    angle = Rotation.from_matrix(matrix).magnitude()
    return float(angle) if np.ndim(angle) == 0 else angle


def motion_difference(a: ArrayLike, b: ArrayLike) -> tuple[float, float]:
    """Translation (m) and rotation (deg) between two motions (or poses): of ``inv(a) @ b``."""
    delta = invert(np.asarray(a, dtype=np.float64)) @ np.asarray(b, dtype=np.float64)
    return float(np.linalg.norm(delta[:3, 3])), float(np.degrees(rotation_angle(delta)))


def rotation_from_euler_zyx(yaw: float, pitch: float, roll: float) -> NDArray[np.float64]:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)``, radians: intrinsic Z-Y-X (scipy's ``"ZYX"``), the vehicle
    convention (turn, then nose up/down, then bank)."""
    return Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()


def euler_zyx(rotation: ArrayLike) -> NDArray[np.float64]:
    """Inverse of :func:`rotation_from_euler_zyx`: ``(..., 3)`` array of (yaw, pitch, roll) in radians.

    scipy's ``as_euler("ZYX")`` (intrinsic; lower-case ``"zyx"`` would be the extrinsic convention,
    a different triple), the convention of the paper's (DCP-style) tables. Yaw and roll lie in
    [-pi, pi], pitch in [-pi/2, pi/2]; at pitch = +-pi/2 (gimbal lock) scipy warns and sets roll to 0.
    """
    matrix = np.asarray(rotation, dtype=np.float64)[..., :3, :3]
    return Rotation.from_matrix(matrix).as_euler("ZYX")


def lidar_to_camera_poses(poses_lidar: ArrayLike, tr_velo_to_cam: ArrayLike) -> Transform:
    """``T_cam = Tr @ T_lidar @ inv(Tr)``: the frame KITTI's ``poses/XX.txt`` files use."""
    tr = np.asarray(tr_velo_to_cam, dtype=np.float64)
    return tr @ np.asarray(poses_lidar, dtype=np.float64) @ invert(tr)


def camera_to_lidar_poses(poses_camera: ArrayLike, tr_velo_to_cam: ArrayLike) -> Transform:
    """``T_lidar = inv(Tr) @ T_cam @ Tr``: every trajectory inside the library is in the LiDAR frame,
    so KITTI's camera-frame files are converted once, where they are read."""
    tr = np.asarray(tr_velo_to_cam, dtype=np.float64)
    return invert(tr) @ np.asarray(poses_camera, dtype=np.float64) @ tr


def normalise_to_first(poses: ArrayLike) -> Transform:
    """Re-anchor a trajectory so that frame 0 is the identity."""
    poses = np.asarray(poses, dtype=np.float64)
    return invert(poses[0])[None] @ poses


def project_to_se3(poses: ArrayLike) -> Transform:
    """Nearest proper rotations (SVD) for ``(..., 4, 4)`` poses, bottom row reset.

    KITTI pose files are printed to 7 significant digits, so their rotation blocks are only nearly
    orthonormal; left as they are, the transpose-inverse of :func:`invert` turns that into false
    rotation between a pose and itself, and evo rejects them as invalid SO(3).
    """
    poses = np.array(poses, dtype=np.float64)
    u, _, vt = np.linalg.svd(poses[..., :3, :3])
    fix = np.ones((*poses.shape[:-2], 3))
    fix[..., 2] = np.sign(np.linalg.det(u @ vt))
    poses[..., :3, :3] = (u * fix[..., None, :]) @ vt
    poses[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    return poses


def skew(vector: ArrayLike) -> NDArray[np.float64]:
    """The 3x3 matrix of ``vector x``: ``skew(a) @ b == np.cross(a, b)``."""
    x, y, z = np.asarray(vector, dtype=np.float64)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def adjoint(transform: Transform) -> NDArray[np.float64]:
    """The 6x6 adjoint of ``transform`` for twists ordered (rotation, translation), open3d's order: a
    left perturbation ``xi`` in ``transform``'s frame is ``adjoint(transform) @ xi`` in its parent's."""
    rotation = transform[:3, :3]
    result = np.zeros((6, 6))
    result[:3, :3] = rotation
    result[3:, 3:] = rotation
    result[3:, :3] = skew(transform[:3, 3]) @ rotation
    return result


def twist(transform: Transform) -> NDArray[np.float64]:
    """A transform as (rotation vector, translation): the first-order error a covariance describes."""
    return np.concatenate([Rotation.from_matrix(transform[:3, :3]).as_rotvec(), transform[:3, 3]])
