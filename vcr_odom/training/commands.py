"""What the ``cache``, ``train`` and ``pretrain`` commands do, one function each (callable from a notebook).

Why frame caches first: pre-processing (open3d) runs once per frame into a cache; training then needs
only numpy and torch, so caches built on one machine can train on another that has no open3d. A run
takes its frames from caches, from sequences pre-processed on the spot, or both (:class:`TrainingData`).

    from vcr_odom.model.config import VcrConfig
    from vcr_odom.training import TrainConfig, TrainingData, fit_on

    data = TrainingData(caches=["s00.npz"], protocols=["odometry", "same-scan"], max_motion=15.0)
    result = fit_on("train", data, VcrConfig.preset("default"), TrainConfig(epochs=8, out="runs/mine"))
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Self

from pydantic import Field, field_validator, model_validator

from vcr_odom.data.frame_cache import FrameCache, build_frame_cache
from vcr_odom.errors import ConfigError
from vcr_odom.model.config import VcrConfig
from vcr_odom.results import check_output_file, check_output_folder
from vcr_odom.settings import Settings
from vcr_odom.training.checkpoint import load_checkpoint
from vcr_odom.training.config import Progress, TrainConfig, TrainResult
from vcr_odom.training.datasets import PairDatasets, train_val_datasets
from vcr_odom.training.loop import pretrain, train
from vcr_odom.training.pairs import PairConfig, Protocol

FramesProgress = Callable[[str, int, int], None]
"""``(sequence name, frames pre-processed, frames to pre-process)``, first with 0 done, then per frame."""


class FrameSource(Settings):
    """Sequences under a KITTI-layout root to pre-process into frame caches, and which of their frames."""

    data_root: Path | None = Field(None, description="KITTI-layout root (real or from `vcr-odom synth`).")
    seqs: tuple[str, ...] = Field((), description="Sequence id under --data-root; repeat for several.")
    copies: int = Field(2, ge=2, le=64, description="Independent down-samplings stored per frame.")
    frames: str | None = Field(
        None, description="Only frames A:B of each --seq (B exclusive), e.g. to keep a test block out."
    )
    stride: int = Field(
        1, ge=1, description="Every K-th frame of --frames (neighbouring frames are near-copies)."
    )


class TrainingData(FrameSource):
    """The frames a run learns from (caches and/or sequences), the pairs drawn from them, the split."""

    caches: tuple[Path, ...] = Field(
        (), description="Frame caches from `vcr-odom cache` (instead of, or beside, --seq)."
    )
    protocols: tuple[Protocol, ...] = Field(
        ("odometry",),
        min_length=1,
        description="Pairs of different scans with GT motion, or the paper's same-scan protocol (random "
        "yaw ±30°, tilt ±5°, ±5 m / ±1 m); repeat for both.",
    )
    augment: bool = Field(True, description=PairConfig.model_fields["augment"].description)
    augment_yaw: float = Field(
        30.0,
        ge=0,
        le=180,
        allow_inf_nan=False,
        description="Yaw range (± degrees) of the random motion of --augment and of same-scan pairs "
        "(the paper's 30); 180 shows the network every heading, as a revisit from the other side does.",
    )
    max_motion: float | None = Field(
        None,
        gt=0,
        allow_inf_nan=False,
        description="Odometry pairs: every pair of frames at most this many metres apart (instead of "
        "pairs 1, 2, 3 and 5 frames apart).",
    )
    reverse: bool = Field(False, description=PairConfig.model_fields["reverse"].description)
    val_fraction: float = Field(
        0.2,
        ge=0.05,
        le=0.5,
        description="Share of each sequence's frames (contiguous blocks) held out for validation.",
    )

    @field_validator("protocols")
    @classmethod
    def _once_each(cls, protocols: tuple[str, ...]) -> tuple[str, ...]:
        return tuple(dict.fromkeys(protocols))

    @model_validator(mode="after")
    def _some_frames(self) -> Self:
        if not self.caches and not self.seqs:
            raise ValueError("give training data: --seq (with --data-root) or --cache")
        return self

    def pair_configs(self, num_points: int, seed: int) -> list[PairConfig]:
        """One :class:`PairConfig` per protocol (the augment/max_motion/reverse settings are for
        odometry pairs; same-scan pairs ignore them)."""
        return [
            PairConfig(
                protocol=protocol,
                num_points=num_points,
                augment=self.augment,
                seed=seed,
                max_motion=self.max_motion,
                reverse=self.reverse,
                yaw_deg=self.augment_yaw,
            )
            for protocol in self.protocols
        ]


def sequence_caches(
    source: FrameSource, model_config: VcrConfig, progress: FramesProgress | None = None
) -> list[FrameCache]:
    """One in-memory frame cache per sequence of ``source``, pre-processed as ``model_config``'s
    network is fed at inference (needs open3d, unless there is no sequence)."""
    if not source.seqs:
        return []
    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.preprocess import network_preprocess_config

    preprocess = network_preprocess_config(model_config)
    caches = []
    for seq in source.seqs:
        sequence = open_sequence(seq, data_root=source.data_root)
        indices = select_frames(len(sequence), source.frames, source.stride)
        name = sequence.name
        if progress is not None:
            progress(name, 0, len(indices))
        on_frame = None if progress is None else lambda done, total, name=name: progress(name, done, total)
        caches.append(build_frame_cache(sequence, indices, preprocess, source.copies, on_frame))
    return caches


def cache_sequence(
    source: FrameSource,
    model_config: VcrConfig,
    out: Path | None = None,
    progress: FramesProgress | None = None,
) -> FrameCache:
    """The ``cache`` command: pre-process the one sequence of ``source`` and write it to ``out``
    (a ``.npz``, atomically) when given."""
    if len(source.seqs) != 1:
        raise ConfigError("give exactly one --seq per cache file")
    if out is not None:  # before the pre-processing: a folder it cannot write fails first
        check_output_file(out, "--out")
    (cache,) = sequence_caches(source, model_config, progress)
    if out is not None:
        cache.save(out)
    return cache


def training_sets(
    data: TrainingData, model_config: VcrConfig, seed: int, progress: FramesProgress | None = None
) -> tuple[PairDatasets, PairDatasets]:
    """Training and validation pairs of ``data`` (caches loaded, sequences pre-processed), each pair
    drawn from ``seed``; validation frames are contiguous blocks never seen in training."""
    caches = [FrameCache.load(path, num_points=model_config.num_points) for path in data.caches]
    for path, cache in zip(data.caches, caches, strict=True):
        check_cache_crop(path, cache, model_config)
    caches += sequence_caches(data, model_config, progress)
    pairs = data.pair_configs(model_config.num_points, seed)
    return train_val_datasets(caches, pairs, data.val_fraction)


def check_cache_crop(path: Path, cache: FrameCache, model_config: VcrConfig) -> None:
    """ConfigError where a cache was cropped otherwise than the network being trained will see its
    clouds: the weights would run on clouds unlike the ones they were fitted to."""
    crop = cache.preprocess.get("max_range")
    if crop is not None and float(crop) != model_config.input_max_range:
        raise ConfigError(
            f"frame cache {path} was cropped at {float(crop):g} m, the model sees "
            f"{model_config.input_max_range:g} m; rebuild it with `vcr-odom cache --input-max-range "
            f"{model_config.input_max_range:g}` or train with --input-max-range {float(crop):g}"
        )


TRAINING_TASKS = {"train": train, "pretrain": pretrain}
"""``train``: the correspondence loss (the network); ``pretrain``: the triplet loss (the encoder)."""


def fit_on(
    task: str,
    data: TrainingData,
    model_config: VcrConfig,
    config: TrainConfig,
    resume: bool = False,
    progress: Progress | None = None,
    frames_progress: FramesProgress | None = None,
) -> TrainResult:
    """The ``train`` and ``pretrain`` commands: that task's loop on the pairs of ``data``."""
    if task not in TRAINING_TASKS:
        raise ConfigError(f"task must be one of {', '.join(TRAINING_TASKS)}; got {task!r}")
    check_output_folder(config.out, "--out")  # before the pre-processing, as every command does
    if resume:  # a missing or broken checkpoint, too, is found before the pre-processing
        load_checkpoint(config.out / "last.pt", task, model_config)
    train_set, val_set = training_sets(data, model_config, config.seed, frames_progress)
    return TRAINING_TASKS[task](model_config, train_set, val_set, config, resume, progress)
