"""Training and validation pairs for VCR-Net: the paper's same-scan protocol and odometry pairs.

Two protocols (DESIGN.md, "VCR-Net: where the paper and the released code differ"):

- ``"same-scan"`` (the paper's Table III): one ground-removed scan down-sampled twice, independently
  (different seeds), to N points; the second copy is moved by a random rigid transform ``M`` (yaw ±30°,
  roll/pitch ±5°, horizontal ±5 m, vertical ±1 m; LiDAR frame, z up). **Source = the first copy as
  it is, target = the second copy moved by M, so ``transform = M``**: the label's distribution is
  exactly the documented ranges.
- ``"odometry"``: scans ``i`` and ``j = i + d`` (``d`` in ``gaps``), each ground-removed and
  down-sampled independently; **source = frame j, target = frame i, ``transform = inv(P_i) @ P_j``**
  (``T_i_j`` from the LiDAR-frame ground truth). With ``augment=True`` the target is also moved by a
  random ``M`` of the same ranges and ``transform = M @ T_i_j``, so the network cannot rely on the
  small motion between consecutive frames. With ``max_motion`` set, the pairs are instead every
  ``(i, j)``, ``i < j``, whose ground-truth motion is at most ``max_motion`` metres (a stop gives
  pairs that did not move; a fast stretch few of them), so training covers 0 to ``max_motion`` m
  whatever the frame rate and speed. ``reverse=True`` swaps source and target of a random half of
  the samples each epoch (the motion then points backwards).

Every sample's ``transform`` is ``T_target_source``: ``target ≈ R @ source + t``.

Pre-processing (open3d RANSAC + FPS, ~50 ms a frame) runs once, in :func:`build_frame_cache`, which
stores K independently down-sampled copies of each ground-removed frame in one ``.npz``. Loading a
cache and iterating a :class:`PairDataset` need numpy and torch only (open3d and
:mod:`vcr_odom.preprocess` are imported lazily), so a cache can be carried to a GPU machine without
open3d. Randomness never touches global RNGs: each sample draws from
``numpy.random.default_rng([seed, epoch, index])``.
"""

from __future__ import annotations

import io
import json
import math
import os
import zipfile
import zlib
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
import torch
from numpy.typing import NDArray
from torch.utils.data import ConcatDataset, Dataset

from vcr_odom.errors import ConfigError, DataError
from vcr_odom.geometry import invert, make_transform, rotation_from_euler_zyx
from vcr_odom.io import atomic_write_bytes

if TYPE_CHECKING:
    from vcr_odom.data.base import LidarSequence
    from vcr_odom.preprocess import PreprocessConfig

PROTOCOLS = ("same-scan", "odometry")
STORAGES = ("int16", "float16", "float32")
"""How a cache stores points: ``int16`` fixed point of ``INT16_STEP`` metres (±163 m, at most 2.5 mm
error, half of float32's size), ``float16`` (up to ~3 cm error at 64-80 m: coarse for a 5 cm target),
or exact ``float32``."""
INT16_STEP = 0.005
CACHE_VERSION = 1
_COPY_SEED_STRIDE = 1_000_003


class PairSample(TypedDict):
    """One training pair; ``transform`` is ``T_target_source`` (maps source points onto the target)."""

    source: torch.Tensor
    target: torch.Tensor
    transform: torch.Tensor
    meta: str


# ----------------------------------------------------------------------------------------------
# Building blocks


def random_rigid_transform(
    rng: np.random.Generator,
    yaw_deg: float = 30.0,
    tilt_deg: float = 5.0,
    horizontal_m: float = 5.0,
    vertical_m: float = 1.0,
) -> NDArray[np.float64]:
    """The paper's random motion: yaw, pitch and roll uniform in ±yaw_deg / ±tilt_deg (z-y-x Euler,
    LiDAR frame, z up), translation uniform in ±horizontal_m along x and y and ±vertical_m along z."""
    yaw, pitch, roll = np.radians(
        rng.uniform([-yaw_deg, -tilt_deg, -tilt_deg], [yaw_deg, tilt_deg, tilt_deg])
    )
    translation = rng.uniform(
        [-horizontal_m, -horizontal_m, -vertical_m], [horizontal_m, horizontal_m, vertical_m]
    )
    return make_transform(rotation_from_euler_zyx(yaw, pitch, roll), translation)


