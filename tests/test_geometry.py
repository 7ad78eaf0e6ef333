"""SE(3) helpers checked against independent references: numpy's inverse, rotations built here by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vcr_odom import geometry


def random_transform(rng: np.random.Generator) -> np.ndarray:
    return geometry.make_transform(
        Rotation.random(random_state=rng.integers(1 << 31)).as_matrix(), rng.normal(size=3)
    )


def rz(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def ry(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rx(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' formula: the rotation by ``angle`` about the unit ``axis``."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


def test_invert_matches_numpy_and_broadcasts() -> None:
    rng = np.random.default_rng(0)
    stack = np.stack([random_transform(rng) for _ in range(5)])
    np.testing.assert_allclose(geometry.invert(stack), np.linalg.inv(stack), atol=1e-12)
    np.testing.assert_allclose(geometry.invert(stack[0]) @ stack[0], np.eye(4), atol=1e-12)


# Yaw and roll over (-180, 180], pitch inside (-90, 90): where the Z-Y-X triple is unique.
EULER_CASES = [
    (0.0, 0.0, 0.0),
    (0.3, -0.2, 0.1),
    (math.radians(179.9), 0.05, -0.05),
    (math.radians(-179.9), -0.05, 0.05),
    (-2.0, math.radians(89.0), 3.0),
    (1.0, math.radians(-89.0), -3.0),
    (math.pi, 0.2, math.pi),
]


@pytest.mark.parametrize(("yaw", "pitch", "roll"), EULER_CASES)
def test_euler_zyx_is_intrinsic_z_then_y_then_x(yaw: float, pitch: float, roll: float) -> None:
    expected = rz(yaw) @ ry(pitch) @ rx(roll)
    np.testing.assert_allclose(geometry.rotation_from_euler_zyx(yaw, pitch, roll), expected, atol=1e-12)
    recovered = geometry.euler_zyx(expected)
    # Compare as angles (yaw = 180 and -180 deg are the same turn).
    np.testing.assert_allclose(np.sin(recovered), np.sin([yaw, pitch, roll]), atol=1e-9)
    np.testing.assert_allclose(np.cos(recovered), np.cos([yaw, pitch, roll]), atol=1e-9)
    assert -math.pi <= recovered[0] <= math.pi and -math.pi / 2 <= recovered[1] <= math.pi / 2


def test_euler_zyx_takes_transforms_and_batches() -> None:
    angles = np.array(EULER_CASES[:6]).reshape(2, 3, 3)
    transforms = np.zeros((2, 3, 4, 4))
    for index in np.ndindex(2, 3):
        transforms[index] = geometry.make_transform(
            rz(angles[index][0]) @ ry(angles[index][1]) @ rx(angles[index][2]), [1.0, 2.0, 3.0]
        )
    np.testing.assert_allclose(geometry.euler_zyx(transforms), angles, atol=1e-9)


@pytest.mark.parametrize("angle", [1e-9, 1e-4, 0.5, math.pi / 2, math.pi - 1e-6, math.pi])
def test_rotation_angle_is_the_geodesic_angle(angle: float) -> None:
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    matrix = axis_angle(axis, angle)
    # The quaternion route is accurate to a few ulp even where arccos((trace - 1) / 2) is not.
    assert geometry.rotation_angle(matrix) == pytest.approx(angle, rel=1e-9, abs=1e-12)
    assert geometry.rotation_angle(geometry.make_transform(matrix.T, [5.0, 0.0, 0.0])) == pytest.approx(
        angle, rel=1e-9, abs=1e-12
    )


def test_rotation_angle_batches_and_is_exactly_zero_for_identity() -> None:
    angles = np.linspace(0.0, math.pi, 6).reshape(2, 3)
    axes = np.random.default_rng(3).normal(size=(2, 3, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    matrices = np.stack([[axis_angle(axes[i, j], angles[i, j]) for j in range(3)] for i in range(2)])
    result = geometry.rotation_angle(matrices)
    assert isinstance(result, np.ndarray) and result.shape == (2, 3)
    np.testing.assert_allclose(result, angles, atol=1e-12)
    identity = geometry.rotation_angle(np.eye(3))
    assert isinstance(identity, float) and identity == 0.0


def test_camera_lidar_conversion_round_trip() -> None:
    rng = np.random.default_rng(5)
    tr = random_transform(rng)
    poses = np.stack([random_transform(rng) for _ in range(4)])
    camera = geometry.lidar_to_camera_poses(poses, tr)
    np.testing.assert_allclose(camera, tr @ poses @ np.linalg.inv(tr), atol=1e-12)
    np.testing.assert_allclose(geometry.camera_to_lidar_poses(camera, tr), poses, atol=1e-12)
    anchored = geometry.normalise_to_first(poses)
    np.testing.assert_allclose(anchored[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(
        geometry.relative(anchored[1], anchored[3]), geometry.relative(poses[1], poses[3]), atol=1e-12
    )


def test_project_to_se3_returns_the_nearest_rotation() -> None:
    rng = np.random.default_rng(6)
    pose = random_transform(rng)
    noisy = pose.copy()
    noisy[:3, :3] += rng.normal(0.0, 2e-7, (3, 3))  # what 7 printed digits do to a rotation
    noisy[3] = (1e-9, 0.0, 0.0, 1.0)
    projected = geometry.project_to_se3(noisy)
    rotation = projected[:3, :3]
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-14)
    assert np.linalg.det(rotation) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_array_equal(projected[3], [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_array_equal(projected[:3, 3], noisy[:3, 3])
    # Nearest in the Frobenius norm: no nearby rotation is closer to the noisy block.
    distance = np.linalg.norm(rotation - noisy[:3, :3])
    for _ in range(50):
        nearby = Rotation.from_rotvec(rng.normal(0.0, 1e-7, 3)).as_matrix() @ rotation
        assert np.linalg.norm(nearby - noisy[:3, :3]) >= distance - 1e-15


def test_the_adjoint_moves_a_perturbation_into_the_parent_frame() -> None:
    """A small left perturbation ``xi`` in a pose's own frame, ``T exp(xi)``, is ``exp(Ad(T) xi) T``:
    checked against the exact conjugation ``T exp(xi) T^-1``, to first order."""
    rng = np.random.default_rng(4)
    pose = geometry.make_transform(
        Rotation.from_rotvec(rng.normal(size=3)).as_matrix(), rng.normal(size=3) * 20
    )
    xi = rng.normal(size=6) * 1e-6
    small = geometry.make_transform(Rotation.from_rotvec(xi[:3]).as_matrix(), xi[3:])
    conjugated = geometry.twist(pose @ small @ geometry.invert(pose))
    np.testing.assert_allclose(geometry.adjoint(pose) @ xi, conjugated, rtol=1e-4, atol=1e-12)
    np.testing.assert_allclose(
        geometry.skew([1.0, 2.0, 3.0]) @ [4.0, 5.0, 6.0], np.cross([1, 2, 3], [4, 5, 6])
    )
