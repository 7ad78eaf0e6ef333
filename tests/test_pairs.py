"""Training pairs: transform convention, random ranges, determinism, the frame cache, splits."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from vcr_odom.data import open_sequence
from vcr_odom.data.frame_cache import INT16_STEP, FrameCache, build_frame_cache
from vcr_odom.errors import ConfigError, DataError
from vcr_odom.geometry import euler_zyx, invert, transform_points
from vcr_odom.preprocess import PreprocessConfig, preprocess
from vcr_odom.synth import SynthSequence
from vcr_odom.training import (
    PairConfig,
    PairDataset,
    pair_indices,
    random_rigid_transform,
    split_frames,
    train_val_datasets,
)

N = 256
REPO = Path(__file__).resolve().parents[1]


def median_nn(points: np.ndarray, reference: np.ndarray) -> float:
    """Median distance from each point to its nearest neighbour in ``reference``."""
    return float(np.median(cKDTree(reference[:, :3]).query(points[:, :3])[0]))


def assert_aligned(sample: dict, raw_source: np.ndarray) -> tuple[float, float]:
    """Independent check of ``transform``: ``inv(transform)`` brings the target back onto the full
    raw scan of the source frame (its own coordinates), which identity does not. Only points within
    30 m count: farther, the raw scan's rings are too sparse for nearest neighbours to tell."""
    back = transform_points(invert(sample["transform"]), sample["target"])
    near = np.linalg.norm(back, axis=1) < 30.0
    assert near.sum() >= 10, sample["meta"]
    target = np.asarray(sample["target"])[near]
    aligned, unaligned = median_nn(back[near], raw_source), median_nn(target, raw_source)
    assert aligned < 0.3 and aligned < 0.6 * unaligned, (aligned, unaligned, sample["meta"])
    return aligned, unaligned


@pytest.fixture(scope="module")
def synth() -> SynthSequence:
    return SynthSequence(frames=8, seed=0)


@pytest.fixture(scope="module")
def synth_cache(synth: SynthSequence) -> FrameCache:
    return build_frame_cache(synth, None, PreprocessConfig(n_points=N), copies=2, storage="float32")


def test_random_transform_respects_ranges() -> None:
    rng = np.random.default_rng(0)
    draws = np.stack([random_rigid_transform(rng) for _ in range(2000)])
    angles = np.degrees(np.stack([euler_zyx(t[:3, :3]) for t in draws]))  # yaw, pitch, roll
    assert np.allclose(np.linalg.det(draws[:, :3, :3]), 1.0)
    assert np.abs(angles[:, 0]).max() <= 30.0 + 1e-6 and np.abs(angles[:, 0]).max() > 28.0
    assert np.abs(angles[:, 1:]).max() <= 5.0 + 1e-6 and np.abs(angles[:, 1:]).max() > 4.7
    translation = draws[:, :3, 3]
    assert np.abs(translation[:, :2]).max() <= 5.0 and np.abs(translation[:, :2]).max() > 4.9
    assert np.abs(translation[:, 2]).max() <= 1.0 and np.abs(translation[:, 2]).max() > 0.98


def test_same_scan_transform_maps_source_onto_target_exactly() -> None:
    # Both copies are the same points: before down-sampling noise, transform(source) IS the target.
    points = np.random.default_rng(1).uniform(-30, 30, size=(3, 1, 64, 3)).astype(np.float32)
    cache = FrameCache(points=np.repeat(points, 2, axis=1), frame_indices=[4, 5, 6], name="toy")
    dataset = PairDataset(cache, PairConfig(num_points=64, seed=3))
    assert len(dataset) == 3
    for index in range(3):
        sample = dataset[index]
        assert sample["source"].dtype == torch.float32 and sample["transform"].shape == (4, 4)
        moved = transform_points(sample["transform"].double().numpy(), sample["source"].numpy())
        assert np.allclose(moved, sample["target"].numpy(), atol=1e-3)
        assert not np.allclose(sample["source"].numpy(), sample["target"].numpy(), atol=0.1)
    assert dataset[0]["meta"] == "toy:4->4 same-scan"
    odometry = PairDataset(
        FrameCache(
            points=np.repeat(points, 2, axis=1),
            frame_indices=[4, 5, 6],
            gt_poses=np.tile(np.eye(4), (3, 1, 1)),
        ),
        PairConfig(protocol="odometry", num_points=64, gaps=(1,)),
    )
    odometry[0]["source"].zero_()  # a caller editing a sample in place never changes the cache
    odometry[0]["target"].zero_()
    assert np.array_equal(odometry.cache.points, np.repeat(points, 2, axis=1))


