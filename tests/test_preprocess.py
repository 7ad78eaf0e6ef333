"""Pre-processing: range crop, ground removal on a scene with a known plane, exact-N down-sampling."""

from __future__ import annotations

import numpy as np
import pytest

from vcr_odom.errors import ConfigError, DataWarning
from vcr_odom.preprocess import (
    DOWNSAMPLE_METHODS,
    PreprocessConfig,
    crop_range,
    downsample,
    preprocess,
    remove_ground,
)

SLOPE, HEIGHT = 0.02, -1.73  # ground z = 0.02 x - 1.73: a gentle slope under a KITTI-high sensor


def ground_z(x: np.ndarray) -> np.ndarray:
    return SLOPE * x + HEIGHT


def synthetic_scene(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Tilted noisy ground plus boxes (cars) and poles standing on it; returns (points, is_ground)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-40.0, 40.0, size=(30000, 2))
    ground = np.column_stack([xy, ground_z(xy[:, 0]) + rng.normal(0.0, 0.03, len(xy))])
    objects = []
    for cx, cy in rng.uniform(-30.0, 30.0, size=(12, 2)):  # car bodies: 0.4-1.6 m above the road
        local = rng.uniform([-2.0, -0.9, 0.4], [2.0, 0.9, 1.6], size=(600, 3))
        objects.append(local + np.array([cx, cy, 0.0]))
    for cx, cy in rng.uniform(-30.0, 30.0, size=(15, 2)):  # poles: 0.4-5 m above the road
        angle = rng.uniform(0.0, 2 * np.pi, 200)
        height = rng.uniform(0.4, 5.0, 200)
        objects.append(np.column_stack([cx + 0.15 * np.cos(angle), cy + 0.15 * np.sin(angle), height]))
    objects = np.concatenate(objects)
    objects[:, 2] += ground_z(objects[:, 0])
    points = np.concatenate([ground, objects])
    reflectance = rng.uniform(0.0, 1.0, size=(len(points), 1))
    is_ground = np.r_[np.ones(len(ground), bool), np.zeros(len(objects), bool)]
    return np.hstack([points, reflectance]).astype(np.float32), is_ground


def assert_true_ground(plane: np.ndarray | None) -> None:
    """The recovered plane is z = 0.02 x - 1.73: normal within 0.5°, offset within 3 cm."""
    assert plane is not None
    expected = np.array([-SLOPE, 0.0, 1.0, -HEIGHT]) / np.linalg.norm([-SLOPE, 0.0, 1.0])
    normal_error = np.degrees(np.arccos(np.clip(plane[:3] @ expected[:3], -1, 1)))
    assert normal_error < 0.5
    assert abs(plane[3] - expected[3]) < 0.03


def test_remove_ground_recovers_known_plane() -> None:
    points, is_ground = synthetic_scene()
    kept, plane = remove_ground(points, PreprocessConfig(seed=3))
    assert_true_ground(plane)
    kept_rows = {row.tobytes() for row in kept}
    kept_mask = np.array([row.tobytes() in kept_rows for row in points])
    assert (~kept_mask[is_ground]).mean() > 0.95  # >95 % of the road removed
    assert (~kept_mask[~is_ground]).mean() < 0.05  # <5 % of cars and poles removed


def test_remove_ground_is_deterministic_for_a_seed() -> None:
    points, _ = synthetic_scene()
    config = PreprocessConfig(seed=7)
    first, plane_a = remove_ground(points, config)
    second, plane_b = remove_ground(points, config)
    np.testing.assert_array_equal(first, second)
    np.testing.assert_array_equal(plane_a, plane_b)


def test_ransac_on_a_subset_finds_the_plane_of_all_points() -> None:
    """Hypotheses scored on 5k of 38k points classify (nearly) every point as RANSAC on all of them does."""
    points, _ = synthetic_scene()
    subset, plane_subset = remove_ground(points, PreprocessConfig(seed=1, ground_sample_size=5000))
    full, plane_full = remove_ground(points, PreprocessConfig(seed=1, ground_sample_size=len(points)))
    assert_true_ground(plane_subset)
    assert_true_ground(plane_full)
    assert abs(len(subset) - len(full)) < 0.01 * len(full)


