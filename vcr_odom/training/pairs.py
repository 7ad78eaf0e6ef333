"""Which pairs VCR-Net trains on: the paper's same-scan protocol and odometry pairs, and the split.

Why two protocols: the paper trains and tests on one scan against a moved copy of itself (its Table
III), which never shows the network what differs between two real scans (moved objects, occlusion, a
new sampling of the same surfaces); odometry pairs of different scans do, and they are what
inference sees. Training on both keeps the paper's protocol comparable.

- ``"same-scan"``: one ground-removed scan down-sampled twice, independently (different seeds), to N
  points; the second copy is moved by a random rigid transform ``M`` (yaw ±30°, roll/pitch ±5°,
  horizontal ±5 m, vertical ±1 m; LiDAR frame, z up). **Source = the first copy as it is, target =
  the second copy moved by M, so ``transform = M``**: the label's distribution is exactly the
  documented ranges.
- ``"odometry"``: scans ``i`` and ``j = i + d`` (``d`` in ``gaps``), each ground-removed and
  down-sampled independently; **source = frame j, target = frame i, ``transform = inv(P_i) @ P_j``**
  (``T_i_j`` from the LiDAR-frame ground truth). With ``augment=True`` the target is also moved by a
  random ``M`` of the same ranges and ``transform = M @ T_i_j``, so the network cannot rely on the
  small motion between consecutive frames. With ``max_motion`` set, the pairs are instead every
  ``(i, j)``, ``i < j``, whose ground-truth motion is at most ``max_motion`` metres (a stop gives
  pairs that did not move; a fast stretch few of them), so training covers 0 to ``max_motion`` m
  whatever the frame rate and speed. ``reverse=True`` swaps source and target of a random half of
  the samples each epoch (the motion then points backwards).

Every sample's ``transform`` is ``T_target_source``: ``target ≈ R @ source + t``. The samples
themselves are drawn by :class:`vcr_odom.training.datasets.PairDataset` from a frame cache.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated, Any, Literal, Self, get_args

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, field_validator, model_validator

from vcr_odom.errors import ConfigError
from vcr_odom.geometry import make_transform, rotation_from_euler_zyx
from vcr_odom.settings import Settings

if TYPE_CHECKING:
    from vcr_odom.data.frame_cache import FrameCache
    from vcr_odom.preprocess import PreprocessConfig

Protocol = Literal["odometry", "same-scan"]
PROTOCOLS: tuple[str, ...] = get_args(Protocol)


def _range(default: float, description: str) -> Any:
    return Field(default, ge=0, allow_inf_nan=False, description=description)


class PairConfig(Settings):
    """How pairs are made from a frame cache (see the module doc for both protocols)."""

    protocol: Protocol = Field("same-scan", description="One of PROTOCOLS.")
    num_points: int = Field(1024, ge=1, description="Points per cloud; the cache must hold as many.")
    gaps: tuple[Annotated[int, Field(ge=1)], ...] = Field(
        (1, 2, 3, 5), min_length=1, description="Odometry pairs: frames apart (without max_motion)."
    )
    augment: bool = Field(
        False, description="Odometry pairs: add the same-scan random transform on top of the GT motion."
    )
    preprocess: Any = Field(
        None,
        description="The cache's PreprocessConfig (None = its defaults); what inference uses, so that "
        "training sees what the network is fed. Its n_points must equal num_points.",
    )
    seed: int = Field(0, ge=0, description="Drives every random transform and copy choice.")
    yaw_deg: float = _range(30.0, "Same-scan motion: yaw uniform in ±yaw_deg.")
    tilt_deg: float = _range(5.0, "Same-scan motion: pitch and roll uniform in ±tilt_deg.")
    horizontal_m: float = _range(5.0, "Same-scan motion: x and y uniform in ±horizontal_m.")
    vertical_m: float = _range(1.0, "Same-scan motion: z uniform in ±vertical_m.")
    max_motion: float | None = Field(
        None,
        gt=0,
        allow_inf_nan=False,
        description="Odometry pairs: every pair of frames at most this many metres apart (instead of "
        "the pairs `gaps` frames apart).",
    )
    reverse: bool = Field(
        False, description="Odometry pairs: swap source and target of a random half of the pairs each epoch."
    )

    @field_validator("preprocess", mode="before")
    @classmethod
    def _preprocess_config(cls, value: Any) -> Any:
        """None, a PreprocessConfig, or its dict (what :meth:`to_dict` wrote)."""
        if value is None:
            return None
        from vcr_odom.preprocess import PreprocessConfig  # lazily: open3d; a caller holding one has it

        if isinstance(value, dict):
            return PreprocessConfig(**value)
        if not isinstance(value, PreprocessConfig):
            raise ValueError(f"must be None or a PreprocessConfig; got {type(value).__name__}")
        return value

    @model_validator(mode="after")
    def _points_agree(self) -> Self:
        if self.preprocess is not None and self.preprocess.n_points != self.num_points:
            raise ValueError(
                f"num_points={self.num_points} differs from preprocess.n_points={self.preprocess.n_points}"
            )
        return self

    def preprocess_config(self) -> PreprocessConfig:
        """The pre-processing of the cache (imports open3d: only call where it is installed)."""
        from vcr_odom.preprocess import PreprocessConfig

        return self.preprocess or PreprocessConfig(n_points=self.num_points)

    def transform_ranges(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in ("yaw_deg", "tilt_deg", "horizontal_m", "vertical_m")}


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
    if len(gaps) == 0 or any(not isinstance(d, int | np.integer) or d < 1 for d in gaps):
        raise ConfigError(f"gaps must be a non-empty set of integers >= 1; got {tuple(gaps)!r}")
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
    = 10 s of a 10 Hz LiDAR). ``round(blocks * val_fraction)`` blocks (at least one when
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