def test_same_scan_on_independent_copies(synth: SynthSequence, synth_cache: FrameCache) -> None:
    dataset = PairDataset(synth_cache, PairConfig(num_points=N, seed=0))
    for index in range(len(dataset)):
        sample = dataset.sample(index)
        source, target = sample["source"], sample["target"]
        back = transform_points(invert(sample["transform"]), target)
        assert not np.allclose(
            np.sort(source, axis=0), np.sort(back, axis=0), atol=1e-3
        )  # independent copies
        assert_aligned(sample, synth.frame(index))


def test_copy_zero_is_what_inference_sees(synth: SynthSequence, synth_cache: FrameCache) -> None:
    expected = preprocess(synth.frame(3), PreprocessConfig(n_points=N))
    assert np.array_equal(synth_cache.copy_points(3, 0), expected)


def test_odometry_pairs_use_ground_truth(synth: SynthSequence, synth_cache: FrameCache) -> None:
    config = PairConfig(protocol="odometry", num_points=N, gaps=(1, 3))
    dataset = PairDataset(synth_cache, config)
    assert dataset.pairs == [(j + d, j) for d in (1, 3) for j in range(8 - d)]
    poses = synth.gt_poses
    for index in (0, 6, len(dataset) - 1):
        sample = dataset[index]
        source_frame, target_frame = dataset.pairs[index]
        expected = invert(poses[target_frame]) @ poses[source_frame]
        assert np.allclose(sample["transform"].numpy(), expected, atol=1e-5)
        assert_aligned({k: np.asarray(v) for k, v in sample.items()}, synth.frame(source_frame))
    assert dataset[0]["meta"] == f"{synth.name}:1->0 odometry"


def test_odometry_augment_moves_target(synth: SynthSequence, synth_cache: FrameCache) -> None:
    config = PairConfig(protocol="odometry", num_points=N, gaps=(2,), augment=True, seed=5)
    plain = PairDataset(synth_cache, PairConfig(protocol="odometry", num_points=N, gaps=(2,)))
    dataset = PairDataset(synth_cache, config)
    for index in range(len(dataset)):
        sample = dataset.sample(index)
        gt = plain.sample(index)["transform"]
        assert not np.allclose(sample["transform"], gt, atol=0.05)
        assert_aligned(sample, synth.frame(plain.pairs[index][0]))


def test_determinism_per_seed_epoch_index(synth_cache: FrameCache) -> None:
    config = PairConfig(num_points=N, seed=11)
    a, b = PairDataset(synth_cache, config), PairDataset(synth_cache, config)
    for index in range(3):
        assert torch.equal(a[index]["transform"], b[index]["transform"])
        assert torch.equal(a[index]["target"], b[index]["target"])
    first = a[2]["transform"]
    a.set_epoch(1)
    assert not torch.equal(a[2]["transform"], first)
    assert not torch.equal(a[2]["transform"], a[3]["transform"])
    b.set_epoch(1)
    torch.manual_seed(123)
    np.random.seed(123)  # global RNGs play no part
    assert torch.equal(a[2]["transform"], b[2]["transform"])
    other_seed = PairDataset(synth_cache, PairConfig(num_points=N, seed=12))
    other_seed.set_epoch(1)
    assert not torch.equal(other_seed[2]["transform"], a[2]["transform"])


def test_cache_round_trip(tmp_path: Path, synth_cache: FrameCache) -> None:
    for storage, tolerance in (("float32", 0.0), ("int16", INT16_STEP / 2 + 1e-5), ("float16", 0.04)):
        synth_cache.storage = storage
        path = synth_cache.save(tmp_path / f"cache-{storage}.npz")
        loaded = FrameCache.load(path, num_points=N, min_copies=2)
        assert np.abs(loaded.points - synth_cache.points).max() <= tolerance
        assert np.array_equal(loaded.frame_indices, synth_cache.frame_indices)
        assert np.array_equal(loaded.gt_poses, synth_cache.gt_poses)
        assert np.array_equal(loaded.seeds, synth_cache.seeds)
        assert loaded.name == synth_cache.name and loaded.storage == storage
        assert loaded.preprocess["n_points"] == N
    synth_cache.storage = "float32"
    size = (tmp_path / "cache-int16.npz").stat().st_size
    assert size < 8 * 2 * N * 3 * 2 + 10_000  # int16: ~2 bytes a coordinate or less
    assert not list(tmp_path.glob(".*.tmp"))