def test_remove_ground_rejects_a_dominant_wall() -> None:
    """A facade with more points than the road is found first, rejected (vertical), and the road found next."""
    points, _ = synthetic_scene()
    rng = np.random.default_rng(1)
    wall = np.column_stack([rng.uniform(-40, 40, 60000), np.full(60000, 8.0), rng.uniform(-1.5, 15.0, 60000)])
    scene = np.concatenate([points[:, :3], wall]).astype(np.float32)
    _, plane = remove_ground(scene, PreprocessConfig(seed=0))
    assert_true_ground(plane)


def test_remove_ground_finds_the_road_behind_three_larger_facades() -> None:
    """A narrow old-town street: three facades (and a fourth wall), each larger than the road, are found
    first and set aside (an OS1-128 old-town scan of tuning drive 402 measured three walls of 21-24 k
    points before its road of 20 k); three attempts, the old default, ended there and kept the road."""
    points, _ = synthetic_scene()
    rng = np.random.default_rng(2)
    walls = [
        np.column_stack([rng.uniform(-40, 40, 45000), np.full(45000, y), rng.uniform(-1.5, 15.0, 45000)])
        for y in (6.0, -6.0, 14.0)
    ]
    walls.append(
        np.column_stack([np.full(40000, 25.0), rng.uniform(-6, 6, 40000), rng.uniform(-1.0, 15.0, 40000)])
    )
    scene = np.concatenate([points[:, :3], *walls]).astype(np.float32)
    _, plane = remove_ground(scene, PreprocessConfig(seed=0))
    assert_true_ground(plane)
    with pytest.warns(DataWarning, match="no plausible ground"):
        _, plane = remove_ground(scene, PreprocessConfig(seed=0, ground_max_attempts=3))
    assert plane is None


def test_remove_ground_without_ground_warns_and_keeps_points() -> None:
    rng = np.random.default_rng(0)
    wall = np.column_stack([rng.uniform(-5, 5, 500), np.full(500, 3.0), rng.uniform(0.5, 4.0, 500)])
    with pytest.warns(DataWarning, match="no plausible ground"):
        kept, plane = remove_ground(wall.astype(np.float32))
    assert plane is None
    assert len(kept) == len(wall)


def test_crop_range_keeps_open_interval() -> None:
    points = np.array([[1, 0, 0, 0], [3, 0, 0, 0], [0, 50, 0, 0], [0, 0, 90, 0]], dtype=np.float32)
    cropped = crop_range(points, 2.0, 80.0)
    np.testing.assert_array_equal(cropped, points[1:3])
    assert cropped.dtype == np.float32


@pytest.mark.parametrize("method", DOWNSAMPLE_METHODS)
def test_downsample_exact_n_and_deterministic(method: str) -> None:
    points, _ = synthetic_scene()
    first = downsample(points, 1024, method, seed=5)
    second = downsample(points, 1024, method, seed=5)
    assert first.shape == (1024, 4)
    assert first.dtype == np.float32
    np.testing.assert_array_equal(first, second)
    if method != "voxel":  # fps and random pick real input rows, reflectance included
        rows = {row.tobytes() for row in points}
        assert all(row.tobytes() in rows for row in first)
        assert len({row.tobytes() for row in first}) == 1024
        other = downsample(points, 1024, method, seed=6)
        assert not np.array_equal(first, other)


def test_downsample_pads_when_too_few_points() -> None:
    points = np.random.default_rng(0).normal(size=(100, 4)).astype(np.float32)
    for method in DOWNSAMPLE_METHODS:
        with pytest.warns(DataWarning, match="padding"):
            padded = downsample(points, 256, method, seed=1, voxel_size=0.01)
        assert padded.shape == (256, 4)
        if method != "voxel":
            np.testing.assert_array_equal(padded[:100], points)
        with pytest.warns(DataWarning):
            again = downsample(points, 256, method, seed=1, voxel_size=0.01)
        np.testing.assert_array_equal(padded, again)