def pair_indices(
    length: int, gaps: Sequence[int], frames: Sequence[int] | None = None
) -> list[tuple[int, int]]:
    """Every ``(i, i + d)`` with ``d`` in ``gaps`` and both frames in ``frames`` (default all of
    ``range(length)``), sorted by ``(d, i)``. Enumerating rather than drawing ``d`` keeps the dataset
    length fixed and every gap equally represented per frame."""
    if length < 0:
        raise ConfigError(f"length must be >= 0; got {length}")
    _check_gaps(gaps)
    available = set(range(length)) if frames is None else {int(f) for f in frames if 0 <= int(f) < length}
    return [(i, i + d) for d in sorted(set(gaps)) for i in sorted(available) if i + d in available]


def pairs_within(cache: FrameCache, frames: Sequence[int], max_motion: float) -> list[tuple[int, int]]:
    """Every ``(i, j)``, ``i < j`` in ``frames``, whose ground-truth translation is at most
    ``max_motion`` metres, sorted."""
    if cache.gt_poses is None:
        raise ConfigError(f"pairs by motion need ground-truth poses; {cache.name} has none")
    ordered = sorted(int(f) for f in frames)
    positions = (
        np.stack([cache.gt_poses[cache.row(f)][:3, 3] for f in ordered]) if ordered else np.zeros((0, 3))
    )
    distance = np.linalg.norm(positions[:, None] - positions[None], axis=-1)
    rows, cols = np.nonzero(np.triu(distance <= max_motion, k=1))
    return [(ordered[r], ordered[c]) for r, c in zip(rows.tolist(), cols.tolist(), strict=True)]