def test_cache_errors_name_the_file(tmp_path: Path, synth_cache: FrameCache) -> None:
    with pytest.raises(DataError, match=r"missing.npz"):
        FrameCache.load(tmp_path / "missing.npz")
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(DataError, match=r"corrupt.npz"):
        FrameCache.load(corrupt)
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(synth_cache.save(tmp_path / "full.npz").read_bytes()[:-2000])
    with pytest.raises(DataError, match=r"truncated.npz"):
        FrameCache.load(truncated)
    other = tmp_path / "other.npz"
    np.savez(other, something=np.zeros(3))
    with pytest.raises(DataError, match=r"other.npz"):
        FrameCache.load(other)
    path = synth_cache.save(tmp_path / "good.npz")
    wrong_header = tmp_path / "header.npz"
    np.savez(
        wrong_header,
        header=np.array('{"version": 1}'),
        points=np.zeros((1, 2, 4, 3)),
        frame_indices=[0],
        seeds=[0, 1],
    )
    with pytest.raises(DataError, match=r"header.npz"):
        FrameCache.load(wrong_header)
    with pytest.raises(DataError, match=r"good.npz.*512"):
        FrameCache.load(path, num_points=512)
    with pytest.raises(DataError, match=r"good.npz"):
        FrameCache.load(path, min_copies=3)


def test_loading_and_iterating_without_open3d(tmp_path: Path, synth_cache: FrameCache) -> None:
    path = synth_cache.save(tmp_path / "cache.npz")
    script = f"""
import sys
sys.modules["open3d"] = None
from vcr_odom.data.frame_cache import FrameCache
from vcr_odom.training import PairConfig, PairDataset
cache = FrameCache.load({str(path)!r})
for protocol in ("same-scan", "odometry"):
    dataset = PairDataset(cache, PairConfig(protocol=protocol, num_points={N}, augment=True))
    loader = __import__("torch").utils.data.DataLoader(dataset, batch_size=4)
    batch = next(iter(loader))
    assert batch["source"].shape == (4, {N}, 3), batch["source"].shape
assert "vcr_odom.preprocess" not in sys.modules
print("ok")
"""
    result = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "ok"


