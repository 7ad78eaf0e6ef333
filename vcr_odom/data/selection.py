"""Which frames of which sequence: ``--frames A:B`` and ``--stride K`` over a KITTI root or a folder."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field

from vcr_odom.data import LidarSequence, open_sequence
from vcr_odom.errors import ConfigError
from vcr_odom.settings import Settings


def select_frames(length: int, frames: str | None = None, stride: int = 1) -> list[int]:
    """Frame indices for ``--frames A:B`` (Python slice semantics, B exclusive) and ``--stride K``."""
    if stride < 1:
        raise ConfigError(f"--stride must be a positive integer, got {stride}")
    start, stop = 0, length
    if frames:
        parts = frames.split(":")
        if len(parts) != 2:
            raise ConfigError(f"--frames expects A:B (e.g. 0:100), got {frames!r}")
        try:
            start = int(parts[0]) if parts[0] else 0
            stop = int(parts[1]) if parts[1] else length
        except ValueError as error:
            raise ConfigError(f"--frames expects integers A:B, got {frames!r}") from error
        start, stop, _ = slice(start, stop).indices(length)
    indices = list(range(start, stop, stride))
    if len(indices) < 2:
        raise ConfigError(
            f"--frames {frames or ':'} with --stride {stride} selects {len(indices)} frame(s) of {length}; "
            "odometry needs at least 2"
        )
    return indices


class FrameSelection(Settings):
    """A sequence's source (a KITTI-layout root plus ``seq``, or a plain ``folder`` of scans) and which
    of its frames to use: what the ``--data-root/--seq/--folder/...`` options say."""

    data_root: Path | None = None
    seq: str = "00"
    folder: Path | None = None
    poses: Path | None = None
    calib: Path | None = None
    frames: str | None = None
    stride: int = Field(default=1, ge=1)

    def open(self) -> LidarSequence:
        seq = None if self.folder else self.seq  # seq has a default; a folder wins over it
        return open_sequence(
            seq, data_root=self.data_root, folder=self.folder, poses=self.poses, calib=self.calib
        )

    def indices(self, sequence: LidarSequence) -> list[int]:
        return select_frames(len(sequence), self.frames, self.stride)
