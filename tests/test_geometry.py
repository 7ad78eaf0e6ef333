"""SE(3) helpers checked against scipy, an independent implementation."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vcr_odom import geometry


def random_transform(rng: np.random.Generator) -> np.ndarray:
    return geometry.make_transform(
        Rotation.random(random_state=rng.integers(1 << 31)).as_matrix(), rng.normal(size=3)
    )


def test_invert_matches_numpy_and_broadcasts():
    rng = np.random.default_rng(0)
    stack = np.stack([random_transform(rng) for _ in range(5)])
    np.testing.assert_allclose(geometry.invert(stack), np.linalg.inv(stack), atol=1e-12)
    np.testing.assert_allclose(geometry.invert(stack[0]) @ stack[0], np.eye(4), atol=1e-12)


def test_euler_zyx_matches_scipy_both_ways():
    rng = np.random.default_rng(1)
    for _ in range(20):
        rotation = Rotation.random(random_state=rng.integers(1 << 31))
        expected = rotation.as_euler("ZYX")  # intrinsic z-y-x: yaw, pitch, roll
        np.testing.assert_allclose(geometry.euler_zyx(rotation.as_matrix()), expected, atol=1e-9)
        np.testing.assert_allclose(
            geometry.rotation_from_euler_zyx(*expected), rotation.as_matrix(), atol=1e-12
        )


def test_rotation_angle_is_the_geodesic_angle():
    rotations = Rotation.random(10, random_state=3)
    np.testing.assert_allclose(
        geometry.rotation_angle(rotations.as_matrix()), rotations.magnitude(), atol=1e-7
    )
    assert geometry.rotation_angle(np.eye(3)) == 0.0


@pytest.mark.parametrize("weighted", [False, True])
def test_weighted_kabsch_recovers_transform_and_never_reflects(weighted):
    rng = np.random.default_rng(4)
    truth = random_transform(rng)
    source = rng.normal(size=(50, 3))
    target = geometry.transform_points(truth, source)
    weights = rng.uniform(0.1, 1.0, 50) if weighted else None
    np.testing.assert_allclose(geometry.weighted_kabsch(source, target, weights), truth, atol=1e-9)
    # A mirrored target: the best proper rotation must still have det +1.
    mirrored = target * np.array([1.0, 1.0, -1.0])
    estimate = geometry.weighted_kabsch(source, mirrored, weights)
    assert np.linalg.det(estimate[:3, :3]) == pytest.approx(1.0)


def test_camera_lidar_conversion_round_trip():
    rng = np.random.default_rng(5)
    tr = random_transform(rng)
    poses = np.stack([random_transform(rng) for _ in range(4)])
    camera = geometry.lidar_to_camera_poses(poses, tr)
    np.testing.assert_allclose(geometry.camera_to_lidar_poses(camera, tr), poses, atol=1e-12)
    anchored = geometry.normalise_to_first(poses)
    np.testing.assert_allclose(anchored[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(
        geometry.relative(anchored[1], anchored[3]), geometry.relative(poses[1], poses[3]), atol=1e-12
    )
