"""Frame caches: ground-removed, down-sampled copies of a sequence's frames, in one ``.npz``.

Why a cache: pre-processing (open3d RANSAC + farthest point sampling) costs far more than a training
step, and every epoch would repeat it. :func:`build_frame_cache` runs it once per frame and stores K
independently down-sampled copies of each frame. Loading a cache needs numpy only (open3d and
:mod:`vcr_odom.preprocess` are imported lazily, by :func:`build_frame_cache` alone), so a cache can be
carried to a GPU machine that has no open3d.

File format (version :data:`CACHE_VERSION`): arrays ``points`` (frames, copies, N, 3) in the stored
dtype, ``frame_indices``, ``seeds``, optional ``gt_poses``, and ``header`` (JSON: version, name,
storage, int16 step, pre-processing settings).
"""

from __future__ import annotations

import io
import json
import os
import zipfile
import zlib
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, is_dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from vcr_odom.errors import ConfigError, DataError
from vcr_odom.geometry import invert
from vcr_odom.io import atomic_write_bytes

if TYPE_CHECKING:
    from vcr_odom.data.base import LidarSequence
    from vcr_odom.preprocess import PreprocessConfig

STORAGES = ("int16", "float16", "float32")
"""How a cache stores points: ``int16`` fixed point of ``INT16_STEP`` metres (±163 m, at most 2.5 mm
error, half of float32's size), ``float16`` (up to ~3 cm error at 64-80 m, where its step is 6.25 cm:
coarse for a 5 cm target), or exact ``float32``."""
INT16_STEP = 0.005
CACHE_VERSION = 1
COPY_SEED_STRIDE = 1_000_003
"""Copy k of a frame is down-sampled with seed ``config.seed + k * COPY_SEED_STRIDE``."""


class SaysItsPreprocessing(Protocol):
    """Anything that names the pre-processing of a cache (e.g. a training ``PairConfig``)."""

    def preprocess_config(self) -> PreprocessConfig: ...


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

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write one ``.npz`` atomically (temp file + rename): a crash never leaves a half file."""
        arrays: dict[str, NDArray] = {
            "points": _encode(self.points, self.storage),
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
        if not zipfile.is_zipfile(path):  # else np.load reads any other file as a pickle, and its error
            raise DataError(  # says to load it unsafely: the wrong diagnosis and a dangerous advice
                f"frame cache {path}: not a frame cache made by `vcr-odom cache` (not an .npz archive)"
            )
        try:
            with np.load(path, allow_pickle=False) as data:
                header = json.loads(str(data["header"]))
                raw = data["points"]
                frame_indices = data["frame_indices"]
                seeds = data["seeds"]
                gt_poses = data["gt_poses"] if "gt_poses" in data.files else None
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as error:
            raise DataError(
                f"frame cache {path}: corrupt, or not a frame cache made by `vcr-odom cache`: {error}"
            ) from error
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


def _encode(points: NDArray[np.float32], storage: str) -> NDArray:
    """``points`` in the stored dtype (``int16``: multiples of :data:`INT16_STEP`)."""
    if storage == "float32":
        return points
    if storage == "float16":
        return points.astype(np.float16)
    limit = np.iinfo(np.int16).max * INT16_STEP
    if np.abs(points).max(initial=0.0) > limit:
        raise DataError(f"points beyond ±{limit:.0f} m do not fit storage='int16'; use 'float32'")
    return np.round(points / INT16_STEP).astype(np.int16)


def build_frame_cache(
    sequence: LidarSequence,
    frame_indices: Sequence[int] | None = None,
    config: PreprocessConfig | SaysItsPreprocessing | None = None,
    copies: int = 2,
    progress: Callable[[int, int], None] | None = None,
    storage: str = "int16",
) -> FrameCache:
    """Ground-remove each frame once and down-sample it ``copies`` times with different seeds.

    ``config`` is the pre-processing (None = its defaults), or anything with a ``preprocess_config()``
    such as a training ``PairConfig``. Copy 0 uses ``config.seed`` (so it equals
    ``preprocess(frame, config)``), copy k ``config.seed + k * COPY_SEED_STRIDE``.
    ``progress(done, total)`` is called after each frame. Imports open3d (through
    :mod:`vcr_odom.preprocess`): the only function here that does.
    """
    from vcr_odom.preprocess import PreprocessConfig, crop_and_remove_ground, downsample

    if config is not None and not isinstance(config, PreprocessConfig):
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
    seeds = np.array([config.seed + k * COPY_SEED_STRIDE for k in range(copies)], dtype=np.int64)
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
        preprocess=_settings_dict(config),
    )


def _settings_dict(config: Any) -> dict[str, Any]:
    """The pre-processing settings as a JSON-able dict (a dataclass or a pydantic configuration)."""
    return asdict(config) if is_dataclass(config) else config.to_dict()


__all__ = [
    "CACHE_VERSION",
    "COPY_SEED_STRIDE",
    "INT16_STEP",
    "STORAGES",
    "FrameCache",
    "build_frame_cache",
]