def test_downsample_empty_and_bad_arguments() -> None:
    with pytest.warns(DataWarning, match="empty frame"):
        out = downsample(np.zeros((0, 4), np.float32), 16)
    assert out.shape == (16, 4)
    with pytest.raises(ConfigError, match="fps, random, voxel"):
        downsample(np.zeros((10, 4), np.float32), 4, method="grid")
    with pytest.raises(ConfigError):
        PreprocessConfig(n_points=0)


@pytest.mark.parametrize("method", DOWNSAMPLE_METHODS)
def test_preprocess_shapes(method: str) -> None:
    points, _ = synthetic_scene()
    out = preprocess(points, PreprocessConfig(n_points=512, method=method))
    assert out.shape == (512, 3)
    assert out.dtype == np.float32
    assert (out[:, 2] > ground_z(out[:, 0]) + 0.2).mean() > 0.99  # the ground is gone
    with_reflectance = preprocess(
        points, PreprocessConfig(n_points=512, method=method, keep_reflectance=True)
    )
    assert with_reflectance.shape == (512, 4)


@pytest.mark.parametrize("size", [0, 1, 2, 5, 50])
def test_preprocess_tiny_frames_do_not_crash(size: int) -> None:
    points = np.random.default_rng(size).uniform(-20, 20, size=(size, 4)).astype(np.float32)
    with pytest.warns(DataWarning):
        out = preprocess(points, PreprocessConfig(n_points=64))
    assert out.shape == (64, 3)
    if size == 0:
        assert not out.any()  # an empty frame becomes zeros
        return
    # Too few points to crop or segment: every input point is kept, and padding only repeats them.
    assert {row.tobytes() for row in out} == {row.tobytes() for row in points[:, :3]}


def test_preprocess_falls_back_when_ground_removal_leaves_too_few() -> None:
    """An open field (ground plus a handful of object points): the ground is kept, with a warning."""
    points, is_ground = synthetic_scene()
    field = np.concatenate([points[is_ground], points[~is_ground][:20]])
    with pytest.warns(DataWarning, match="ground kept"):
        out = preprocess(field, PreprocessConfig(n_points=256))
    assert out.shape == (256, 3)
    assert (np.abs(out[:, 2] - ground_z(out[:, 0])) < 0.2).mean() > 0.5


def test_preprocess_drops_non_finite_points() -> None:
    points, _ = synthetic_scene()
    points[:10, 0] = np.nan
    config = PreprocessConfig(n_points=256, method="random")
    with pytest.warns(DataWarning, match="non-finite"):
        out = preprocess(points, config)
    # The same as if the bad points had never been there.
    np.testing.assert_array_equal(out, preprocess(points[10:], config))


def test_ground_removal_repeats_exactly_on_ray_cast_scans() -> None:
    """open3d's RANSAC stopped early at a moment that depended on its threads, so repeats could differ
    by a few points (seen on these frames); with the early stop off they must not."""
    from vcr_odom.preprocess import crop_and_remove_ground
    from vcr_odom.synth import SynthSequence

    sequence = SynthSequence(frames=6, seed=2)
    config = PreprocessConfig(n_points=128)
    for index in (3, 4, 5):
        frame = sequence.frame(index)
        first = crop_and_remove_ground(frame, config)
        for _ in range(4):
            np.testing.assert_array_equal(crop_and_remove_ground(frame, config), first)


def test_downsample_without_padding_keeps_what_there_is() -> None:
    """``pad=False`` (the network at inference) returns every point of a frame with fewer than n, none
    repeated and no warning; the default pads by resampling, as training caches need exactly n."""
    import warnings

    from vcr_odom.preprocess import downsample

    points = np.random.default_rng(0).uniform(-10, 10, size=(50, 3)).astype(np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        kept = downsample(points, 64, pad=False)
    np.testing.assert_array_equal(kept, points)
    with pytest.warns(DataWarning, match="padding"):
        padded = downsample(points, 64)
    assert len(padded) == 64 and len(np.unique(padded, axis=0)) == 50
