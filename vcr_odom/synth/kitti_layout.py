"""Writing a synthetic sequence in the KITTI odometry layout (``sequences/<seq>/velodyne/*.bin``,
``calib.txt``, ``times.txt`` and camera-frame ``poses/<seq>.txt``), so every tool that reads KITTI
reads it too."""

from __future__ import annotations

import os
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.errors import ConfigError
from vcr_odom.geometry import lidar_to_camera_poses
from vcr_odom.io import atomic_write_bytes, write_kitti_calib, write_kitti_poses, write_times
from vcr_odom.synth.calibration import KITTI_TR, kitti_calib
from vcr_odom.synth.sequence import SynthConfig, SynthSequence

SEQUENCE_NAME = re.compile(r"^[A-Za-z0-9_-]+$")
"""What ``seq`` may be: it becomes a folder and a file name."""


@dataclass(frozen=True)
class WrittenSequence:
    """What :func:`write_sequence` wrote: where, and a summary of the drive for the user."""

    seq_dir: Path
    poses_file: Path
    frames: int
    length: float
    """Distance driven (m)."""
    duration: float
    """Time of the last frame (s)."""
    seconds: float
    """Wall-clock time the generation took (s)."""
    sensor: str
    height: float
    """Sensor mounting height (m)."""
    scene: str


def write_bin(path: Path, points: NDArray[np.float32]) -> Path:
    """Write a KITTI ``.bin`` atomically: never a half-written frame."""
    return atomic_write_bytes(path, np.ascontiguousarray(points, dtype=np.float32).tobytes())


def write_sequence(
    sequence: SynthSequence,
    out_root: str | os.PathLike[str],
    seq: str = "00",
    progress: Callable[[int], None] | None = None,
) -> WrittenSequence:
    """Write ``sequence`` under ``out_root`` in the KITTI odometry layout.

    Frames first, then ``calib.txt``, ``times.txt`` and last the poses, so a sequence with a poses file
    is complete. Stale frames of an earlier, longer run in the same folder are removed. ``progress`` is
    called with the number of frames written so far.
    """
    if not SEQUENCE_NAME.match(seq):
        raise ConfigError(f"seq must be letters, digits, '-' or '_', got {seq!r}")
    start = time.perf_counter()
    root = Path(out_root)
    seq_dir = root / "sequences" / seq
    velodyne = seq_dir / "velodyne"
    poses_file = root / "poses" / f"{seq}.txt"
    velodyne.mkdir(parents=True, exist_ok=True)
    poses_file.unlink(missing_ok=True)
    for stale in velodyne.glob("*.bin"):
        if stale.stem.isdigit() and int(stale.stem) >= len(sequence):
            stale.unlink()
    for index in range(len(sequence)):
        write_bin(velodyne / f"{index:06d}.bin", sequence.frame(index))
        if progress is not None:
            progress(index + 1)
    write_kitti_calib(seq_dir / "calib.txt", kitti_calib())
    write_times(seq_dir / "times.txt", sequence.timestamps)
    write_kitti_poses(poses_file, lidar_to_camera_poses(sequence.gt_poses, KITTI_TR))
    return WrittenSequence(
        seq_dir=seq_dir,
        poses_file=poses_file,
        frames=len(sequence),
        length=sequence.length,
        duration=float(sequence.timestamps[-1]),
        seconds=time.perf_counter() - start,
        sensor=sequence.sensor.name,
        height=sequence.sensor.height,
        scene=sequence.scene_style,
    )


def generate_sequence(
    out_root: str | os.PathLike[str],
    seq: str = "00",
    config: SynthConfig | None = None,
    progress: Callable[[int], None] | None = None,
    **options: Any,
) -> WrittenSequence:
    """Generate a synthetic sequence and write it in the KITTI layout (``<out_root>/sequences/<seq>``).

    ``options`` are :class:`SynthConfig` fields (``frames``, ``seed``, ``speed``, ``sensor``,
    ``height``, ``scene``, ``stops``, ``frame_period``), applied on top of ``config`` when one is given.
    """
    return write_sequence(SynthSequence(config, **options), out_root, seq, progress)