def test_split_frames_contiguous_blocks() -> None:
    train, val = split_frames(1000, val_fraction=0.2, block=50)
    assert not set(train) & set(val) and sorted(train + val) == list(range(1000))
    assert len(val) == 200
    blocks = {frame // 50 for frame in val}
    assert all(set(range(b * 50, b * 50 + 50)) <= set(val) for b in blocks)
    assert split_frames(1000, 0.2, 50) == (train, val)
    train, val = split_frames(60)  # default block for a short sequence: 12 frames
    assert val and train and not set(train) & set(val) and len(train) + len(val) == 60
    with pytest.raises(ConfigError, match="val_fraction"):
        split_frames(100, val_fraction=1.0)
    with pytest.raises(ConfigError, match="block"):
        split_frames(10, val_fraction=0.5, block=10)


def test_pair_indices_and_frame_subsets(synth_cache: FrameCache) -> None:
    assert pair_indices(5, (1, 2)) == [(0, 1), (1, 2), (2, 3), (3, 4), (0, 2), (1, 3), (2, 4)]
    assert pair_indices(6, (1,), frames=[0, 1, 3, 4]) == [(0, 1), (3, 4)]
    dataset = PairDataset(
        synth_cache, PairConfig(protocol="odometry", num_points=N, gaps=(1,)), frames=[0, 1, 2, 5]
    )
    assert dataset.pairs == [(1, 0), (2, 1)]
    with pytest.raises(ConfigError, match="frames not in the cache"):
        PairDataset(synth_cache, PairConfig(num_points=N), frames=[99])


def test_both_protocols_share_one_split(synth_cache: FrameCache) -> None:
    """Training on both protocols: each gets its pairs, and no validation frame is a training frame."""
    same_scan = PairConfig(protocol="same-scan", num_points=N)
    odometry = PairConfig(protocol="odometry", num_points=N, gaps=(1,))
    train, val = train_val_datasets([synth_cache], [same_scan, odometry], val_fraction=0.25)
    alone_train, alone_val = train_val_datasets([synth_cache], same_scan, val_fraction=0.25)
    assert len(train.datasets) == len(val.datasets) == 2
    assert len(train.datasets[0]) == len(alone_train) and len(val.datasets[0]) == len(alone_val)
    assert {d.config.protocol for d in train.datasets} == {"same-scan", "odometry"}
    train_frames = {f for d in train.datasets for pair in d.pairs for f in pair}
    val_frames = {f for d in val.datasets for pair in d.pairs for f in pair}
    assert train_frames and val_frames and not train_frames & val_frames
    with pytest.raises(ConfigError, match="at least one"):
        train_val_datasets([synth_cache], [])


def test_config_validation_names_the_field() -> None:
    with pytest.raises(ConfigError, match="protocol"):
        PairConfig(protocol="partial")
    with pytest.raises(ConfigError, match="num_points"):
        PairConfig(num_points=0)
    with pytest.raises(ConfigError, match="gaps"):
        PairConfig(gaps=(0, 1))
    with pytest.raises(ConfigError, match="gaps"):
        PairConfig(gaps=())
    with pytest.raises(ConfigError, match="gaps"):
        PairConfig(gaps=(1.5,))
    assert PairConfig(gaps=[np.int64(2), 1]).gaps == (2, 1)
    with pytest.raises(ConfigError, match="yaw_deg"):
        PairConfig(yaw_deg=-1)
    with pytest.raises(ConfigError, match="seed"):
        PairConfig(seed=-1)
    with pytest.raises(ConfigError, match="n_points"):
        PairConfig(num_points=512, preprocess=PreprocessConfig(n_points=1024))
    one_copy = FrameCache(points=np.zeros((2, 1, 8, 3), np.float32), frame_indices=[0, 1])
    with pytest.raises(ConfigError, match="copies"):
        PairDataset(one_copy, PairConfig(num_points=8))
    with pytest.raises(ConfigError, match="ground-truth"):
        PairDataset(
            FrameCache(points=np.zeros((2, 2, 8, 3), np.float32), frame_indices=[0, 1]),
            PairConfig(protocol="odometry", num_points=8),
        )
    with pytest.raises(ConfigError, match="num_points"):
        PairDataset(one_copy, PairConfig(num_points=16))


@pytest.mark.filterwarnings("ignore:.*no timestamps")
def test_real_kitti_pairs(kitti_sample_root: Path) -> None:
    sequence = open_sequence("00", data_root=kitti_sample_root)
    config = PairConfig(protocol="odometry", num_points=512, gaps=(1, 2))
    progress: list[tuple[int, int]] = []
    cache = build_frame_cache(sequence, [10, 11, 12], config, progress=lambda d, t: progress.append((d, t)))
    assert progress[-1] == (3, 3) and cache.name == "kitti/00"
    for protocol, expected_pairs in (("odometry", 3), ("same-scan", 3)):
        dataset = PairDataset(cache, PairConfig(protocol=protocol, num_points=512, gaps=(1, 2)))
        assert len(dataset) == expected_pairs
        for index in range(len(dataset)):
            assert_aligned(dataset.sample(index), sequence.frame(dataset.pairs[index][0]))
    poses = sequence.gt_poses
    assert np.allclose(cache.relative_pose(10, 12), invert(poses[10]) @ poses[12])


def _line_cache(steps: list[float]) -> FrameCache:
    """Frames driven along x with the given steps (metres), every frame the same toy cloud."""
    x = np.concatenate([[0.0], np.cumsum(steps)])
    poses = np.tile(np.eye(4), (len(x), 1, 1))
    poses[:, 0, 3] = x
    points = np.random.default_rng(0).uniform(-10, 10, (len(x), 2, 8, 3)).astype(np.float32)
    return FrameCache(points=points, frame_indices=list(range(len(x))), gt_poses=poses, name="line")


def test_pairs_by_motion_cover_every_pair_within_the_distance() -> None:
    # A stop (two zero steps), slow and fast stretches.
    cache = _line_cache([0.0, 0.0, 1.0, 2.0, 6.0, 9.0, 0.5])
    positions = cache.gt_poses[:, 0, 3]
    expected = [
        (i, j)
        for i in range(len(positions))
        for j in range(i + 1, len(positions))
        if abs(positions[j] - positions[i]) <= 9.0
    ]
    dataset = PairDataset(cache, PairConfig(protocol="odometry", num_points=8, max_motion=9.0))
    assert sorted((target, source) for source, target in dataset.pairs) == expected
    assert (0, 1) in expected and (0, 2) in expected  # the stop gives pairs that did not move
    for index in range(len(dataset)):
        sample = dataset.sample(index)
        assert np.linalg.norm(sample["transform"][:3, 3]) <= 9.0 + 1e-9


def test_reverse_swaps_source_and_target_with_the_inverse_motion() -> None:
    cache = _line_cache([3.0, 3.0])
    plain = PairDataset(cache, PairConfig(protocol="odometry", num_points=8, max_motion=7.0))
    swapped = PairDataset(cache, PairConfig(protocol="odometry", num_points=8, max_motion=7.0, reverse=True))
    reversed_seen = 0
    for epoch in range(4):
        swapped.set_epoch(epoch)
        for index in range(len(swapped)):
            sample = swapped.sample(index)
            source_frame, target_frame = swapped.pairs[index]
            truth = cache.relative_pose(target_frame, source_frame)
            if sample["meta"].endswith("+reversed"):
                reversed_seen += 1
                np.testing.assert_allclose(sample["transform"], np.linalg.inv(truth), atol=1e-12)
            else:
                np.testing.assert_allclose(sample["transform"], truth, atol=1e-12)
    assert 0 < reversed_seen < 4 * len(plain)


def test_max_motion_must_be_positive() -> None:
    with pytest.raises(ConfigError, match="max_motion"):
        PairConfig(protocol="odometry", max_motion=0.0)
