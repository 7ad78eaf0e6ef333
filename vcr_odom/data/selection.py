"""Which frames of which sequence: ``--frames A:B`` and ``--stride K`` over a KITTI root, a folder, or a
recording read by a kiss-icp loader (``--dataloader NAME --data PATH``)."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field

from vcr_odom.data import DEFAULT_BIN_COLUMNS, LidarSequence, open_sequence
from vcr_odom.data.bin_scans import MAX_BIN_COLUMNS
from vcr_odom.data.kiss_loaders import LOADERS, KissLoaderSequence
from vcr_odom.errors import ConfigError, DataError
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
    """A sequence's source (a KITTI-layout root plus ``seq``, a plain ``folder`` of scans, or a
    ``dataloader`` reading ``data``) and which of its frames to use: what the
    ``--data-root/--seq/--folder/--dataloader/...`` options say."""

    data_root: Path | None = None
    seq: str = "00"
    folder: Path | None = None
    poses: Path | None = None
    calib: Path | None = None
    times: Path | None = None
    bin_columns: int = Field(default=DEFAULT_BIN_COLUMNS, ge=3, le=MAX_BIN_COLUMNS)
    dataloader: str | None = None
    data: Path | None = None
    topic: str | None = None
    frames: str | None = None
    stride: int = Field(default=1, ge=1)

    def open(self) -> LidarSequence:
        if self.dataloader is not None or self.data is not None:
            return self._open_recording()
        if self.topic:
            raise ConfigError("--topic only applies to a recording: --dataloader rosbag|mcap --data PATH")
        seq = None if self.folder else self.seq  # seq has a default; a folder wins over it
        return open_sequence(
            seq,
            data_root=self.data_root,
            folder=self.folder,
            poses=self.poses,
            calib=self.calib,
            times=self.times,
            bin_columns=self.bin_columns,
        )

    def _open_recording(self) -> KissLoaderSequence:
        if self.dataloader is None:
            raise ConfigError(f"--data needs --dataloader NAME to say how to read it ({', '.join(LOADERS)})")
        if self.data is None:
            raise ConfigError(f"--dataloader {self.dataloader} needs --data PATH (the recording to read)")
        if self.folder is not None:
            raise ConfigError("give either --folder (a folder of scans) or --dataloader/--data, not both")
        if self.bin_columns != DEFAULT_BIN_COLUMNS:
            raise ConfigError("--bin-columns applies to --folder and --data-root scans, not to --dataloader")
        return KissLoaderSequence(
            self.dataloader,
            self.data,
            sequence=self.seq,
            topic=self.topic,
            poses=self.poses,
            calib=self.calib,
            times=self.times,
        )

    def indices(self, sequence: LidarSequence) -> list[int]:
        """The selected frames; a DataError naming the source when it has none (an empty recording),
        where ``--frames``/``--stride`` would otherwise be blamed for selecting "0 frame(s) of 0"."""
        if len(sequence) == 0:
            where = getattr(sequence, "sequence_path", None) or sequence.name
            raise DataError(f"{where}: no frames to read ({sequence.name} is empty)")
        return select_frames(len(sequence), self.frames, self.stride)
