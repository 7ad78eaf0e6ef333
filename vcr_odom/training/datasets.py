"""The torch datasets of training pairs: one frame cache under one :class:`PairConfig`, and several.

Why samples are pure functions of ``(seed, epoch, index)``: every sample draws from
``numpy.random.default_rng([seed, epoch, index])`` and never from a global RNG, so DataLoader workers,
DDP ranks and a resumed run all see the same pairs. Only numpy and torch are needed (no open3d), so
training runs from carried caches on a machine without the pre-processing stack.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, TypedDict

import numpy as np
import torch
from numpy.typing import NDArray
from torch.utils.data import ConcatDataset, Dataset

from vcr_odom.data.frame_cache import FrameCache
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import invert
from vcr_odom.training.pairs import (
    PairConfig,
    pair_indices,
    pairs_within,
    random_rigid_transform,
    split_frames,
)


class PairSample(TypedDict):
    """One training pair; ``transform`` is ``T_target_source`` (maps source points onto the target)."""

    source: torch.Tensor
    target: torch.Tensor
    transform: torch.Tensor
    meta: str


class PairDataset(Dataset):
    """Pairs of one :class:`FrameCache` under :class:`PairConfig` (conventions: :mod:`vcr_odom.training.pairs`).

    ``frames`` restricts the sequence frames used (e.g. one side of :func:`split_frames`); odometry
    pairs need both frames in it. ``pairs[k]`` is ``(source_frame, target_frame)``. Sample ``i`` of
    epoch ``e`` is a pure function of ``(config.seed, e, i)``: call :meth:`set_epoch` each epoch for
    new transforms and copy choices (before creating the DataLoader iterator: workers copy the
    dataset, so with ``persistent_workers=True`` the epoch would not reach them).
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


class PairDatasets(ConcatDataset):
    """Several caches' pair datasets as one, forwarding ``set_epoch`` (torch's ConcatDataset does not)."""

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


def _apply(transform: NDArray[np.float64], points: NDArray[np.float32]) -> NDArray[np.float32]:
    """``R @ p + t`` in float64, returned as float32."""
    return (points.astype(np.float64) @ transform[:3, :3].T + transform[:3, 3]).astype(np.float32)
