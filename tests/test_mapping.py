"""VoxelMap: registered scans line up, the map stays one point per voxel, and it saves atomically."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest

from vcr_odom.errors import ConfigError, DataError
from vcr_odom.mapping import VoxelMap
from vcr_odom.synth import SynthSequence

VOXEL = 0.5


@pytest.fixture(scope="module")
def sequence() -> tuple[list[np.ndarray], np.ndarray]:
    seq = SynthSequence(frames=6, seed=0)
    return [seq.frame(i) for i in range(6)], seq.gt_poses


def _world(points: np.ndarray, pose: np.ndarray, max_range: float = 60.0) -> np.ndarray:
    xyz = points[:, :3].astype(np.float64)
    xyz = xyz[np.linalg.norm(xyz, axis=1) <= max_range]
    return xyz @ pose[:3, :3].T + pose[:3, 3]


def occupied_voxels(xyz: np.ndarray) -> np.ndarray:
    """The distinct cells ``floor(p / VOXEL)`` of the origin-anchored grid that ``xyz`` falls in, sorted."""
    return np.unique(np.floor(xyz / VOXEL).astype(np.int64), axis=0)


def test_map_holds_one_point_in_every_occupied_voxel(sequence):
    frames, poses = sequence
    voxel_map = VoxelMap(voxel_size=VOXEL)
    seen = []
    for points, pose in zip(frames, poses, strict=True):
        voxel_map.add(points, pose)
        seen.append(_world(points, pose))
        # Counted independently with numpy: every voxel any scan so far touched, once, and no other.
        expected = occupied_voxels(np.concatenate(seen))
        assert len(voxel_map) == len(expected)
        np.testing.assert_array_equal(occupied_voxels(voxel_map.points()), expected)


def test_true_poses_line_up(sequence):
    frames, poses = sequence
    good = VoxelMap(voxel_size=VOXEL)
    for points, pose in zip(frames, poses, strict=True):
        good.add(points, pose)

    # Wrong poses smear the static street over more voxels than the true ones.
    bad = VoxelMap(voxel_size=VOXEL)
    rng = np.random.default_rng(0)
    for points, pose in zip(frames, poses, strict=True):
        noisy = pose.copy()
        noisy[:3, 3] += rng.uniform(-1.5, 1.5, 3)
        bad.add(points, noisy)
    assert len(bad) > 1.5 * len(good)

    # Every map point sits in a voxel some input point fell in: within the voxel diagonal of one.
    cloud = o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(np.concatenate([_world(p, t) for p, t in zip(frames, poses, strict=True)]))
    )
    tree = o3d.geometry.KDTreeFlann(cloud)
    distances = np.array([math.sqrt(tree.search_knn_vector_3d(q, 1)[2][0]) for q in good.points()])
    assert distances.max() <= math.sqrt(3) * VOXEL + 1e-9
    assert np.mean(distances <= VOXEL) > 0.99


def test_the_same_scan_again_leaves_the_map_as_it_was(sequence):
    """A car standing still re-adds one scene: the map must not grow (or drift) with the frame count."""
    frames, poses = sequence
    once = VoxelMap(voxel_size=VOXEL)
    once.add(frames[0], poses[0])
    repeated = VoxelMap(voxel_size=VOXEL)
    for _ in range(50):
        repeated.add(frames[0], poses[0])
    assert repeated.scans == 50 and once.scans == 1
    # Same voxels, and in each the same mean point and reflectance (open3d averages in float32).
    order_once = np.lexsort(np.floor(once.points() / VOXEL).T)
    order_repeated = np.lexsort(np.floor(repeated.points() / VOXEL).T)
    np.testing.assert_array_equal(occupied_voxels(repeated.points()), occupied_voxels(once.points()))
    np.testing.assert_allclose(repeated.points()[order_repeated], once.points()[order_once], atol=1e-4)
    np.testing.assert_allclose(
        repeated.intensities()[order_repeated], once.intensities()[order_once], atol=1e-5
    )


def test_max_range_crops_in_the_sensor_frame(sequence):
    frames, poses = sequence
    near = VoxelMap(voxel_size=VOXEL, max_range=10.0)
    near.add(frames[3], poses[3])
    centre = poses[3][:3, 3]
    assert np.linalg.norm(near.points() - centre, axis=1).max() <= 10.0 + math.sqrt(3) * VOXEL
    assert len(near) == len(occupied_voxels(_world(frames[3], poses[3], max_range=10.0)))
    far = VoxelMap(voxel_size=VOXEL, max_range=None)
    far.add(frames[3], poses[3])
    assert len(far) == len(occupied_voxels(_world(frames[3], poses[3], max_range=np.inf)))


def test_save_round_trip(tmp_path, sequence):
    frames, poses = sequence
    voxel_map = VoxelMap(voxel_size=VOXEL)
    for points, pose in zip(frames[:2], poses[:2], strict=True):
        voxel_map.add(points, pose)
    for name in ("map.ply", "map.pcd"):
        written = voxel_map.save(tmp_path / name)
        back = o3d.io.read_point_cloud(str(written))
        np.testing.assert_allclose(np.asarray(back.points), voxel_map.points(), rtol=0, atol=1e-5)
        assert back.has_colors()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.pcd", "map.ply"]


def test_bad_extension_names_the_file(tmp_path):
    voxel_map = VoxelMap()
    voxel_map.add(np.ones((10, 4), dtype=np.float32), np.eye(4))
    with pytest.raises(DataError, match=r"map\.xyz"):
        voxel_map.save(tmp_path / "map.xyz")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "options",
    [
        {"voxel_size": 0},
        {"voxel_size": -1.0},
        {"voxel_size": float("nan")},
        {"max_range": 0},
        {"voxel_size": "1"},
    ],
)
def test_bad_options(options):
    with pytest.raises(ConfigError):
        VoxelMap(**options)


def test_bad_inputs():
    voxel_map = VoxelMap()
    with pytest.raises(DataError):
        voxel_map.add(np.ones((5, 2)), np.eye(4))
    with pytest.raises(DataError):
        voxel_map.add(np.ones((5, 4)), np.eye(3))


def test_top_down_is_deterministic_and_capped(sequence):
    frames, poses = sequence
    first, second = VoxelMap(voxel_size=VOXEL), VoxelMap(voxel_size=VOXEL)
    for points, pose in zip(frames[:3], poses[:3], strict=True):
        first.add(points, pose)
        second.add(points, pose)
    sample = first.top_down(max_points=500)
    assert sample.shape == (500, 2)
    np.testing.assert_array_equal(sample, first.top_down(max_points=500))
    np.testing.assert_array_equal(sample, second.top_down(max_points=500))
    assert first.top_down(max_points=10**9).shape == (len(first), 2)
    with pytest.raises(ConfigError):
        first.top_down(max_points=0)