def split_frames(
    length: int, val_fraction: float = 0.2, block: int | None = None
) -> tuple[list[int], list[int]]:
    """``(train, val)`` frame indices of one sequence, by contiguous blocks of ``block`` frames.

    Why blocks: neighbouring frames see nearly the same scene, so interleaving would validate on
    near-copies of training scans. ``block=None`` means ``min(100, max(1, length // 5))`` (100 frames
    = 10 s, ~100 m of KITTI driving). ``round(blocks * val_fraction)`` blocks (at least one when
    ``val_fraction > 0``), evenly spread along the sequence, go to validation. Deterministic.
    """
    if length < 2:
        raise ConfigError(f"length must be >= 2 to split; got {length}")
    if not 0.0 <= val_fraction < 1.0:
        raise ConfigError(f"val_fraction must be in [0, 1); got {val_fraction}")
    block = min(100, max(1, length // 5)) if block is None else block
    if block < 1:
        raise ConfigError(f"block must be >= 1; got {block}")
    n_blocks = math.ceil(length / block)
    n_val = 0 if val_fraction == 0 else max(1, round(n_blocks * val_fraction))
    if n_val >= n_blocks:
        raise ConfigError(
            f"block={block} gives {n_blocks} blocks of {length} frames: too few to keep "
            f"{val_fraction:.0%} for validation and some for training"
        )
    val_blocks = {int((k + 0.5) * n_blocks / n_val) for k in range(n_val)}
    train: list[int] = []
    val: list[int] = []
    for frame in range(length):
        (val if frame // block in val_blocks else train).append(frame)
    return train, val


def _check_gaps(gaps: Sequence[int]) -> None:
    if len(gaps) == 0 or any(not isinstance(d, int | np.integer) or d < 1 for d in gaps):
        raise ConfigError(f"gaps must be a non-empty set of integers >= 1; got {tuple(gaps)!r}")


# ----------------------------------------------------------------------------------------------
# Configuration


@dataclass(frozen=True)
class PairConfig:
    """How pairs are made. ``preprocess`` (a :class:`~vcr_odom.preprocess.PreprocessConfig`, None =
    its defaults) is what ``run`` uses, so training sees what inference feeds it; its ``n_points``
    must equal ``num_points``. ``seed`` drives every random transform and copy choice."""

    protocol: str = "same-scan"
    num_points: int = 1024
    gaps: tuple[int, ...] = (1, 2, 3, 5)
    augment: bool = False
    preprocess: PreprocessConfig | None = None
    seed: int = 0
    yaw_deg: float = 30.0
    tilt_deg: float = 5.0
    horizontal_m: float = 5.0
    vertical_m: float = 1.0
    max_motion: float | None = None
    reverse: bool = False

    def __post_init__(self) -> None:
        if self.max_motion is not None and not (math.isfinite(self.max_motion) and self.max_motion > 0):
            raise ConfigError(
                f"max_motion must be None or a finite number of metres > 0; got {self.max_motion!r}"
            )
        if self.protocol not in PROTOCOLS:
            raise ConfigError(f"protocol must be one of {', '.join(PROTOCOLS)}; got {self.protocol!r}")
        if int(self.num_points) != self.num_points or self.num_points < 1:
            raise ConfigError(f"num_points must be an integer >= 1; got {self.num_points!r}")
        _check_gaps(tuple(self.gaps))
        object.__setattr__(self, "gaps", tuple(int(d) for d in self.gaps))
        if self.preprocess is not None and self.preprocess.n_points != self.num_points:
            raise ConfigError(
                f"num_points={self.num_points} differs from preprocess.n_points={self.preprocess.n_points}"
            )
        for name in ("yaw_deg", "tilt_deg", "horizontal_m", "vertical_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ConfigError(f"{name} must be finite and >= 0; got {value!r}")
        if int(self.seed) != self.seed or self.seed < 0:
            raise ConfigError(f"seed must be an integer >= 0; got {self.seed!r}")

    def preprocess_config(self) -> PreprocessConfig:
        """The pre-processing of the cache (imports open3d: only call where it is installed)."""
        from vcr_odom.preprocess import PreprocessConfig

        return self.preprocess or PreprocessConfig(n_points=self.num_points)

    def transform_ranges(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in ("yaw_deg", "tilt_deg", "horizontal_m", "vertical_m")}


# ----------------------------------------------------------------------------------------------
# Frame cache


@dataclass
class FrameCache:
    """Ground-removed, down-sampled copies of frames: ``points[row, copy]`` is float32 ``(N, 3)``.

    ``frame_indices[row]`` is the frame's index in its sequence; ``gt_poses[row]`` its LiDAR-frame
    pose (None when the sequence has no ground truth: only the same-scan protocol works then).
    Copy ``k`` was down-sampled with seed ``seeds[k]``; copy 0 uses the pre-processing seed itself,
    so it equals what ``preprocess(frame, config)`` gives at inference time.
    """

    points: NDArray[np.float32]
    frame_indices: NDArray[np.int64]
    gt_poses: NDArray[np.float64] | None = None
    name: str = "frames"
    storage: str = "int16"
    seeds: NDArray[np.int64] | None = None
    preprocess: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=np.float32)
        self.frame_indices = np.asarray(self.frame_indices, dtype=np.int64).reshape(-1)
        if self.points.ndim != 4 or self.points.shape[-1] != 3 or self.points.shape[1] < 1:
            raise DataError(f"cache points must be (frames, copies, N, 3); got {self.points.shape}")
        if len(self.frame_indices) != len(self.points):
            raise DataError(f"{len(self.frame_indices)} frame indices for {len(self.points)} frames")
        if len(np.unique(self.frame_indices)) != len(self.frame_indices):
            raise DataError("cache frame indices must be unique")
        if self.gt_poses is not None:
            self.gt_poses = np.asarray(self.gt_poses, dtype=np.float64)
            if self.gt_poses.shape != (len(self.points), 4, 4):
                raise DataError(f"gt_poses must be ({len(self.points)}, 4, 4); got {self.gt_poses.shape}")
        if self.storage not in STORAGES:
            raise ConfigError(f"storage must be one of {', '.join(STORAGES)}; got {self.storage!r}")
        if self.seeds is None:
            self.seeds = np.arange(self.copies, dtype=np.int64)
        self.seeds = np.asarray(self.seeds, dtype=np.int64).reshape(-1)
        self._rows = {int(f): row for row, f in enumerate(self.frame_indices)}

    def __len__(self) -> int:
        return len(self.points)

    @property
    def copies(self) -> int:
        return int(self.points.shape[1])

    @property
    def num_points(self) -> int:
        return int(self.points.shape[2])

    def row(self, frame: int) -> int:
        """Row of sequence frame ``frame`` (DataError when it is not cached)."""
        try:
            return self._rows[int(frame)]
        except KeyError:
            raise DataError(f"frame {frame} is not in the cache of {self.name}") from None

    def copy_points(self, frame: int, copy: int) -> NDArray[np.float32]:
        return self.points[self.row(frame), copy]

    def relative_pose(self, target_frame: int, source_frame: int) -> NDArray[np.float64]:
        """``T_target_source = inv(P_target) @ P_source`` from the ground truth."""
        if self.gt_poses is None:
            raise DataError(f"{self.name} has no ground-truth poses: odometry pairs need them")
        return invert(self.gt_poses[self.row(target_frame)]) @ self.gt_poses[self.row(source_frame)]

    # -- persistence ---------------------------------------------------------------------------

    def _encoded_points(self) -> NDArray:
        if self.storage == "float32":
            return self.points
        if self.storage == "float16":
            return self.points.astype(np.float16)
        limit = np.iinfo(np.int16).max * INT16_STEP
        if np.abs(self.points).max(initial=0.0) > limit:
            raise DataError(f"points beyond ±{limit:.0f} m do not fit storage='int16'; use 'float32'")
        return np.round(self.points / INT16_STEP).astype(np.int16)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write one ``.npz`` atomically (temp file + rename): a crash never leaves a half file."""
        arrays: dict[str, NDArray] = {
            "points": self._encoded_points(),
            "frame_indices": self.frame_indices,
            "seeds": np.asarray(self.seeds),
            "header": np.array(
                json.dumps(
                    {
                        "version": CACHE_VERSION,
                        "name": self.name,
                        "storage": self.storage,
                        "int16_step": INT16_STEP,
                        "preprocess": self.preprocess,
                    }
                )
            ),
        }
        if self.gt_poses is not None:
            arrays["gt_poses"] = self.gt_poses
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **arrays)
        return atomic_write_bytes(path, buffer.getvalue())

    @classmethod
    def load(
        cls, path: str | os.PathLike[str], num_points: int | None = None, min_copies: int = 1
    ) -> FrameCache:
        """Read a cache written by :meth:`save`; DataError naming the file when it is missing,
        corrupt, of another version, or does not have ``num_points`` points / ``min_copies`` copies."""
        path = Path(path)
        if not path.is_file():
            raise DataError(f"frame cache {path} not found (build it with build_frame_cache)")
        try:
            with np.load(path, allow_pickle=False) as data:
                header = json.loads(str(data["header"]))
                raw = data["points"]
                frame_indices = data["frame_indices"]
                seeds = data["seeds"]
                gt_poses = data["gt_poses"] if "gt_poses" in data.files else None
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as error:
            raise DataError(f"frame cache {path} is corrupt or not a frame cache: {error}") from error
        if not isinstance(header, dict) or header.get("version") != CACHE_VERSION:
            found = header.get("version") if isinstance(header, dict) else None
            raise DataError(f"frame cache {path} has version {found!r}; expected {CACHE_VERSION}")
        try:
            storage = header["storage"]
            points = raw.astype(np.float32)
            if storage == "int16":
                points *= np.float32(header["int16_step"])
            cache = cls(
                points=points,
                frame_indices=frame_indices,
                gt_poses=gt_poses,
                name=str(header.get("name", path.stem)),
                storage=storage,
                seeds=seeds,
                preprocess=dict(header.get("preprocess", {})),
            )
        except (DataError, ConfigError, KeyError, TypeError, ValueError) as error:
            raise DataError(f"frame cache {path} is inconsistent: {error!r}") from error
        if num_points is not None and cache.num_points != num_points:
            raise DataError(
                f"frame cache {path} holds {cache.num_points} points a frame; expected {num_points}"
            )
        if cache.copies < min_copies:
            raise DataError(f"frame cache {path} holds {cache.copies} copies a frame; need {min_copies}")
        return cache


PreprocessedFrames = FrameCache
"""Alias: the name the training brief uses."""


def build_frame_cache(
    sequence: LidarSequence,
    frame_indices: Sequence[int] | None = None,
    config: PreprocessConfig | PairConfig | None = None,
    copies: int = 2,
    progress: Callable[[int, int], None] | None = None,
    storage: str = "int16",
) -> FrameCache:
    """Ground-remove each frame once and down-sample it ``copies`` times with different seeds.

    Copy 0 uses ``config.seed`` (so it equals ``preprocess(frame, config)``), copy k uses
    ``config.seed + k * 1000003``. ``progress(done, total)`` is called after each frame. Imports
    open3d (through :mod:`vcr_odom.preprocess`): the only function here that does.
    """
    from vcr_odom.preprocess import PreprocessConfig, crop_and_remove_ground, downsample

    if isinstance(config, PairConfig):
        config = config.preprocess_config()
    config = config or PreprocessConfig()
    if copies < 1:
        raise ConfigError(f"copies must be >= 1; got {copies}")
    if storage not in STORAGES:
        raise ConfigError(f"storage must be one of {', '.join(STORAGES)}; got {storage!r}")
    frames = list(range(len(sequence))) if frame_indices is None else [int(f) for f in frame_indices]
    if not frames:
        raise ConfigError("frame_indices is empty")
    bad = [f for f in frames if not 0 <= f < len(sequence)]
    if bad:
        raise ConfigError(f"frame_indices out of range for {len(sequence)} frames: {bad[:5]}")
    seeds = np.array([config.seed + k * _COPY_SEED_STRIDE for k in range(copies)], dtype=np.int64)
    points = np.empty((len(frames), copies, config.n_points, 3), dtype=np.float32)
    for row, frame in enumerate(frames):
        cleaned = crop_and_remove_ground(sequence.frame(frame), config)
        for k, seed in enumerate(seeds):
            sampled = downsample(
                cleaned, config.n_points, config.method, int(seed), config.voxel_size, config.fps_candidates
            )
            points[row, k] = sampled[:, :3]
        if progress is not None:
            progress(row + 1, len(frames))
    all_poses = sequence.gt_poses
    gt_poses = None if all_poses is None else np.asarray(all_poses, dtype=np.float64)[frames]
    return FrameCache(
        points=points,
        frame_indices=np.asarray(frames, dtype=np.int64),
        gt_poses=gt_poses,
        name=sequence.name,
        storage=storage,
        seeds=seeds,
        preprocess=asdict(config),
    )


# ----------------------------------------------------------------------------------------------
# Dataset


class PairDataset(Dataset):
    """Pairs of one :class:`FrameCache` under :class:`PairConfig`; see the module doc for conventions.

    ``frames`` restricts the sequence frames used (e.g. one side of :func:`split_frames`); odometry
    pairs need both frames in it. Sample ``i`` of epoch ``e`` is a pure function of
    ``(config.seed, e, i)``: call :meth:`set_epoch` each epoch for new transforms and copy choices
    (before creating the DataLoader iterator: workers copy the dataset, so with
    ``persistent_workers=True`` the epoch would not reach them).
    """

    def __init__(self, cache: FrameCache, config: PairConfig, frames: Sequence[int] | None = None) -> None:
        if cache.num_points != config.num_points:
            raise ConfigError(f"num_points={config.num_points} but the cache holds {cache.num_points} points")
        if config.protocol == "same-scan" and cache.copies < 2:
            raise ConfigError("protocol 'same-scan' needs a cache with copies >= 2")
        if config.protocol == "odometry" and cache.gt_poses is None:
            raise ConfigError(f"protocol 'odometry' needs ground-truth poses; {cache.name} has none")
        self.cache = cache
        self.config = config
        self.epoch = 0
        available = [int(f) for f in cache.frame_indices]
        if frames is not None:
            wanted = {int(f) for f in frames}
            missing = sorted(wanted - set(available))
            if missing:
                raise ConfigError(f"frames not in the cache of {cache.name}: {missing[:5]}")
            available = [f for f in available if f in wanted]
        if config.protocol == "same-scan":
            self.pairs = [(f, f) for f in sorted(available)]
        elif config.max_motion is not None:
            self.pairs = [(j, i) for i, j in pairs_within(cache, available, config.max_motion)]
        else:
            top = max(available, default=-1) + 1
            self.pairs = [(j, i) for i, j in pair_indices(top, config.gaps, available)]
        # ``pairs[k] = (source_frame, target_frame)``

    def set_epoch(self, epoch: int) -> None:
        """New random draws for this epoch (reproducible; call it in every worker/rank alike)."""
        if epoch < 0:
            raise ConfigError(f"epoch must be >= 0; got {epoch}")
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return len(self.pairs)

    def sample(self, index: int) -> dict[str, Any]:
        """Sample ``index`` as numpy arrays (float32 points, float64 transform) and meta."""
        if not 0 <= index < len(self.pairs):
            raise IndexError(f"pair {index} out of range for {len(self.pairs)} pairs")
        config, cache = self.config, self.cache
        rng = np.random.default_rng([config.seed, self.epoch, index])
        source_frame, target_frame = self.pairs[index]
        if config.protocol == "same-scan":
            source_copy, target_copy = rng.choice(cache.copies, size=2, replace=False)
            transform = random_rigid_transform(rng, **config.transform_ranges())
            source = cache.copy_points(source_frame, source_copy)
            target = cache.copy_points(target_frame, target_copy)
            target = _apply(transform, target)
            meta = f"{cache.name}:{source_frame}->{target_frame} same-scan"
        else:
            source_copy, target_copy = rng.integers(cache.copies, size=2)
            source = cache.copy_points(source_frame, source_copy)
            target = cache.copy_points(target_frame, target_copy)
            transform = cache.relative_pose(target_frame, source_frame)
            meta = f"{cache.name}:{source_frame}->{target_frame} odometry"
            if config.reverse and rng.random() < 0.5:
                source, target, transform = target, source, invert(transform)
                meta += "+reversed"
            if config.augment:
                motion = random_rigid_transform(rng, **config.transform_ranges())
                target = _apply(motion, target)
                transform = motion @ transform
                meta += "+augment"
        # Copies: a caller editing a sample in place must never change the cache.
        return {"source": source.copy(), "target": target.copy(), "transform": transform, "meta": meta}

    def __getitem__(self, index: int) -> PairSample:
        sample = self.sample(index)
        return PairSample(
            source=torch.from_numpy(np.ascontiguousarray(sample["source"], dtype=np.float32)),
            target=torch.from_numpy(np.ascontiguousarray(sample["target"], dtype=np.float32)),
            transform=torch.from_numpy(np.asarray(sample["transform"], dtype=np.float32)),
            meta=sample["meta"],
        )

    @classmethod
    def from_sequence(
        cls,
        sequence: LidarSequence,
        config: PairConfig,
        frames: Sequence[int] | None = None,
        copies: int = 2,
        progress: Callable[[int, int], None] | None = None,
    ) -> PairDataset:
        """Build the cache in memory (needs open3d), then the dataset: for tests and small runs."""
        cache = build_frame_cache(sequence, frames, config, copies=copies, progress=progress)
        return cls(cache, config)


def _apply(transform: NDArray[np.float64], points: NDArray[np.float32]) -> NDArray[np.float32]:
    """``R @ p + t`` in float64, returned as float32."""
    return (points.astype(np.float64) @ transform[:3, :3].T + transform[:3, 3]).astype(np.float32)


__all__ = [
    "CACHE_VERSION",
    "PROTOCOLS",
    "STORAGES",
    "FrameCache",
    "PairConfig",
    "PairDataset",
    "PairSample",
    "PreprocessedFrames",
    "build_frame_cache",
    "pair_indices",
    "pairs_within",
    "random_rigid_transform",
    "split_frames",
]


class PairDatasets(ConcatDataset):
    """Several sequences' pair datasets as one, forwarding ``set_epoch`` (torch's ConcatDataset does not)."""

    def set_epoch(self, epoch: int) -> None:
        for dataset in self.datasets:
            dataset.set_epoch(epoch)


def train_val_datasets(
    caches: Sequence[FrameCache], config: PairConfig | Sequence[PairConfig], val_fraction: float = 0.2
) -> tuple[PairDatasets, PairDatasets]:
    """Training and validation pairs from each cache's own contiguous frame blocks (:func:`split_frames`),
    so no validation pair shares a frame with a training pair. Several configurations (e.g. both
    protocols) give the pairs of each, on the same split."""
    configs = [config] if isinstance(config, PairConfig) else list(config)
    if not configs:
        raise ConfigError("give at least one PairConfig")
    train_sets, val_sets = [], []
    for cache in caches:
        train_rows, val_rows = split_frames(len(cache.frame_indices), val_fraction)
        rows_to_frames = np.asarray(cache.frame_indices)
        for pair_config in configs:
            train_sets.append(PairDataset(cache, pair_config, frames=rows_to_frames[train_rows].tolist()))
            val_sets.append(PairDataset(cache, pair_config, frames=rows_to_frames[val_rows].tolist()))
    return PairDatasets(train_sets), PairDatasets(val_sets)
